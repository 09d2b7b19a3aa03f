"""Rows sampled at the flywheel angles of a cycle's time grid, onto the crank-angle grid (periodic in 4 pi), as
np.interp puts them: the brackets found once (grid_brackets), every row through them (interp_bracketed_rows), and
the two together (rows_on_grid). The result's traces use them (core.monitor.report.cycle_report.report_traces) and
so does a stored result asked for its per-cylinder friction on the grid (CycleResult.friction_torque_cyl): apart
from the report's builder so that the result record need not import it (the builder imports the record). Their
reference is np.interp row by row (tests/core/test_monitor_kernels.py).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def grid_brackets(grid, theta):
    """The brackets of the crank-angle ``grid`` (ng,) in the flywheel angles ``theta`` (n,) of the time samples
    (periodic in 4 pi: theta spans one cycle from the first edge), as np.interp finds them.

    Returns (js, dxs, special, n_special, dxp): grid point i lies dxs[i] after theta[js[i]]; ``special`` marks the
    points that np.interp puts on y0 (an exact hit on theta[0] or outside the period); dxp (n,) the bracket widths
    (the last one wraps to theta[0] + 4 pi). One forward walk over the sorted angles (restarted where the grid wraps
    past theta[0] + 4 pi); a theta that is not increasing falls back to bisection."""
    n = theta.shape[0]
    four_pi = 4.0 * np.pi
    th0 = theta[0]
    x_end = th0 + four_pi
    increasing = True
    for t in range(1, n):
        if not theta[t] >= theta[t - 1]:
            increasing = False
    ng = grid.shape[0]
    js = np.empty(ng, dtype=np.int64)
    dxs = np.empty(ng)
    special = np.zeros(ng, dtype=np.bool_)
    n_special = 0
    lo = 0
    prev_x = -np.inf
    for i in range(ng):
        x = grid[i] - th0
        if x > 0.0 and x < four_pi:  # Python's float % is the identity here
            x = th0 + x
        else:
            x = th0 + x % four_pi
        if x >= x_end or x <= th0:  # an exact hit on theta[0] or outside: y0 (through dx = 0, dxp = 1)
            js[i] = 0
            dxs[i] = 0.0
            special[i] = True
            n_special += 1
            continue
        if increasing:
            if x < prev_x:
                lo = 0
            prev_x = x
            while lo + 1 < n and theta[lo + 1] <= x:  # the largest lo with theta[lo] <= x
                lo += 1
        else:
            lo = 0
            hi = n
            while hi - lo > 1:  # theta[lo] <= x < theta[hi] (theta[n] = x_end)
                mid = (lo + hi) >> 1
                if theta[mid] <= x:
                    lo = mid
                else:
                    hi = mid
        js[i] = lo
        dxs[i] = x - theta[lo]
    dxp = np.empty(n)
    for t in range(n - 1):
        dxp[t] = theta[t + 1] - theta[t]
    dxp[n - 1] = x_end - theta[n - 1]
    return js, dxs, special, n_special, dxp


@numba.njit(cache=True)
def interp_bracketed_rows(vals, js, dxs, special, n_special, dxp, out):
    """out (r, ng) = every row of vals (r, n) at the grid brackets of ``grid_brackets``, as np.interp does.

    np.interp's arithmetic is (y1 - y0) / dxp * dx + y0 with dxp the width of the bracket: the quotient depends on
    the bracket only, so it is formed once per bracket and row (n divisions per row instead of one per grid
    point), bit for bit the same numbers."""
    rows, n = vals.shape
    ng = js.shape[0]
    slope = np.empty((rows, n))
    for k in range(rows):
        for t in range(n - 1):
            slope[k, t] = (vals[k, t + 1] - vals[k, t]) / dxp[t]
        slope[k, n - 1] = (vals[k, 0] - vals[k, n - 1]) / dxp[n - 1]
    # four rows per sweep: the bracket index and offset of a grid point are loaded once for all four
    k = 0
    while k < rows:
        if k + 4 <= rows:
            o0, o1, o2, o3 = out[k], out[k + 1], out[k + 2], out[k + 3]
            v0, v1, v2, v3 = vals[k], vals[k + 1], vals[k + 2], vals[k + 3]
            s0, s1, s2, s3 = slope[k], slope[k + 1], slope[k + 2], slope[k + 3]
            for i in range(ng):
                j = js[i]
                d = dxs[i]
                o0[i] = s0[j] * d + v0[j]
                o1[i] = s1[j] * d + v1[j]
                o2[i] = s2[j] * d + v2[j]
                o3[i] = s3[j] * d + v3[j]
            k += 4
        else:
            o = out[k]
            v = vals[k]
            s = slope[k]
            for i in range(ng):
                j = js[i]
                o[i] = s[j] * dxs[i] + v[j]
            k += 1
    if n_special:
        for k in range(rows):
            o = out[k]
            y0 = vals[k, 0]
            for i in range(ng):
                if special[i]:
                    o[i] = (y0 - y0) / 1.0 * 0.0 + y0


@numba.njit(cache=True)
def rows_on_grid(grid, theta, vals, out):
    """out (r, ng) = the rows vals (r, n_t), sampled at the flywheel angles ``theta``, on the crank-angle ``grid``
    (periodic in 4 pi), exactly as ``report_traces`` puts its rows there."""
    js, dxs, special, n_special, dxp = grid_brackets(grid, theta)
    interp_bracketed_rows(vals, js, dxs, special, n_special, dxp, out)
