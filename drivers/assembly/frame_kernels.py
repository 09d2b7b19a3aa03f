"""Kernels of ``drivers.assembly.frame_store.FrameGroup``: pressure rows that stay in the frames they came in.

A group's retained rows are split into chunks (one per filed frame). Chunk c starts at absolute row ``ci[c, 0]``
(increasing; it ends where chunk c + 1 starts, the last one at the group's ``end``); row s is column
``ci[c, 1] + s - ci[c, 0]`` of ``frames[c]`` (k, n) and was sampled at ``cf[c, 0] + (s - ci[c, 0]) * cf[c, 1]``
timer ticks: the very expression (same operands, same order) with which ``drivers.assembly.pressure_ring.write_frame``
fills a ring's time column, so a time computed here is the float a ring would hold.

The time search (``chunk_search``) runs numpy's binary-search loop over those computed times, so it returns the same
row as np.searchsorted on the equivalent ring, whatever the input: np.searchsorted itself would need the times
materialised (O(n) per search instead of O(log n)); the chunk lookup over ``ci`` is np.searchsorted. The resampling
then treats the window exactly as ``drivers.assembly.pressure_kernels.pressure_rows`` treats a ring's.
"""

from __future__ import annotations

import numba
import numpy as np
from frictionwatch.drivers.assembly.pressure_kernels import ROW_HOLE, ROW_MISSING, ROW_NAN, ROW_OK, window_weights
from frictionwatch.drivers.assembly.ringbuffer import sorts_before


@numba.njit(cache=True)
def _chunk_of(ci, n_chunks, s):
    """Index of the chunk holding absolute row s: the last chunk that starts at or before s (-1: none)."""
    return np.searchsorted(ci[:n_chunks, 0], s, side="right") - 1


@numba.njit(cache=True)
def _time_at(ci, cf, n_chunks, s):
    """Sample time [ticks] of absolute row s (retained)."""
    c = _chunk_of(ci, n_chunks, s)
    return cf[c, 0] + (s - ci[c, 0]) * cf[c, 1]


@numba.njit(cache=True)
def chunk_search(ci, cf, n_chunks, start, n, key, right):
    """np.searchsorted over the times of absolute rows [start, start + n) (computed, not stored): numpy's probes and
    NaN order (``sorts_before``), so the same answer as on a ring."""
    lo = 0
    hi = n
    while lo < hi:
        mid = lo + ((hi - lo) >> 1)
        v = _time_at(ci, cf, n_chunks, start + mid)
        go_right = (not sorts_before(key, v)) if right else sorts_before(v, key)
        if go_right:
            lo = mid + 1
        else:
            hi = mid
    return lo


@numba.njit(cache=True)
def chunk_times(ci, cf, n_chunks, a, b, out):
    """Sample times of the absolute rows [a, b) (retained) into out[0 : b - a]."""
    if b <= a:
        return
    c = _chunk_of(ci, n_chunks, a)
    for s in range(a, b):
        while c + 1 < n_chunks and ci[c + 1, 0] <= s:
            c += 1
        out[s - a] = cf[c, 0] + (s - ci[c, 0]) * cf[c, 1]


@numba.njit(cache=True)
def chunk_values(frames, ci, n_chunks, end, row, a, b, out):
    """Values of group row ``row`` for the absolute rows [a, b) (retained) into out[0 : b - a]."""
    if b <= a:
        return
    c = _chunk_of(ci, n_chunks, a)
    s = a
    while s < b:
        stop = min(ci[c + 1, 0] if c + 1 < n_chunks else end, b)
        src = frames[c]
        col = ci[c, 1] + s - ci[c, 0]
        for i in range(stop - s):  # element copy: a slice assignment compiles ~2 s longer
            out[s - a + i] = src[row, col + i]
        s = stop
        c += 1


