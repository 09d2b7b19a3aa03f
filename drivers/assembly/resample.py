"""Kernels that put samples onto the crank-angle grid: the tooth angle -> time map and pressure by time.

- ``pchip_eval``: monotone piecewise-cubic (Fritsch-Carlson, the same derivative rule as scipy's
  ``PchipInterpolator``) through the tooth edges (theta_j, t_j), evaluated at the grid angles. A monotone t(theta)
  never folds back in time, and between teeth it follows the local speed trend instead of a straight line.
  Compiled, not scipy's, because it runs once per cycle inside the assembly kernel (``cycle_kernels.cycle_edges``):
  scipy's PchipInterpolator there cost ~0.2 ms per cycle, 25 % end to end on deutz-1cyl and k9k-4cyl, 19 % on
  genset-v20 (same process, 8 alternated passes each, loaded 2-core box, issue 26 item 6). scipy is its reference:
  tests/drivers/test_cycles.py and tests/drivers/test_cycle_kernels.py.
- ``interp_sorted``: linear interpolation of pressure samples at sorted query times in one merge pass (O(n + m)),
  the same numbers as ``np.interp`` inside the data range; ``interp_checked`` first refuses a span with a hole
  (a spacing over 1.5 times the mean) or a NaN sample.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def _pchip_slopes(x, y, d):
    n = x.shape[0]
    if n == 2:
        s = (y[1] - y[0]) / (x[1] - x[0])
        d[0] = s
        d[1] = s
        return
    for i in range(1, n - 1):
        h0 = x[i] - x[i - 1]
        h1 = x[i + 1] - x[i]
        s0 = (y[i] - y[i - 1]) / h0
        s1 = (y[i + 1] - y[i]) / h1
        if s0 * s1 <= 0.0:
            d[i] = 0.0
        else:
            w1 = 2.0 * h1 + h0
            w2 = h1 + 2.0 * h0
            d[i] = (w1 + w2) / (w1 / s0 + w2 / s1)
    # end points: shape-preserving three-point formula (scipy _edge_case)
    for e in range(2):
        if e == 0:
            h0 = x[1] - x[0]
            h1 = x[2] - x[1]
            s0 = (y[1] - y[0]) / h0
            s1 = (y[2] - y[1]) / h1
            dn = d[0:1]
        else:
            h0 = x[n - 1] - x[n - 2]
            h1 = x[n - 2] - x[n - 3]
            s0 = (y[n - 1] - y[n - 2]) / h0
            s1 = (y[n - 2] - y[n - 3]) / h1
            dn = d[n - 1 : n]
        v = ((2.0 * h0 + h1) * s0 - h0 * s1) / (h0 + h1)
        if v * s0 <= 0.0:
            v = 0.0
        elif s0 * s1 <= 0.0 and abs(v) > abs(3.0 * s0):
            v = 3.0 * s0
        dn[0] = v


# compiled, not scipy: 19-25 % end to end measured in the per-cycle assembly (module docstring); scipy is the tests' reference
@numba.njit(cache=True)
def pchip_eval_kernel(x, y, xq, out):
    n = x.shape[0]
    d = np.empty(n)
    _pchip_slopes(x, y, d)
    j = 0
    for i in range(xq.shape[0]):
        v = xq[i]
        while j < n - 2 and v > x[j + 1]:
            j += 1
        h = x[j + 1] - x[j]
        s = (v - x[j]) / h
        h00 = (1.0 + 2.0 * s) * (1.0 - s) * (1.0 - s)
        h10 = s * (1.0 - s) * (1.0 - s)
        h01 = s * s * (3.0 - 2.0 * s)
        h11 = s * s * (s - 1.0)
        out[i] = h00 * y[j] + h10 * h * d[j] + h01 * y[j + 1] + h11 * h * d[j + 1]


def pchip_eval(x: np.ndarray, y: np.ndarray, xq: np.ndarray) -> np.ndarray:
    """Monotone cubic through (x, y) at ``xq``.

    x : (n,) strictly increasing, n >= 2; y : (n,); xq : (m,) sorted ascending, inside [x[0], x[-1]]
    """
    xs = np.ascontiguousarray(x, dtype=np.float64)
    ys = np.ascontiguousarray(y, dtype=np.float64)
    q = np.ascontiguousarray(xq, dtype=np.float64)
    if xs.ndim != 1 or xs.shape != ys.shape or xs.shape[0] < 2:
        raise ValueError(f"x and y must be 1-D of the same length >= 2, got {xs.shape} and {ys.shape}")
    if np.any(np.diff(xs) <= 0):
        raise ValueError("x must be strictly increasing")
    if q.size and (q[0] < xs[0] or q[-1] > xs[-1] or np.any(np.diff(q) < 0)):
        raise ValueError("xq must be sorted and inside [x[0], x[-1]]")
    out = np.empty(q.shape[0])
    pchip_eval_kernel(xs, ys, q, out)
    return out


@numba.njit(cache=True)
def _interp_sorted(xq, x, y, out):
    n = x.shape[0]
    j = 0
    for i in range(xq.shape[0]):
        v = xq[i]
        while j < n - 2 and v >= x[j + 1]:
            j += 1
        w = (v - x[j]) / (x[j + 1] - x[j])
        out[i] = y[j] + w * (y[j + 1] - y[j])


def interp_sorted(xq: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Linear interpolation at sorted ``xq`` inside [x[0], x[-1]] (x strictly increasing, n >= 2)."""
    xs = np.ascontiguousarray(x, dtype=np.float64)
    ys = np.ascontiguousarray(y, dtype=np.float64)
    q = np.ascontiguousarray(xq, dtype=np.float64)
    if xs.shape[0] < 2 or xs.shape != ys.shape:
        raise ValueError("x and y must be 1-D of the same length >= 2")
    if q.size and (q[0] < xs[0] or q[-1] > xs[-1]):
        raise ValueError("xq must lie inside [x[0], x[-1]]")
    out = np.empty(q.shape[0])
    _interp_sorted(q, xs, ys, out)
    return out


CHECK_OK, CHECK_HOLE, CHECK_NAN = 0, 1, 2


@numba.njit(cache=True)
def interp_checked_kernel(xq, x, y, out):
    n = x.shape[0]
    lim = 1.5 * (x[n - 1] - x[0]) / (n - 1)
    for i in range(n - 1):
        if x[i + 1] - x[i] > lim:
            return CHECK_HOLE
        if y[i] != y[i]:
            return CHECK_NAN
    if y[n - 1] != y[n - 1]:
        return CHECK_NAN
    _interp_sorted(xq, x, y, out)
    return CHECK_OK


def interp_checked(xq: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray | None, int]:
    """``interp_sorted`` over a span that must be whole: returns (values, CHECK_OK) or (None, CHECK_HOLE |
    CHECK_NAN). x must cover xq (x[0] <= xq[0], xq[-1] <= x[-1]) with at least two samples."""
    xs = np.ascontiguousarray(x, dtype=np.float64)
    ys = np.ascontiguousarray(y, dtype=np.float64)
    q = np.ascontiguousarray(xq, dtype=np.float64)
    if xs.shape[0] < 2 or xs.shape != ys.shape or (q.size and (q[0] < xs[0] or q[-1] > xs[-1])):
        raise ValueError("x must be 1-D, >= 2 samples, the same length as y, and cover xq")
    out = np.empty(q.shape[0])
    code = interp_checked_kernel(q, xs, ys, out)
    return (out, code) if code == CHECK_OK else (None, code)
