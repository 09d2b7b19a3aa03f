"""Periodic row interpolation: ``interp_rows_periodic`` (numba ``_interp_rows``) is np.interp for many rows at once
on one closed period (core.monitor.report.cycle_report)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def _interp_rows(xq, xp, fp, out):
    """np.interp of every row of fp (r, n) at xq (m,), with xp (n + 1,) increasing and fp's value at xp[n] equal to
    its first column (one period closed). The bracket is searched once per query and used for all rows; the
    arithmetic is np.interp's: slope (fp[j+1] - fp[j]) / (xp[j+1] - xp[j]) times (x - xp[j]) plus fp[j]."""
    n = xp.shape[0] - 1
    rows = fp.shape[0]
    for i in range(xq.shape[0]):
        x = xq[i]
        if x >= xp[n]:
            for k in range(rows):
                out[k, i] = fp[k, 0]
            continue
        if x <= xp[0]:
            for k in range(rows):
                out[k, i] = fp[k, 0]
            continue
        lo = 0
        hi = n
        while hi - lo > 1:  # xp[lo] <= x < xp[hi]
            mid = (lo + hi) >> 1
            if xp[mid] <= x:
                lo = mid
            else:
                hi = mid
        j = lo
        if x == xp[j]:
            for k in range(rows):
                out[k, i] = fp[k, j]
            continue
        dxp = xp[j + 1] - xp[j]
        for k in range(rows):
            y0 = fp[k, j]
            y1 = fp[k, j + 1] if j + 1 < n else fp[k, 0]
            out[k, i] = (y1 - y0) / dxp * (x - xp[j]) + y0


def interp_rows_periodic(xq: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """Rows fp (r, n), sampled at xp (n + 1,) increasing with fp[:, 0] repeated at xp[n], at queries xq (m,).

    Same numbers as ``np.interp(xq, xp, np.append(row, row[0]))`` for each row."""
    q = np.ascontiguousarray(xq, dtype=np.float64)
    x = np.ascontiguousarray(xp, dtype=np.float64)
    f = np.ascontiguousarray(np.atleast_2d(fp), dtype=np.float64)
    if x.ndim != 1 or f.shape[1] + 1 != x.shape[0] or f.shape[1] < 1:
        raise ValueError(f"xp must have one point more than the rows of fp, got {x.shape} and {f.shape}")
    if np.any(np.diff(x) <= 0):
        raise ValueError("xp must be strictly increasing")
    out = np.empty((f.shape[0], q.shape[0]))
    _interp_rows(q, x, f, out)
    return out