@numba.njit(cache=True)
def frame_rows(frames, ci, cf, n_chunks, start, end, t_grid, rows, out, codes, x_buf):
    """Every row of a frame group (retained rows [start, end)) at the sorted times t_grid: row r into
    out[rows[r]] (rows[r] < 0: not wanted; a row that is not ROW_OK is left undefined), its code (ROW_*) into
    codes[r]; returns the number of wanted rows that are not ROW_OK.

    ``pressure_rows`` on the equivalent ring (the same arithmetic): the window's times are computed into x_buf (>= its
    length) and give the same window, hole and weights (``window_weights``); then each frame that holds part of
    the window is read once, in memory order: per wanted row the NaN check of its part (up to the first hole) and
    ``y[j] + w (y[j+1] - y[j])`` for the grid times whose interval j starts in it (y[j+1] may open the next frame)."""
    k = rows.shape[0]
    m = t_grid.shape[0]
    n = end - start
    a = 0
    b = 0
    whole = n >= 2
    if whole:
        # np.bool_, not a literal True/False: one chunk_search specialisation (the plain bool the Python callers
        # compile) serves both, not one more per literal value
        a = chunk_search(ci, cf, n_chunks, start, n, t_grid[0], np.bool_(True)) - 1
        b = chunk_search(ci, cf, n_chunks, start, n, t_grid[m - 1], np.bool_(False)) + 1
        whole = a >= 0 and b <= n
    bad = 0
    if not whole:
        for r in range(k):
            codes[r] = ROW_OK if rows[r] < 0 else ROW_MISSING
            bad += rows[r] >= 0
        return bad
    nx = b - a
    x = x_buf[:nx]
    chunk_times(ci, cf, n_chunks, start + a, start + b, x)
    jj = np.empty(m, np.int64)
    ww = np.empty(m)
    lo = start + a
    c = _chunk_of(ci, n_chunks, lo)
    # the frames' own sample period (the window's first chunk's; a group's frames share it): a hole the whole window
    # falls in is seen (window_weights)
    hole = window_weights(x, t_grid, jj, ww, cf[c, 1])
    interp = hole == nx - 1
    need = nx if interp else hole  # window samples whose NaN check counts (a row with a hole: up to it)
    nan = np.zeros(k, np.bool_)
    w0 = 0  # window index of the frame part's first sample
    i0 = 0  # first grid time not interpolated yet
    while w0 < need:
        w1 = min((ci[c + 1, 0] if c + 1 < n_chunks else end) - lo, need)
        src = frames[c]
        col = ci[c, 1] + lo + w0 - ci[c, 0]  # column of window sample w0
        i1 = i0  # grid times [i0, i1) have their interval j in this part; [i0, i2) also j + 1
        if interp:
            while i1 < m and jj[i1] < w1:
                i1 += 1
        i2 = i1
        while i2 > i0 and jj[i2 - 1] == w1 - 1:
            i2 -= 1
        straddle = interp and i2 < i1  # y[j + 1] is the next frame's first sample
        nxt = frames[c + 1] if straddle else src
        nxt_col = ci[c + 1, 1] if straddle else 0
        for r in range(k):
            if rows[r] < 0:
                continue
            y = src[r, col : col + w1 - w0]  # window samples [w0, w1) of this row
            f = False
            for q in range(w1 - w0):
                f |= y[q] != y[q]
            nan[r] |= f
            o = out[rows[r]]
            for i in range(i0, i2):
                # an unsigned index: numba wraps a negative signed one round the end, a test and branch per read
                # that kept this loop (~60 % of the kernel) ~20 % slower; j >= 0 here (its interval is in this part)
                j = np.uint64(jj[i] - w0)
                y0 = y[j]
                o[i] = y0 + ww[i] * (y[j + np.uint64(1)] - y0)
            for i in range(i2, i1):
                y0 = y[w1 - 1 - w0]
                o[i] = y0 + ww[i] * (nxt[r, nxt_col] - y0)
        i0 = i1
        w0 = w1
        c += 1
    for r in range(k):
        if rows[r] < 0:
            codes[r] = ROW_OK
        elif nan[r]:
            codes[r] = ROW_NAN
        elif not interp:
            codes[r] = ROW_HOLE
        else:
            codes[r] = ROW_OK
        bad += codes[r] != ROW_OK
    return bad
