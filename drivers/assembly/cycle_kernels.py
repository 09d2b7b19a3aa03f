"""One numba call for the edges of a complete cycle window (drivers/cycles.py ``_advance_epoch``).

From the verified edges of the window (a run of the mirrored tooth-tick column) it gives in one pass what the
assembler built with a dozen numpy calls: the edge ticks, their epoch positions and wheel indices, their nominal
crank angles and the timer ticks at the grid angles (``drivers.assembly.resample.pchip_eval_kernel`` through the edges). Every
number comes from the same operations in the same order as the numpy reference (``cycle_edges_reference`` in
tests/drivers/test_cycle_kernels.py), so the results are bit for bit the same.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from frictionwatch.drivers.assembly.resample import pchip_eval_kernel
from frictionwatch.drivers.assembly.ringbuffer import search_sorted

_DEG = math.pi / 180.0  # np.radians(x) is x * (pi / 180)


@numba.njit(cache=True)
def cycle_edges(col, i0, m, o0, n, t, shift, a0_deg, grid, ticks, pos, index, theta, t_grid):
    """Edges col[i0 : i0 + m] (int64 ticks) of a window whose first edge has tooth ordinal o0 (wheel of n positions,
    t teeth): ticks, epoch positions ``(o // t) n + o % t``, wheel indices ``pos % n``, nominal angles
    ``radians(a0_deg + (pos + shift) 360 / n)`` [rad] and the ticks at the ``grid`` angles (monotone cubic through
    the edges, relative to the first edge) into the given arrays."""
    step = 360.0 / n
    for q in range(m):
        ticks[q] = col[i0 + q]
        o = o0 + q
        p = (o // t) * n + o % t
        pos[q] = p
        index[q] = p % n
        theta[q] = (a0_deg + (p + shift) * step) * _DEG
    rel = np.empty(m)
    for q in range(m):
        rel[q] = float(ticks[q] - ticks[0])
    pchip_eval_kernel(theta, rel, grid, t_grid)
    t0 = float(ticks[0])
    for i in range(grid.shape[0]):
        t_grid[i] += t0


# ---- sums bit for bit equal to np.add.reduce --------------------------------------------------------------------
# numpy reduces a contiguous float64 vector as 0.0 + pairwise_sum(a, n) (its identity, then the pairwise loop of
# numpy/_core/src/umath/loops_utils.h.src: < 8 values in order; up to 128 in 8 running partial sums combined as
# ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7)), then the tail; longer ones are halved recursively). The
# assembler's means (load over a cycle: ~10 rows, phase windows: 60 grid points) are taken here in one call instead
# of a numpy call per vector; the test (tests/drivers/test_reduce_kernels.py) compares the bytes with np.add.reduce
# over many lengths and magnitudes. Longer vectors than REDUCE_MAX stay with numpy (no recursion here: numba's cache
# does not load recursive functions safely). core.model.pairwise has the same loop for the monitor; drivers may not import
# it (tests/test_layering.py: drivers know core.types and core.model.engine only).
REDUCE_MAX = 128


@numba.njit(cache=True)
def _pairwise_sum(a, i0, n):
    """numpy's pairwise sum of a[i0 : i0 + n] (float64, n <= REDUCE_MAX)."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[i0 + i]
        return res
    r0, r1, r2, r3 = a[i0], a[i0 + 1], a[i0 + 2], a[i0 + 3]
    r4, r5, r6, r7 = a[i0 + 4], a[i0 + 5], a[i0 + 6], a[i0 + 7]
    i = 8
    stop = n - n % 8
    while i < stop:
        j = i0 + i
        r0 += a[j]
        r1 += a[j + 1]
        r2 += a[j + 2]
        r3 += a[j + 3]
        r4 += a[j + 4]
        r5 += a[j + 5]
        r6 += a[j + 6]
        r7 += a[j + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[i0 + i]
        i += 1
    return res


@numba.njit(cache=True)
def _add_reduce2(a, b, i0, n):
    """``float(np.add.reduce(a[i0 : i0 + n]))`` and the same of b (float64 vectors, n <= REDUCE_MAX): the load
    ring's torque and power columns over the same rows."""
    return 0.0 + _pairwise_sum(a, i0, n), 0.0 + _pairwise_sum(b, i0, n)


@numba.njit(cache=True)
def window_sums(t_col, a_col, b_col, i0, n, t_lo, t_hi):
    """(a, b, sum a, sum b): the rows [a, b) of the sorted ``t_col[i0 : i0 + n]`` (a mirrored ring column) within
    [t_lo, t_hi] (``np.searchsorted`` left / right, as ``RingBuffer.searchsorted``) and, if 0 < b - a <= REDUCE_MAX,
    ``np.add.reduce`` of ``a_col`` and ``b_col`` over them (else NaN): the load mean of a cycle in one call."""
    a = search_sorted(t_col, i0, n, t_lo, False)
    b = search_sorted(t_col, i0, n, t_hi, True)
    if 0 < b - a <= REDUCE_MAX:
        return a, b, 0.0 + _pairwise_sum(a_col, i0 + a, b - a), 0.0 + _pairwise_sum(b_col, i0 + a, b - a)
    return a, b, np.nan, np.nan


@numba.njit(cache=True)
def gather_sums(row, idx_a, idx_b):
    """(True, ``np.add.reduce(row[idx_a])``, ``np.add.reduce(row[idx_b])``) for a float64 row and int64 indices (at
    most REDUCE_MAX of each); (False, nan, nan) if an index is outside [0, len(row)) (the caller lets numpy raise)."""
    n = row.shape[0]
    ga = np.empty(idx_a.shape[0])
    for i in range(idx_a.shape[0]):
        k = idx_a[i]
        if k < 0 or k >= n:
            return False, np.nan, np.nan
        ga[i] = row[k]
    gb = np.empty(idx_b.shape[0])
    for i in range(idx_b.shape[0]):
        k = idx_b[i]
        if k < 0 or k >= n:
            return False, np.nan, np.nan
        gb[i] = row[k]
    return True, 0.0 + _pairwise_sum(ga, 0, ga.shape[0]), 0.0 + _pairwise_sum(gb, 0, gb.shape[0])
