"""The friction posterior: its records (Prior, Posterior), ``posterior_from_normal`` with its LAPACK reference, and the
numba kernels of the MAP estimate and its moments for the monitor's sizes (P <= ~50 parameters; the bounded solve: bounded_solve.py).

The bounded problem min params^T N params - 2 r^T params, params >= lower, is convex with N positive definite: when the
unconstrained minimiser (free nuisances eliminated exactly) already satisfies the bounds, it is the bounded optimum,
and NNLS is needed only when a bound is active. These kernels do that common case - Cholesky factors, triangular
solves and SPD inverses of small matrices, where the time of the scipy/LAPACK path went into Python call overhead -
and report a status instead of guessing near any decision the reference makes differently:

- ``NEEDS_BOUND``: a bound is active, or so nearly active (``FEASIBLE_MARGIN``) that NNLS's own tolerance decides;
- ``FALLBACK``: the information's factor has a smallest pivot ratio L_jj^2 / A_jj below
  ``INFORMATION_PIVOT_RATIO_MIN`` (``PIVOT_RATIO_MIN`` in bounded_solve_kernel), the reference information is not
  positive definite, or the trace bound of the reference covariance is near ``max_condition``
  (the reference switches to a pseudo-inverse there). The reference covariance has no pivot-ratio test: it is
  inverted by the reference's own LAPACK calls (spd.lapack_inverse_of_sum, its bits), because its
  condition grows with the accumulated cycles (a balance row against fixed priors, design note 75).

The callers then run the reference code (kept verbatim), so their behaviour in those cases is exactly the old one.
Otherwise the results equal the reference to rounding (<= 1e-10 relative on the monitor's matrices, whose scaled
condition numbers are ~1e2..5e3; tests/core/test_posterior_kernels.py).

``posterior_kernel`` (genset-v20, P = 47) works from one inverse of N = acc.info + n_pr:
- params = (N + 1e-12 D^2)^-1 r (the reference's ridge on the unit-diagonal problem) as N^-1 r and the ridge's
  Neumann series in N^-1, summed to 1e-16 relative, so the bounded solve needs no factor of its own;
- both inverses are the reference's own LAPACK calls (core.monitor.identify.spd: potrf, potri on the raw
  matrix, N's whole, the reference information's coupled head), its bits: N's condition grows with the accumulated
  cycles on genset-v20 (design note 80), the reference information's on every engine (note 75);
- a decoupled diagonal tail (the monitor's reference information: nuisances that only their priors see) is
  inverted by reciprocals, the head alone by LAPACK;
- chi^2 = y^T y - 2 params^T r + params^T A params cancels ~5 digits: it takes the reference's BLAS calls (ddot,
  dgemv) in its order, so its rounding is reproduced rather than a different one added;
- the systematic covariance G S G^T (G = N^-1 B) is W^T W, W = S^1/2 B^T N^-1: two transposed-first gemms.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from frictionwatch.core.monitor.identify.bounded_solve import (
    BAD_SHAPE,
    FALLBACK,
    FEASIBLE_MARGIN,
    NEEDS_BOUND,
    OK,
    REGULARISATION,
    bounded_solve_nnls,
)
from frictionwatch.core.monitor.identify.spd import (
    FASTMATH,
    as_matrix,
    as_vector,
    lapack_inverse_of_sum,
    lapack_spd_inverse_of_sum,
    lower_vector,
    spd_inverse,
    spd_inverse_decoupled,
)

# the information N's pivot ratio below which posterior_kernel leaves N to the reference. N is inverted by the
# reference's own calls (its bits at any ratio, note 80); params and chi^2 differ from the reference by roundings
# as large as its own (~1e-15 x N's unit-diagonal condition of max |params|, both against a long-double solve,
# note 80). Not tuned: a guard against a factor with no digits left, far below the monitor's ratios (genset-v20
# ~1e-6 with 1e4 x the accumulation, note 75); the ridge series (RIDGE_TERMS) is checked on its own
INFORMATION_PIVOT_RATIO_MIN = 1e-9
RIDGE_TERMS = 4  # terms of the ridge's Neumann series in params; not converged (1e-16 relative) after them: FALLBACK


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


def solve_posterior(acc: Accumulator, prior: Prior, sys_var: np.ndarray,
                    lower: float | np.ndarray = 0.0) -> Posterior:
    """Bounded MAP estimate (params >= lower; -inf marks a free nuisance) and its covariance.

    sys_var (R,): variance of the error that repeats every cycle, per raw row, in raw units squared."""
    n_pr, r_pr = prior.normal()
    return posterior_from_normal(acc, n_pr, r_pr, sys_var, lower)


def read_only(bound: np.ndarray) -> np.ndarray:
    """``bound`` as the kernels are compiled for it: read-only, as ``initial_state`` makes the state's (a view where
    it is writable: a bound built by a caller or restored from a pickle). A writable one compiled identify_step_kernel,
    its _estimate and report_kernel and posterior_kernel a second time for the same numbers (design note 130); the
    product's bound is already read-only and passes as it is."""
    if not bound.flags.writeable:
        return bound
    view = bound.view()
    view.flags.writeable = False
    return view


