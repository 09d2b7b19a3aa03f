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
# cycle_terms_kernel and fold_kernel compile when first called (Accumulator.cycle_terms / fold convert their inputs
# to C-ordered float64 first: one specialisation); the monitor's every cycle runs cycle_step_kernel, whose explicit
# signature makes another dtype or layout a TypeError at the call (its caller takes the reference then) instead of
# another specialisation


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


@numba.njit(cache=True)
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


@numba.njit(cache=True)
def fold_kernel(lam, info, rhs, sys_map, info_reference, t_info, t_rhs, t_map, t_ref):
    """lam * (info, rhs, sys_map, info_reference) + (t_info, t_rhs, t_map, t_ref), as new arrays.

    Returns (ok, info, rhs, sys_map, info_reference); ok False (arrays empty) when the shapes differ."""
    return _fold(lam, info, rhs, sys_map, info_reference, t_info, t_rhs, t_map, t_ref)


_ACC = numba.types.Tuple((_M, _V, _M, _M, _M, _V))  # info, rhs, sys_map, info_reference, raw rows, raw targets
_BUDGET = numba.types.Tuple((_V, _V, _V, numba.types.Array(numba.complex128, 1, "C")))  # sys_var, var, freq, harm.


@numba.njit(cache=True)
def _raw_rows(a, y, inv_sigma):
    """identification.raw_rows: the raw rows and targets (a zero weight: zeros), numpy's rounding (1 / w, then x)."""
    r, p = a.shape
    d = np.empty((r, p))
    t = np.empty(r)
    for k in range(r):
        s = 1.0 / inv_sigma[k] if inv_sigma[k] > 0.0 else 0.0
        for i in range(p):
            d[k, i] = a[k, i] * s
        t[k] = y[k] * s
    return d, t


@numba.njit(cache=True)
def _speed_budget(raw_rows, raw_target, raw_weight, params, budget, model_rel_error):
    """identification.speed_budget on the accumulator's raw sums, element by element in numpy's order and
    roundings (loops, not array expressions: a fifth of the compile time)."""
    sys_var, var, freq, harmonics = budget
    out = sys_var.copy()
    if raw_weight <= 0.0:
        return out
    r = np.dot(raw_rows, params)  # the BLAS call numpy's matmul makes
    m = freq.shape[0]
    w = max(raw_weight, 1.0)
    for j in range(m):
        re = (raw_target[j] - r[j]) / raw_weight
        im = (raw_target[m + j] - r[m + j]) / raw_weight
        mean2 = re * re + im * im - 2.0 * var[j] / w
        e = model_rel_error * freq[j] * abs(harmonics[j])
        e2 = e * e
        v = (mean2 if mean2 >= e2 or np.isnan(mean2) else e2) / 2.0  # np.maximum: NaN propagates
        out[j] = v
        out[m + j] = v
    return out


@numba.njit([(_M, _V, _V, numba.float64, numba.boolean, _ACC, numba.float64, _V, _BUDGET, numba.float64)],
            cache=True)
def cycle_step_kernel(a, y, inv_sigma, lam, fold, acc, raw_weight, params, budget, model_rel_error):
    """One cycle's accumulation step in one call (identification.accumulate_cycle; its reference
    ``accumulate_cycle_reference`` is the chain it replaces: Accumulator.cycle_terms with the last row as reference,
    raw_rows, Accumulator.fold with the raw sums when ``fold``, speed_budget): whitened rows a (R, P), y (R,),
    inv_sigma (R,); the accumulator's arrays ``acc`` (info, rhs, sys_map, info_reference, raw rows (R, P), raw
    targets (R,); raw rows (0, 0) and targets (0,): not kept, as a fresh accumulator's) and ``raw_weight`` (after the
    fold); the estimate ``params`` (P,); ``budget`` (sys_var (R,), the statistics' var (M,), freq (M,), harmonics
    (M,) complex).

    Returns (ok, the cycle's terms (info, rhs, yty, sys_map, info_reference), the accumulator's arrays after the
    step (``acc`` itself without a fold; a fold without raw rows kept starts them from this cycle's), the speed
    rows' budget (R,): sys_var where no raw rows are kept); ok False (all arrays empty) when a shape does not fit."""
    info, rhs, sys_map, ref, raw_rows, raw_target = acc
    sys_var, var, freq, harmonics = budget
    r, p = a.shape
    m = freq.shape[0]
    e2, e1 = np.empty((0, 0)), np.empty(0)
    kept = raw_rows.shape[0] != 0
    fits = ((not kept or (raw_rows.shape[0] == r and raw_rows.shape[1] == p and raw_target.shape[0] == r))
            and (kept or (raw_rows.shape[1] == 0 and raw_target.shape[0] == 0))
            and params.shape[0] == p and sys_var.shape[0] == r and var.shape[0] == m and harmonics.shape[0] == m
            and 2 * m <= r and sys_map.shape[0] == p and sys_map.shape[1] == r)
    ok, t_info, t_rhs, yty, t_map, t_ref = _cycle_terms(a, y, inv_sigma, 1)
    if not (fits and ok):
        return False, (e2, e1, 0.0, e2, e2), (e2, e1, e2, e2, e2, e1), e1
    if fold:
        d, t = _raw_rows(a, y, inv_sigma)
        ok, info, rhs, sys_map, ref = _fold(lam, info, rhs, sys_map, ref, t_info, t_rhs, t_map, t_ref)
        if not ok:
            return False, (e2, e1, 0.0, e2, e2), (e2, e1, e2, e2, e2, e1), e1
        if kept:
            raw_rows, raw_target = _scaled_sum(lam, raw_rows, d), _scaled_sum_1d(lam, raw_target, t)
        else:
            raw_rows, raw_target, kept = d, t, True
    out = _speed_budget(raw_rows, raw_target, raw_weight if kept else 0.0, params, budget, model_rel_error)
    return True, (t_info, t_rhs, yty, t_map, t_ref), (info, rhs, sys_map, ref, raw_rows, raw_target), out
