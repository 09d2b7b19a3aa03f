"""One numba call per cylinder for a cycle's pressure row: window search in the mirrored ring storage, the
hole/NaN check and the linear interpolation at the grid times (drivers.cycle_parts.pressure_on_grid).

It replaces two ``RingBuffer.searchsorted`` calls, two views and the ``interp_checked`` wrapper (numpy call
overhead, ~10 us per cylinder) with the same arithmetic: the binary searches follow np.searchsorted's loop (NaN
ordered last) and the interpolation is ``drivers.resample._interp_sorted``. The plain reference is the
RingBuffer/np.searchsorted/interp_checked path (tests/drivers/test_pressure_kernels.py).
"""

from __future__ import annotations

import numba

from drivers.resample import CHECK_HOLE, CHECK_NAN, _interp_checked
from drivers.ringbuffer import _search_sorted as _search

ROW_OK, ROW_MISSING, ROW_HOLE, ROW_NAN = 0, 1, 2, 3


@numba.njit(cache=True)
def _pressure_row(col_t, col_p, start, end, t_grid, out):
    """Row of one pressure ring (mirrored columns col_t, col_p of length 2 cap, retained rows [start, end)) at the
    sorted times t_grid; returns ROW_OK (out filled), ROW_MISSING, ROW_HOLE or ROW_NAN."""
    n = end - start
    if n < 2:
        return ROW_MISSING
    cap = col_t.shape[0] // 2
    i0 = start % cap
    m = t_grid.shape[0]
    a = _search(col_t, i0, n, t_grid[0], True) - 1
    b = _search(col_t, i0, n, t_grid[m - 1], False) + 1
    if a < 0 or b > n:
        return ROW_MISSING
    code = _interp_checked(t_grid, col_t[i0 + a : i0 + b], col_p[i0 + a : i0 + b], out)
    if code == CHECK_HOLE:
        return ROW_HOLE
    if code == CHECK_NAN:
        return ROW_NAN
    return ROW_OK
