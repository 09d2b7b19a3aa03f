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
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
import scipy.linalg.lapack
from frictionwatch.core.monitor.identify.accumulate_kernels import cycle_terms_kernel, fold_kernel
from frictionwatch.core.monitor.identify.layout import bounded_solve_nnls
from frictionwatch.core.monitor.identify.posterior_kernels import (
    BAD_SHAPE,
    NEEDS_BOUND,
    OK,
    as_matrix,
    as_vector,
    lower_vector,
    posterior_kernel,
    posterior_moments_kernel,
)

_potrf = scipy.linalg.lapack.dpotrf
_potri = scipy.linalg.lapack.dpotri


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
        several accumulators, e.g. the running one and this cycle's own). One kernel (core.monitor.identify.accumulate_kernels);
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


@dataclass(frozen=True)
class Prior:
    """Gaussian prior rows: sum over rows of ((row @ params - target) / sigma)^2."""

    rows: np.ndarray  # (Q, P)
    target: np.ndarray  # (Q,)
    sigma: np.ndarray  # (Q,)

    def normal(self) -> tuple[np.ndarray, np.ndarray]:
        w = self.rows / self.sigma[:, None]
        return w.T @ w, w.T @ (self.target / self.sigma)

    @staticmethod
    def stack(*priors: Prior) -> Prior:
        return Prior(np.vstack([p.rows for p in priors]), np.concatenate([p.target for p in priors]),
                     np.concatenate([p.sigma for p in priors]))


@dataclass(frozen=True)
class Posterior:
    """params (P,), covariance (P, P) = statistical + systematic, chi2 reduced, weight (effective cycles)."""

    params: np.ndarray
    covariance: np.ndarray
    cov_statistical: np.ndarray
    chi2_reduced: float
    weight: float
    cov_reference: np.ndarray  # priors + mean balance only (no speed signal)

    def head(self, n: int) -> Posterior:
        """The marginal posterior of the first ``n`` parameters (e.g. friction without the nuisances)."""
        return Posterior(self.params[:n], self.covariance[:n, :n], self.cov_statistical[:n, :n], self.chi2_reduced,
                         self.weight, self.cov_reference[:n, :n])

    def data_gain(self, rows: np.ndarray) -> np.ndarray:
        """1 - var_posterior / var_reference of linear functions rows (Q, P) @ params: the share of what is known
        about them that the speed signal contributed (0: prior and mean balance only, 1: all from the speed)."""
        r = np.atleast_2d(rows)
        post = _quadratic_forms(r, self.cov_statistical)
        ref = _quadratic_forms(r, self.cov_reference)
        # a function the reference already pins down (e.g. a share of one cylinder) is not left to any prior
        pinned = ref <= 1e-12 * max(float(np.max(ref, initial=0.0)), 1e-300) + 1e-300
        return np.where(pinned, 1.0, np.clip(1.0 - post / np.maximum(ref, 1e-300), 0.0, 1.0))

    def sigma_of(self, rows: np.ndarray) -> np.ndarray:
        """1-sigma of linear functions rows (Q, P) @ params."""
        r = np.atleast_2d(rows)
        return np.sqrt(np.clip(_quadratic_forms(r, self.covariance), 0.0, None))

    def diagonal_gain(self) -> np.ndarray:
        """``data_gain(np.eye(P))`` from the diagonals alone."""
        post = np.diag(self.cov_statistical)
        ref = np.diag(self.cov_reference)
        pinned = ref <= 1e-12 * max(float(np.max(ref, initial=0.0)), 1e-300) + 1e-300
        return np.where(pinned, 1.0, np.clip(1.0 - post / np.maximum(ref, 1e-300), 0.0, 1.0))


