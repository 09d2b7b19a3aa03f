"""Numba kernels of one cycle's normal-equation terms and their exponentially weighted fold
(core.monitor.identify.accumulate.Accumulator.cycle_terms / fold): one call each instead of six numpy calls and seven array
expressions on (P, P) and (P, R) arrays.

Arithmetic against the numpy code they replace (tests/core/test_accumulate_kernels.py):
- A^T y and y^T y are the same BLAS calls (dgemv, ddot) numpy makes: bit-identical. They matter most: chi^2 =
  y^T y - 2 theta^T A^T y + theta^T A^T A theta cancels ~5 digits (core.monitor.identify.posterior_kernels).
- A^T A is a gemm where numpy calls syrk (another summation order: ~1e-18 of the largest entry), made exactly
  symmetric like syrk's result.
- A^T diag(1/sigma) and the reference rows' outer products are the same single products (bit-identical for one
  reference row; summed in row order for more); the fold lambda * old + new is rounded like numpy (no fused
  multiply-add: these kernels are compiled without fastmath).
"""

from __future__ import annotations

import numba
import numpy as np

_M = numba.types.Array(numba.float64, 2, "C")
_V = numba.types.Array(numba.float64, 1, "C")
# explicit signatures: any other dtype or layout raises TypeError at the call (the callers convert then) instead
# of compiling another specialisation


@numba.njit(cache=True)
def _scaled_sum(lam, old, new):
    """lam * old + new for C-contiguous (n, m) arrays, as one flat loop."""
    n, m = old.shape
    out = np.empty((n, m))
    _scaled_sum_1d_into(lam, old.reshape(n * m), new.reshape(n * m), out.reshape(n * m))
    return out


@numba.njit(cache=True)
def _scaled_sum_1d_into(lam, old, new, out):
    for i in range(old.shape[0]):
        out[i] = lam * old[i] + new[i]


@numba.njit(cache=True)
def _scaled_sum_1d(lam, old, new):
    out = np.empty(old.shape[0])
    _scaled_sum_1d_into(lam, old, new, out)
    return out


@numba.njit(cache=True)
def _cycle_terms(a, y, inv_sigma, reference_rows):
    r, p = a.shape
    if y.shape[0] != r or inv_sigma.shape[0] != r or not 0 <= reference_rows <= r:
        e2 = np.empty((0, 0))
        return False, e2, np.empty(0), 0.0, e2, e2
    info = np.dot(a.T, a)
    for i in range(p):  # exactly symmetric (numpy's syrk is)
        for j in range(i):
            info[j, i] = info[i, j]
    rhs = np.dot(a.T, y)
    yty = np.dot(y, y)
    sys_map = np.empty((p, r))
    for i in range(p):
        for k in range(r):
            sys_map[i, k] = a[k, i] * inv_sigma[k]
    ref = np.zeros((p, p))
    for k in range(r - reference_rows, r):
        for i in range(p):
            f = a[k, i]
            for j in range(p):
                ref[i, j] += f * a[k, j]
    return True, info, rhs, yty, sys_map, ref


@numba.njit([(_M, _V, _V, numba.int64)], cache=True)
def cycle_terms_kernel(a, y, inv_sigma, reference_rows):
    """One cycle's terms from whitened rows a (R, P), targets y (R,), raw-row weights inv_sigma (R,); the last
    ``reference_rows`` rows also go into info_reference.

    Returns (ok, info (P, P), rhs (P,), yty, sys_map (P, R), info_reference (P, P)); ok False (arrays empty) when
    y, inv_sigma or reference_rows do not fit a."""
    return _cycle_terms(a, y, inv_sigma, reference_rows)


@numba.njit(cache=True)
def _fold(lam, info, rhs, sys_map, info_reference, t_info, t_rhs, t_map, t_ref):
    if (info.shape != t_info.shape or rhs.shape != t_rhs.shape or sys_map.shape != t_map.shape
            or info_reference.shape != t_ref.shape):
        e2 = np.empty((0, 0))
        return False, e2, np.empty(0), e2, e2
    return (True, _scaled_sum(lam, info, t_info), _scaled_sum_1d(lam, rhs, t_rhs), _scaled_sum(lam, sys_map, t_map),
            _scaled_sum(lam, info_reference, t_ref))


@numba.njit([(numba.float64, _M, _V, _M, _M, _M, _V, _M, _M)], cache=True)
def fold_kernel(lam, info, rhs, sys_map, info_reference, t_info, t_rhs, t_map, t_ref):
    """lam * (info, rhs, sys_map, info_reference) + (t_info, t_rhs, t_map, t_ref), as new arrays.

    Returns (ok, info, rhs, sys_map, info_reference); ok False (arrays empty) when the shapes differ."""
    return _fold(lam, info, rhs, sys_map, info_reference, t_info, t_rhs, t_map, t_ref)


_RAW = numba.types.Tuple((_M, _V))  # raw rows (R, P) and targets (R,)


@numba.njit([(numba.float64, _M, _V, _M, _M, _M, _V, _M, _M, _RAW, _RAW)], cache=True)
def fold_raw_kernel(lam, info, rhs, sys_map, info_reference, t_info, t_rhs, t_map, t_ref, raw, cycle_raw):
    """``fold_kernel`` and the raw sums lam * raw + cycle_raw, each a pair (rows (R, P), targets (R,)), in one call
    (the accumulator's fold with its raw rows kept: six sums, numpy's rounding, one dispatch instead of one and four
    numpy expressions). Returns (ok, info, rhs, sys_map, info_reference, raw_rows, raw_target); ok False (arrays
    empty) when a shape differs."""
    raw_rows, raw_target = raw
    d, t = cycle_raw
    if raw_rows.shape != d.shape or raw_target.shape != t.shape or d.shape != sys_map.shape[::-1]:
        e2 = np.empty((0, 0))
        return False, e2, np.empty(0), e2, e2, e2, np.empty(0)
    ok, a, b, c, e = _fold(lam, info, rhs, sys_map, info_reference, t_info, t_rhs, t_map, t_ref)
    return ok, a, b, c, e, _scaled_sum(lam, raw_rows, d), _scaled_sum_1d(lam, raw_target, t)
