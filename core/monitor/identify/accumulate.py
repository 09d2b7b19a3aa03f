"""Normal equations accumulated across cycles with exponential forgetting, and an honest posterior.

One cycle of a many-cylinder engine cannot separate its coefficients (physics.md §12.5); cycle-to-cycle combustion
variation is natural excitation, so the monitor keeps the whitened normal equations

    N = sum_c lambda^(age_c) A_c^T A_c,   r = sum_c lambda^(age_c) A_c^T y_c

and solves them with the priors (a weak one per parameter, the Eq. 6 sharing per cylinder) and params >= 0.

Uncertainty has two parts:
- statistical: (N + N_prior)^-1, scaled up by the reduced chi^2 when the residual is larger than the noise model;
- systematic: errors that repeat every cycle (model error, residual tooth-spacing error, pressure calibration) do
  not average out. With B = sum_c lambda^age A_c^T D_c (D_c the whitening), a repeated raw error e moves params by
  N^-1 B e, so its covariance N^-1 B C_sys B^T N^-1 is added. C_sys comes from the persistent (mean) residual per
  harmonic and a stated relative model-error floor.

The numba kernels of one cycle's normal-equation terms and their exponentially weighted fold
(core.monitor.identify.accumulate.Accumulator.cycle_terms / fold): one call each instead of six numpy calls and seven array
expressions on (P, P) and (P, R) arrays.

Arithmetic against the numpy code they replace (tests/core/test_accumulate_kernels.py):
- A^T y and y^T y are the same BLAS calls (dgemv, ddot) numpy makes: bit-identical. They matter most: chi^2 =
  y^T y - 2 theta^T A^T y + theta^T A^T A theta cancels ~5 digits (core.monitor.identify.posterior).
- A^T A is a gemm where numpy calls syrk (another summation order: ~1e-18 of the largest entry), made exactly
  symmetric like syrk's result.
- A^T diag(1/sigma) and the reference rows' outer products are the same single products (bit-identical for one
  reference row; summed in row order for more); the fold lambda * old + new is rounded like numpy (no fused
  multiply-add: these kernels are compiled without fastmath).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np


@dataclass(frozen=True)
class Accumulator:
    """Exponentially weighted normal equations (P params, R raw rows per cycle incl. the mean-balance row).

    info (P, P), rhs (P,), yty whitened sum of squares, weight effective number of cycles, rows effective number of
    rows, sys_map (P, R) = sum lambda^age A^T D; raw_rows (R, P) and raw_target (R,): sum lambda^age of the raw
    (unwhitened) rows and targets over raw_weight effective cycles, so the accumulated cycles' mean residual at any
    estimate is at hand (``persistent_residual``; None: not kept, e.g. a state saved before they were)."""

    info: np.ndarray
    rhs: np.ndarray
    yty: float
    weight: float
    rows: float
    sys_map: np.ndarray
    info_reference: np.ndarray
    raw_rows: np.ndarray | None = None
    raw_target: np.ndarray | None = None
    raw_weight: float = 0.0

    def persistent_residual(self, params: np.ndarray) -> np.ndarray | None:
        """(R,) the accumulated cycles' mean raw residual at ``params``: target minus rows @ params, weighted as
        the equations are (None: raw rows not kept, or nothing accumulated)."""
        if self.raw_rows is None or self.raw_target is None or self.raw_weight <= 0.0:
            return None
        return (self.raw_target - self.raw_rows @ np.asarray(params, dtype=np.float64)) / self.raw_weight

    @staticmethod
    def empty(n_params: int, n_rows: int) -> Accumulator:
        return Accumulator(np.zeros((n_params, n_params)), np.zeros(n_params), 0.0, 0.0, 0.0,
                           np.zeros((n_params, n_rows)), np.zeros((n_params, n_params)))

    @staticmethod
    def of_terms(terms: CycleTerms) -> Accumulator:
        """One cycle's equations alone (``empty(...).fold(terms, 0.0)`` without the arithmetic)."""
        return Accumulator(terms.info, terms.rhs, terms.yty, 1.0, terms.rows, terms.sys_map, terms.info_reference)

    def update(self, a: np.ndarray, y: np.ndarray, inv_sigma: np.ndarray, forgetting: float,
               reference_rows: int = 0) -> Accumulator:
        """Fold in one cycle's whitened rows a (R, P), y (R,) whose raw rows were divided by 1/``inv_sigma`` (R,).

        The last ``reference_rows`` rows (the mean balance) are also kept apart in ``info_reference``: what the
        estimate would know without the speed signal, to tell resolved quantities from prior-driven ones."""
        return self.fold(self.cycle_terms(a, y, inv_sigma, reference_rows), forgetting)

    def cycle_terms(self, a: np.ndarray, y: np.ndarray, inv_sigma: np.ndarray, reference_rows: int = 0) -> CycleTerms:
        """One cycle's contribution (``update`` = ``fold(cycle_terms(...))``; computed once, it can be folded into
        several accumulators, e.g. the running one and this cycle's own). One kernel (``cycle_terms_kernel`` below);
        all arrays new, sys_map C-contiguous."""
        if a.shape != self.sys_map.shape[::-1]:
            raise ValueError(f"rows must have shape {self.sys_map.shape[::-1]}, got {a.shape}")
        ok, info, rhs, yty, sys_map, ref = cycle_terms_kernel(
            np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(y, dtype=np.float64),
            np.ascontiguousarray(inv_sigma, dtype=np.float64), int(reference_rows))
        if not ok:
            raise ValueError(f"y {np.shape(y)} and inv_sigma {np.shape(inv_sigma)} must have one value per row of "
                             f"a {a.shape}, and 0 <= reference_rows <= {a.shape[0]} (got {reference_rows})")
        return CycleTerms(info, rhs, yty, float(a.shape[0]), sys_map, ref)

    def fold(self, terms: CycleTerms, forgetting: float,
             raw: tuple[np.ndarray, np.ndarray] | None = None) -> Accumulator:
        """lambda * self + one cycle's ``terms`` (new arrays; self is unchanged); ``raw``: that cycle's raw rows
        (R, P) and targets (R,), summed into ``raw_rows`` / ``raw_target`` (None: those are dropped)."""
        lam = float(forgetting)
        if not 0.0 <= lam <= 1.0:
            raise ValueError(f"forgetting factor must be in [0, 1], got {lam}")
        ok, info, rhs, sys_map, ref = fold_kernel(
            lam, *(np.ascontiguousarray(x, dtype=np.float64) for x in (
                self.info, self.rhs, self.sys_map, self.info_reference, terms.info, terms.rhs, terms.sys_map,
                terms.info_reference)))
        if not ok:
            raise ValueError("the cycle's terms do not have the accumulator's shapes")
        raw_rows = raw_target = None
        raw_weight = 0.0
        if raw is not None:
            d, t = np.asarray(raw[0], dtype=np.float64), np.asarray(raw[1], dtype=np.float64)
            if d.shape != sys_map.shape[::-1] or t.shape != (sys_map.shape[1],):
                raise ValueError(f"raw rows {d.shape} and targets {t.shape} must be {sys_map.shape[::-1]} and "
                                 f"({sys_map.shape[1]},)")
            have = self.raw_rows is not None and self.raw_target is not None
            raw_rows = lam * self.raw_rows + d if have else d.copy()
            raw_target = lam * self.raw_target + t if have else t.copy()
            raw_weight = lam * self.raw_weight + 1.0 if have else 1.0
        return Accumulator(info, rhs, lam * self.yty + terms.yty, lam * self.weight + 1.0,
                           lam * self.rows + terms.rows, sys_map, ref, raw_rows, raw_target, raw_weight)


    def discounted(self, keep: float) -> Accumulator:
        """This accumulator with every cycle's weight x ``keep`` (0 < keep <= 1): a one-off forgetting step, after
        a detected change, so the estimate follows the new state instead of averaging the two. The systematic map
        is scaled with the information, so the systematic covariance N^-1 B C B^T N^-1 is unchanged (a repeated
        error does not average out over fewer cycles either)."""
        k = float(keep)
        if not 0.0 < k <= 1.0:
            raise ValueError(f"keep must be in (0, 1], got {k}")
        return Accumulator(self.info * k, self.rhs * k, self.yty * k, self.weight * k, self.rows * k,
                           self.sys_map * k, self.info_reference * k,
                           None if self.raw_rows is None else self.raw_rows * k,
                           None if self.raw_target is None else self.raw_target * k, self.raw_weight * k)