def _quadratic_forms(rows: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """r_q^T C r_q for every row r_q of rows (Q, P)."""
    return np.einsum("qp,qp->q", rows @ cov, rows)


def solve_posterior(acc: Accumulator, prior: Prior, sys_var: np.ndarray,
                    lower: float | np.ndarray = 0.0) -> Posterior:
    """Bounded MAP estimate (params >= lower; -inf marks a free nuisance) and its covariance.

    sys_var (R,): variance of the error that repeats every cycle, per raw row, in raw units squared."""
    n_pr, r_pr = prior.normal()
    return posterior_from_normal(acc, n_pr, r_pr, sys_var, lower)


def posterior_from_normal(acc: Accumulator, n_pr: np.ndarray, r_pr: np.ndarray, sys_var: np.ndarray,
                          lower: float | np.ndarray = 0.0) -> Posterior:
    """``solve_posterior`` with the prior already in normal form (n_pr (P, P), r_pr (P,); ``Prior.normal``), so a
    caller that keeps a fixed prior's normal equations does not rebuild them every cycle.

    The numba kernel (core.monitor.identify.posterior_kernels) solves the unconstrained problem from one inverse; when a
    bound is active NNLS decides the parameters and the kernel forms the moments at them; when a factor is nearly
    singular or the reference covariance is at its pseudo-inverse switch, ``posterior_from_normal_reference``
    (LAPACK) decides. Every returned array is new (none aliases an input)."""
    p, r = acc.sys_map.shape
    f64 = np.float64
    n_pr, r_pr, sys_var = np.asarray(n_pr, dtype=f64), np.asarray(r_pr, dtype=f64), np.asarray(sys_var, dtype=f64)
    lo = lower_vector(lower, p)
    # the kernel checks every shape; the accumulator's own arrays are float64 and C-contiguous by construction (its
    # kernels, ``empty``): no per-call copies (another layout would only be another compiled specialisation)
    info, rhs, sys_map, info_ref = acc.info, acc.rhs, acc.sys_map, acc.info_reference
    yty, rows = float(acc.yty), float(acc.rows)
    status, params, chi2_red, cov_stat, cov, ref = posterior_kernel(
        info, rhs, yty, rows, sys_map, info_ref, n_pr, r_pr, sys_var, lo, REFERENCE_MAX_CONDITION)
    if status == BAD_SHAPE:  # name the input that does not fit
        as_matrix(n_pr, p, name="n_pr")
        as_vector(r_pr, p, "r_pr")
        as_vector(sys_var, r, "sys_var")
        raise ValueError(f"the accumulator's arrays do not fit its sys_map {acc.sys_map.shape}")
    if status == NEEDS_BOUND:
        params = bounded_solve_nnls(info + n_pr, rhs + r_pr, lo)
        status, chi2_red, cov_stat, cov, ref = posterior_moments_kernel(
            info, rhs, yty, rows, sys_map, info_ref, n_pr, sys_var, params, REFERENCE_MAX_CONDITION)
    if status != OK:
        return posterior_from_normal_reference(acc, n_pr, r_pr, sys_var, lo)
    return Posterior(params=params, covariance=cov, cov_statistical=cov_stat, chi2_reduced=float(chi2_red),
                     weight=acc.weight, cov_reference=ref)


REFERENCE_MAX_CONDITION = 1e12  # above: the reference covariance is a pseudo-inverse


def posterior_from_normal_reference(acc: Accumulator, n_pr: np.ndarray, r_pr: np.ndarray, sys_var: np.ndarray,
                                    lower: float | np.ndarray = 0.0) -> Posterior:
    """``posterior_from_normal`` by LAPACK/scipy calls: the general path (non-positive-definite or nearly singular
    matrices) and the reference of the kernel."""
    info = acc.info + n_pr
    rhs = acc.rhs + r_pr
    params = bounded_solve_nnls(info, rhs, lower)
    dof = acc.rows - params.shape[0]
    chi2 = acc.yty - 2.0 * params @ acc.rhs + params @ acc.info @ params
    chi2_red = float(chi2 / dof) if dof > 0 else 1.0
    inv = spd_inverse(info)
    if inv is None:
        inv = np.linalg.inv(info)
        inv = 0.5 * (inv + inv.T)
    cov_stat = inv * max(1.0, chi2_red)
    g = inv @ acc.sys_map
    cov_sys = (g * sys_var[None, :]) @ g.T
    ref_info = acc.info_reference + n_pr
    ref = spd_inverse_decoupled(ref_info, max_condition=REFERENCE_MAX_CONDITION)
    if ref is None:  # (near-)singular: the pseudo-inverse drops what nothing pins down
        ref = np.linalg.pinv(ref_info, rcond=1e-13, hermitian=True)
    ref = ref * max(1.0, chi2_red)
    return Posterior(params=params, covariance=cov_stat + cov_sys, cov_statistical=cov_stat, chi2_reduced=chi2_red,
                     weight=acc.weight, cov_reference=ref)


def spd_inverse_lower(a: np.ndarray) -> np.ndarray | None:
    """The inverse of a symmetric positive-definite matrix in the lower triangle of the result (LAPACK potrf then
    potri; the upper triangle holds the factor's leftovers); None if ``a`` is not numerically positive definite. For
    a caller that mirrors the triangle itself (the pull check's kernel): the symmetrisation is ~half the cost of a
    47 x 47 inverse."""
    c, info = _potrf(a, lower=True, clean=False, overwrite_a=False)
    if info != 0:
        return None
    inv, info = _potri(c, lower=True, overwrite_c=True)
    return inv if info == 0 else None


def spd_inverse(a: np.ndarray, max_condition: float = np.inf) -> np.ndarray | None:
    """Inverse of a symmetric positive-definite matrix by Cholesky (LAPACK potrf/potri), exactly symmetric; None if
    ``a`` is not numerically positive definite or its condition number may exceed ``max_condition`` (bounded by
    trace(a) trace(a^-1) >= lambda_max / lambda_min)."""
    inv = spd_inverse_lower(a)
    if inv is None:
        return None
    inv = np.tril(inv) + np.tril(inv, -1).T  # potri fills the lower triangle only
    if np.isfinite(max_condition):
        bound = float(np.trace(a)) * float(np.trace(inv))
        if not bound < max_condition:
            return None
    return inv


def spd_inverse_decoupled(a: np.ndarray, max_condition: float = np.inf) -> np.ndarray | None:
    """``spd_inverse`` of a matrix whose trailing rows may have no off-diagonal entry (the reference information:
    nuisances that only their priors see): the coupled head by ``spd_inverse``'s calls (potrf, potri), the diagonal
    tail by reciprocals; None as ``spd_inverse`` (not positive definite, or trace(a) trace(a^-1) not below
    ``max_condition``). The reference of core.monitor.identify.spd_kernels.lapack_inverse_of_sum (equal bits)."""
    n = a.shape[0]
    coupled = np.flatnonzero(np.any(np.tril(a, -1) != 0.0, axis=1))
    k = int(coupled[-1]) + 1 if coupled.size else 0
    tail = np.diag(a)[k:]
    if not np.all(tail > 0.0):
        return None
    inv = np.zeros((n, n))
    if k:
        head = spd_inverse_lower(np.ascontiguousarray(a[:k, :k]))
        if head is None:
            return None
        inv[:k, :k] = np.tril(head) + np.tril(head, -1).T
    inv[k:, k:] = np.diag(1.0 / tail)
    if np.isfinite(max_condition) and not float(np.trace(a)) * float(np.trace(inv)) < max_condition:
        return None
    return inv


@dataclass(frozen=True)
class ResidualStats:
    """Per-row residual statistics across cycles (EWMA): mean (persistent part) and variance about it (random part).

    Used as the noise model (whitening) and the systematic-error budget. Rows are complex harmonics (M,) plus the
    mean balance as a real scalar."""

    mean: np.ndarray  # (M,) complex
    var: np.ndarray  # (M,) per real component
    balance_mean: float
    balance_var: float
    count: int

    @staticmethod
    def empty(n_harmonics: int) -> ResidualStats:
        return ResidualStats(np.zeros(n_harmonics, complex), np.zeros(n_harmonics), 0.0, 0.0, 0)

    def update(self, resid: np.ndarray, balance_resid: float, memory: float) -> ResidualStats:
        """Fold in one cycle's residuals; ``memory`` is the EWMA factor (e.g. 1 - 1/50); the first cycles average."""
        n = self.count + 1
        g = max(1.0 - memory, 1.0 / n)
        d = resid - self.mean
        db = balance_resid - self.balance_mean
        return replace(
            self,
            mean=self.mean + g * d,
            var=(1.0 - g) * (self.var + g * 0.5 * np.abs(d) ** 2) if n > 1 else 0.5 * np.abs(resid) ** 2,
            balance_mean=self.balance_mean + g * db,
            balance_var=(1.0 - g) * (self.balance_var + g * db * db) if n > 1 else balance_resid**2,
            count=n,
        )
