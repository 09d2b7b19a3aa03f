"""One numba call per cylinder for a cycle's pressure row: window search in the mirrored ring storage, the
hole/NaN check and the linear interpolation at the grid times (drivers.assembly.cycle_parts.pressure_on_grid).

It replaces two ``RingBuffer.searchsorted`` calls, two views and the ``interp_checked`` wrapper (numpy call
overhead, ~10 us per cylinder) with the same arithmetic: the binary searches follow np.searchsorted's loop (NaN
ordered last) and the interpolation is ``drivers.assembly.resample.interp_checked_kernel``. The numpy reference
(np.searchsorted, np.interp) is in tests/drivers/test_pressure_kernels.py.
"""

from __future__ import annotations

import numba
import numpy as np
from frictionwatch.drivers.assembly.resample import CHECK_HOLE, CHECK_NAN, interp_checked_kernel
from frictionwatch.drivers.assembly.ringbuffer import search_sorted

ROW_OK, ROW_MISSING, ROW_HOLE, ROW_NAN = 0, 1, 2, 3


@numba.njit(cache=True)
def pressure_row(col_t, col_p, start, end, t_grid, out):
    """Row of one pressure ring (mirrored columns col_t, col_p of length 2 cap, retained rows [start, end)) at the
    sorted times t_grid; returns ROW_OK (out filled), ROW_MISSING, ROW_HOLE or ROW_NAN."""
    n = end - start
    if n < 2:
        return ROW_MISSING
    cap = col_t.shape[0] // 2
    i0 = start % cap
    m = t_grid.shape[0]
    # np.bool_, not a literal True/False: one search_sorted specialisation (the plain bool the Python callers
    # compile) serves both, not one more per literal value
    a = search_sorted(col_t, i0, n, t_grid[0], np.bool_(True)) - 1
    b = search_sorted(col_t, i0, n, t_grid[m - 1], np.bool_(False)) + 1
    if a < 0 or b > n:
        return ROW_MISSING
    code = interp_checked_kernel(t_grid, col_t[i0 + a : i0 + b], col_p[i0 + a : i0 + b], out)
    if code == CHECK_HOLE:
        return ROW_HOLE
    if code == CHECK_NAN:
        return ROW_NAN
    return ROW_OK


@numba.njit(cache=True)
def window_weights(x, t_grid, jj, ww, period):
    """The part of a group's resampling that depends on the shared sample times x (the retained window that
    brackets the sorted times t_grid) only: the first hole (a spacing over 1.5 times the window's mean, or over 1.5
    sample periods where ``period`` > 0 is the source's own; x.size - 1: none, as ``interp_checked_kernel``) and,
    when there is none, the interval j and weight w of every grid time (``resample.interp_sorted``'s walk) into jj,
    ww. Returns the hole index.

    Why the period: the window's mean cannot see a hole that swallows the whole window -- a cycle inside a stretch of
    pressure dropped has a window of two samples, the last before the hole and the first after it, whose mean
    spacing is the hole itself; the cycle was interpolated across it, ~170 bar off on the demo log before this
    check."""
    nx = x.shape[0]
    m = t_grid.shape[0]
    lim = 1.5 * (x[nx - 1] - x[0]) / (nx - 1)
    if period > 0.0 and 1.5 * period < lim:
        lim = 1.5 * period
    hole = nx - 1
    for i in range(nx - 1):
        if x[i + 1] - x[i] > lim:
            hole = i
            break
    if hole == nx - 1:
        j = 0
        for i in range(m):
            v = t_grid[i]
            while j < nx - 2 and v >= x[j + 1]:
                j += 1
            jj[i] = j
            ww[i] = (v - x[j]) / (x[j + 1] - x[j])
    return hole


@numba.njit(cache=True)
def _row_on_weights(y, nx, hole, jj, ww, o):
    """One row's samples y[0:nx] over the window of ``window_weights``: its ROW_* code, and o filled if ROW_OK.
    The NaN check runs up to the first hole (the first NaN before the first hole wins, as in ``interp_checked_kernel``'s
    loop); then ``y[j] + w (y[j+1] - y[j])`` with the j and w of ``resample.interp_sorted``."""
    nan = False
    for i in range(hole):
        nan |= y[i] != y[i]
    if nan:
        return ROW_NAN
    if hole < nx - 1:
        return ROW_HOLE
    if y[nx - 1] != y[nx - 1]:
        return ROW_NAN
    for i in range(o.shape[0]):
        j = np.uint64(jj[i])  # unsigned: no wrap-around test per read (drivers/assembly/frame_kernels.py frame_rows)
        y0 = y[j]
        o[i] = y0 + ww[i] * (y[j + np.uint64(1)] - y0)
    return ROW_OK


@numba.njit(cache=True)
def pressure_rows(col_t, block_p, start, end, t_grid, rows, out, codes, period=0.0):
    """Every row of a pressure group (time column col_t, value block block_p (k, 2 cap), retained rows
    [start, end)) at the sorted times t_grid: row r into out[rows[r]] (rows[r] < 0: not wanted), its code
    (ROW_*) into codes[r]. Returns the number of wanted rows that are not ROW_OK. ``period``: the samples' own
    period [ticks] where known (> 0), for the hole test (``window_weights``).

    What ``pressure_row`` gives for each row on its own (the same arithmetic): the window search, the hole search and the
    interpolation intervals and weights depend on the shared times only and are done once (``window_weights``);
    per row remain the NaN check and the interpolation (``_row_on_weights``)."""
    k = block_p.shape[0]
    n = end - start
    cap = col_t.shape[0] // 2
    i0 = start % cap
    m = t_grid.shape[0]
    a = 0
    b = 0
    whole = n >= 2
    if whole:
        a = search_sorted(col_t, i0, n, t_grid[0], np.bool_(True)) - 1  # np.bool_: see pressure_row
        b = search_sorted(col_t, i0, n, t_grid[m - 1], np.bool_(False)) + 1
        whole = a >= 0 and b <= n
    bad = 0
    if not whole:
        for r in range(k):
            codes[r] = ROW_OK if rows[r] < 0 else ROW_MISSING
            bad += rows[r] >= 0
        return bad
    nx = b - a
    jj = np.empty(m, np.int64)
    ww = np.empty(m)
    hole = window_weights(col_t[i0 + a : i0 + b], t_grid, jj, ww, period)
    for r in range(k):
        if rows[r] < 0:
            codes[r] = ROW_OK
            continue
        codes[r] = _row_on_weights(block_p[r, i0 + a : i0 + b], nx, hole, jj, ww, out[rows[r]])
        bad += codes[r] != ROW_OK
    return bad