def posterior_from_normal(acc: Accumulator, n_pr: np.ndarray, r_pr: np.ndarray, sys_var: np.ndarray,
                          lower: float | np.ndarray = 0.0) -> Posterior:
    """``solve_posterior`` with the prior already in normal form (n_pr (P, P), r_pr (P,); ``Prior.normal``), so a
    caller that keeps a fixed prior's normal equations does not rebuild them every cycle.

    The numba kernel (``posterior_kernel`` below) solves the unconstrained problem from one inverse; when a
    bound is active NNLS decides the parameters and the kernel forms the moments at them; when a factor is nearly
    singular or the reference covariance is at its pseudo-inverse switch, ``posterior_from_normal_reference``
    (LAPACK) decides. Every returned array is new (none aliases an input)."""
    p, r = acc.sys_map.shape
    f64 = np.float64
    n_pr, r_pr, sys_var = np.asarray(n_pr, dtype=f64), np.asarray(r_pr, dtype=f64), np.asarray(sys_var, dtype=f64)
    # the state's bound is a per-run constant, already a contiguous float64 (p,) (initial_state): used as it is,
    # lower_vector's own answer for it, without a call into spd.py every posterior (two a cycle)
    lo = read_only(lower if type(lower) is np.ndarray and lower.dtype == f64 and lower.shape == (p,)
                   and lower.flags.c_contiguous else lower_vector(lower, p))
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


@numba.njit(cache=True, fastmath=FASTMATH)
def _moments_from_inverse(acc_info, acc_rhs, yty, rows, sys_map, info_reference, n_pr, sys_var, params, max_condition,
                          inv):
    """``posterior_moments_kernel`` given inv = (acc_info + n_pr)^-1 (n, n), which becomes cov_stat (scaled in
    place: the caller must not use it afterwards)."""
    n = acc_info.shape[0]
    dof = rows - n
    # chi^2 cancels ~5 digits (yty ~ params^T rhs ~ 1e5 chi^2): the reference's BLAS calls (ddot, dgemv) in its
    # order, so that its rounding is reproduced rather than a different one added
    lin = np.dot(params, acc_rhs)
    quad = np.dot(np.dot(params, acc_info), params)
    chi2 = yty - 2.0 * lin + quad
    chi2_red = chi2 / dof if dof > 0 else 1.0
    c = chi2_red if chi2_red > 1.0 else 1.0  # Python's max(1.0, x): nan keeps 1.0
    empty = np.empty((0, 0))
    # cov_reference = c (info_reference + n_pr)^-1 by the reference's own LAPACK calls (its bits): a balance row
    # accumulated against fixed priors makes this matrix's condition grow with the cycles (design note 75), so no
    # pivot-ratio test; only a failed factor (the reference's pseudo-inverse) falls back
    ref = np.empty((n, n))
    if lapack_inverse_of_sum(info_reference, n_pr, ref, c) != 0:
        return FALLBACK, chi2_red, empty, empty, empty
    if np.isfinite(max_condition):
        t_info = 0.0
        t_ref = 0.0
        for i in range(n):
            t_info += info_reference[i, i] + n_pr[i, i]
            t_ref += ref[i, i]
        if not t_info * t_ref < max_condition * (1.0 - 1e-6) * c:  # at or near the reference's pinv switch
            return FALLBACK, chi2_red, empty, empty, empty
    # G = inv B: a repeated raw error e moves params by G e; cov_sys = G S G^T = W^T W with W = S^1/2 G^T from
    # G^T = B^T inv (inv is exactly symmetric): two transposed-first gemms on contiguous operands, no transposed
    # copy, one (R, P) temporary (the square roots change the rounding by ~1e-16 relative)
    w = np.dot(sys_map.T, inv)
    m = w.shape[0]
    nonnegative = True
    for j in range(m):
        nonnegative &= sys_var[j] >= 0.0  # False for NaN too
    if nonnegative:
        for j in range(m):
            v = np.sqrt(sys_var[j])
            for i in range(n):
                w[j, i] *= v
        cov = np.dot(w.T, w)
    else:  # a negative or NaN variance: (G S) G^T as the reference forms it
        h = np.empty((m, n))
        for j in range(m):
            for i in range(n):
                h[j, i] = w[j, i] * sys_var[j]
        cov = np.dot(w.T, h)
    for i in range(n):  # cov_stat = inv * c (in place), cov = cov_stat + cov_sys
        for j in range(n):
            v = inv[i, j] * c
            inv[i, j] = v
            cov[i, j] = v + cov[i, j]
    return OK, chi2_red, inv, cov, ref