class CycleTerms(NamedTuple):
    """One cycle's whitened normal-equation terms (``Accumulator.cycle_terms``; immutable like the accumulator, a
    named tuple: built every cycle, it costs a third of a frozen dataclass)."""

    info: np.ndarray
    rhs: np.ndarray
    yty: float
    rows: float
    sys_map: np.ndarray
    info_reference: np.ndarray

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


def raw_rows(a: np.ndarray, y: np.ndarray, inv_sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The raw rows and targets of one cycle's whitened equations (a zero weight, a row not there: zeros)."""
    scale = np.divide(1.0, inv_sigma, out=np.zeros(inv_sigma.shape, inv_sigma.dtype), where=inv_sigma > 0.0)
    return a * scale[:, None], y * scale


def speed_budget(acc: Accumulator, params: np.ndarray, white, model_rel_error: float,
                 harmonics: np.ndarray) -> np.ndarray:
    """The repeatable-error variance per raw row (R,) of the accumulated equations: for the flywheel's M harmonics,
    the accumulated cycles' persistent residual at ``params`` (less its own sampling variance, var / W per
    component) or ``model_rel_error`` of this cycle's harmonic, whichever is larger; the other rows (the free end's,
    the mean balance) as the noise model states them.

    Not this cycle's noise statistics alone (``white.sys_var``: their 100-cycle EWMA of the residual at the previous
    estimate): after a load ramp that EWMA held the ramp's transient and the systematic sigma of every accumulated
    cycle rose with it (genset-v20, +-20 % profile, seed 29: a cylinder's from ~6 % to 9-17 % 100 cycles after a
    ramp, 17 measured cylinders to 3; design note 35)."""
    r = acc.persistent_residual(params)
    sys_var = np.array(white.sys_var, dtype=np.float64)
    if r is None:
        return sys_var
    m = white.freq.shape[0]
    mean2 = r[:m] ** 2 + r[m:2 * m] ** 2 - 2.0 * white.stats.var / max(acc.raw_weight, 1.0)
    e = model_rel_error * white.freq * np.abs(harmonics)
    v = np.maximum(mean2, e * e) / 2.0
    sys_var[:m] = v
    sys_var[m:2 * m] = v
    return sys_var


def accumulate_cycle(acc: Accumulator, white, forgetting: float, fold: bool, params: np.ndarray,
                     model_rel_error: float, harmonics: np.ndarray) -> tuple[CycleTerms, Accumulator, np.ndarray]:
    """One cycle's accumulation step: (the cycle's terms (the last row, the mean balance, as the reference), the
    accumulator after folding them in with ``forgetting`` and the raw rows when ``fold`` (else ``acc`` itself), the
    speed rows' repeatable-error budget at ``params`` on that accumulator). One kernel call
    (``cycle_step_kernel`` above) where ``accumulate_cycle_reference`` makes four helper calls and builds
    two records (design note 63); arrays of another dtype or layout, or shapes that do not fit, take the
    reference (which converts, or names what does not fit)."""
    lam = float(forgetting)
    if not 0.0 <= lam <= 1.0:
        return accumulate_cycle_reference(acc, white, lam, fold, params, model_rel_error, harmonics)
    kept = acc.raw_rows is not None and acc.raw_target is not None
    raw = (acc.raw_rows, acc.raw_target) if kept else (np.empty((0, 0)), np.empty(0))
    raw_weight = (lam * acc.raw_weight + 1.0 if kept else 1.0) if fold else acc.raw_weight
    try:
        ok, terms, arrays, budget = cycle_step_kernel(
            white.a, white.y, white.inv_sigma, lam, bool(fold),
            (acc.info, acc.rhs, acc.sys_map, acc.info_reference, *raw), raw_weight,
            np.asarray(params, dtype=np.float64), (white.sys_var, white.stats.var, white.freq, harmonics),
            float(model_rel_error))
    except TypeError:  # another dtype or layout: the reference converts
        ok = False
    if not ok:
        return accumulate_cycle_reference(acc, white, lam, fold, params, model_rel_error, harmonics)
    info, rhs, yty, sys_map, ref = terms
    terms = CycleTerms(info, rhs, yty, float(white.a.shape[0]), sys_map, ref)
    if fold:
        acc = Accumulator(*arrays[:2], lam * acc.yty + yty, lam * acc.weight + 1.0, lam * acc.rows + terms.rows,
                          *arrays[2:], raw_weight)
    return terms, acc, budget


def accumulate_cycle_reference(acc: Accumulator, white, forgetting: float, fold: bool, params: np.ndarray,
                               model_rel_error: float, harmonics: np.ndarray) -> tuple[CycleTerms, Accumulator,
                                                                                       np.ndarray]:
    """``accumulate_cycle`` by its helpers, one after another (its reference, and the general path)."""
    terms = acc.cycle_terms(white.a, white.y, white.inv_sigma, 1)  # the mean-balance row: reference
    if fold:
        acc = acc.fold(terms, forgetting, raw_rows(white.a, white.y, white.inv_sigma))
    return terms, acc, speed_budget(acc, params, white, model_rel_error, harmonics)
