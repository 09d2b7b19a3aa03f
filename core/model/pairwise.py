"""Sums in numpy's order, for kernels whose numbers must equal the numpy steps they replace to the last bit:
``pairwise_sum`` is np.add.reduce of a contiguous float64 vector (numpy/_core/src/umath/loops_utils.h.src: below 8
values in order; up to 128 in eight running partial sums combined as ((r0 + r1) + (r2 + r3)) + ((r4 + r5) +
(r6 + r7)), then the tail; longer vectors halved at a multiple of 8). Plain numerics for the monitor's kernels
(core.monitor.monitor_kernels, core.monitor.report_kernels, core.model.dynamics); tested against np.add.reduce in
tests/core/test_monitor_kernels.py. drivers.assembly.cycle_kernels keeps its own copy of the loop (drivers may import only
core.types and core.model.engine).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def _pairwise_block(a, lo, n):
    """numpy's pairwise_sum for n <= 128: a plain loop below 8, else eight running sums."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0 = a[lo]
    r1 = a[lo + 1]
    r2 = a[lo + 2]
    r3 = a[lo + 3]
    r4 = a[lo + 4]
    r5 = a[lo + 5]
    r6 = a[lo + 6]
    r7 = a[lo + 7]
    m = n - n % 8
    i = 8
    while i < m:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@numba.njit(cache=True)
def pairwise_sum(a, lo, n):
    """Sum of a[lo:lo + n] in numpy's pairwise order (np.add.reduce of a contiguous float64 array). Above 128
    numpy halves recursively (at a multiple of 8); that tree is walked here with an explicit stack (numba's cache
    does not reload recursive functions reliably)."""
    if n <= 128:
        return _pairwise_block(a, lo, n)
    los = np.empty(64, dtype=np.int64)
    ns = np.empty(64, dtype=np.int64)
    stage = np.empty(64, dtype=np.int64)
    vals = np.empty(64)
    top = 0
    los[0] = lo
    ns[0] = n
    stage[0] = 0
    nv = 0
    while top >= 0:
        k = ns[top]
        if k <= 128:
            vals[nv] = _pairwise_block(a, los[top], k)
            nv += 1
            top -= 1
            continue
        n2 = k // 2
        n2 -= n2 % 8
        if stage[top] == 0:  # left half first
            stage[top] = 1
            los[top + 1] = los[top]
            ns[top + 1] = n2
            stage[top + 1] = 0
            top += 1
        elif stage[top] == 1:  # then the right half
            stage[top] = 2
            los[top + 1] = los[top] + n2
            ns[top + 1] = k - n2
            stage[top + 1] = 0
            top += 1
        else:  # both halves done: left + right
            vals[nv - 2] = vals[nv - 2] + vals[nv - 1]
            nv -= 1
            top -= 1
    return vals[0]