@numba.njit(cache=True, fastmath=FASTMATH)
def posterior_moments_kernel(acc_info, acc_rhs, yty, rows, sys_map, info_reference, n_pr, sys_var, params,
                             max_condition):
    """chi^2 reduced, statistical, total and reference covariances of ``posterior_from_normal`` at params.

    Returns (status, chi2_red, cov_stat, covariance, cov_reference); the arrays are valid only with status OK."""
    n = acc_info.shape[0]
    inv = np.empty((n, n))
    if lapack_spd_inverse_of_sum(acc_info, n_pr, inv, 1.0) < INFORMATION_PIVOT_RATIO_MIN:
        empty = np.empty((0, 0))
        return FALLBACK, 1.0, empty, empty, empty
    return _moments_from_inverse(acc_info, acc_rhs, yty, rows, sys_map, info_reference, n_pr, sys_var, params,
                                 max_condition, inv)


@numba.njit(cache=True, fastmath=FASTMATH)
def posterior_kernel(acc_info, acc_rhs, yty, rows, sys_map, info_reference, n_pr, r_pr, sys_var, lo, max_condition):
    """The posterior of ``posterior_from_normal`` from one inverse of info = acc_info + n_pr.

    params: the unconstrained minimiser of ``bounded_solve_kernel`` (unit-diagonal scaling, ridge 1e-12 on the
    scaled diagonal): (info + 1e-12 D^2)^-1 rhs = sum_k (-1e-12 info^-1 D^2)^k params0, params0 = info^-1 rhs,
    D^2 = diag(info), summed until a term is below 1e-16 of params (FALLBACK if not within RIDGE_TERMS); when it
    meets the bounds with the margin it is the bounded optimum, else NEEDS_BOUND. info^-1 is the reference's own
    LAPACK calls (its bits), so only params and chi^2 differ from the reference, by roundings (design note 80).

    Returns (status, params, chi2_red, cov_stat, covariance, cov_reference); the arrays are valid only with status
    OK (params also with NEEDS_BOUND: the unconstrained minimiser)."""
    n = acc_info.shape[0]
    empty = np.empty((0, 0))
    params = np.empty(n)
    m = sys_map.shape[1]
    if (acc_info.shape[1] != n or acc_rhs.shape[0] != n or sys_map.shape[0] != n or info_reference.shape != (n, n)
            or n_pr.shape != (n, n) or r_pr.shape[0] != n or sys_var.shape[0] != m or lo.shape[0] != n):
        return BAD_SHAPE, params, 1.0, empty, empty, empty
    inv = np.empty((n, n))
    # N^-1 by the reference's own calls (spd_inverse's potrf, potri on the raw matrix): cov_stat is its bits at any
    # condition, which grows with the accumulated cycles on genset-v20 (design note 80)
    if lapack_spd_inverse_of_sum(acc_info, n_pr, inv, 1.0) < INFORMATION_PIVOT_RATIO_MIN:
        return FALLBACK, params, 1.0, empty, empty, empty
    rhs = np.empty(n)
    ridge = np.empty(n)  # e D^2 (e = REGULARISATION, D^2 = diag(N) floored as bounded_solve floors it)
    for i in range(n):
        rhs[i] = acc_rhs[i] + r_pr[i]
        v = acc_info[i, i] + n_pr[i, i]
        ridge[i] = REGULARISATION * (v if v > 1e-300 else 1e-300)
    # (N + e D^2)^-1 rhs = sum_k (-N^-1 e D^2)^k N^-1 rhs: terms until one is below 1e-16 of params (the ridge's
    # effect is e |S^-1| relative per term, S the unit-diagonal N: ~1e-6 at the monitor's worst ratios)
    term = np.empty(n)
    t = np.empty(n)
    for i in range(n):
        acc_t = 0.0
        for j in range(n):
            acc_t += inv[i, j] * rhs[j]
        params[i] = acc_t
        term[i] = acc_t
    converged = False
    for _ in range(RIDGE_TERMS):
        for i in range(n):
            t[i] = ridge[i] * term[i]
        big = 0.0
        size = 0.0
        for i in range(n):
            acc_t = 0.0
            for j in range(n):
                acc_t += inv[i, j] * t[j]
            term[i] = -acc_t
            params[i] -= acc_t
            big = max(big, abs(acc_t))
            size = max(size, abs(params[i]))
        if big <= 1e-16 * size:
            converged = True
            break
    if not converged:
        return FALLBACK, params, 1.0, empty, empty, empty
    scale = 0.0
    for i in range(n):
        if np.isfinite(lo[i]):
            v = acc_info[i, i] + n_pr[i, i]
            x = abs(params[i] * np.sqrt(v if v > 1e-300 else 1e-300))
            if x > scale:
                scale = x
    for i in range(n):
        if np.isfinite(lo[i]):
            v = acc_info[i, i] + n_pr[i, i]
            d = np.sqrt(v if v > 1e-300 else 1e-300)
            if not params[i] * d - lo[i] * d > FEASIBLE_MARGIN * scale:
                return NEEDS_BOUND, params, 1.0, empty, empty, empty
    status, chi2_red, cov_stat, cov, ref = _moments_from_inverse(
        acc_info, acc_rhs, yty, rows, sys_map, info_reference, n_pr, sys_var, params, max_condition, inv)
    return status, params, chi2_red, cov_stat, cov, ref
