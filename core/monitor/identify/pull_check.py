"""The pull check: a cylinder's figure drawn by a repeated error its stated sigma does not see (issue 29, design
notes 41-42).

The accumulated speed equations have a point of their own, theta_d = N^-1 r (no prior, no bound): where more cycles
of the same equations lead the estimate. Where the equations are right, the posterior sits between the prior and
theta_d, and a cylinder's distance from it, d_k = c_k (theta_d - theta), is statistical scatter with variance

    v_k = c_k (N^-1 - (N + N_prior)^-1) c_k^T        (Var(theta_d - theta) when the prior is right in its own sigma)

Genset-v20 at one load with one wheel (note 41): the flywheel's low orders carry a repeated model error whose
projection on cylinder 13 puts theta_d +120-160 % from the truth, 5-7 of its sigma; the posterior slides towards
it as the data gain grows (+13 % at 3,000 cycles, +21.6 % on sigma 6 % at 8,000 of a profile log) and the
systematic sigma (the per-row sandwich) stays 3-4 %. The check takes the distance beyond ``kappa`` of its scatter,

    e_k^2 = max(0, d_k^2 - kappa^2 v_k),

as a repeated error of the data in that cylinder's direction, and the part of the figure's move away from its
Eq. 6 share, shift_k = t_k - share_k, in the same proportion as unproven:

    sigma_pull,k = |shift_k| e_k / |d_k|        (<= |shift_k|; one cylinder, or each independent direction of d:
                                                  ``pull_sigma``)

Scalar case (prior p of variance s_p^2, data-only point x of variance s_d^2, data gain g): the posterior moved
shift = g (x - p) and lies d = (1 - g)(x - p) from x; v = (1 - g)^2 (s_d^2 + s_p^2). A repeated error b of the data
moves the posterior by g b, and b^2 ~ (x - p)^2 - kappa^2 (s_d^2 + s_p^2) = e^2 / (1 - g)^2, i.e. g b = shift e / d.
It is added in quadrature to the figure's sigma before "measured" is decided (``with_pull``). Nothing changes where
the data agree with the figure within kappa of their scatter (the prior's own sigma included: a cylinder truly
off its share by about the prior's spread does not fire it). What the check cannot see: a repeated error in a
direction the data alone decide (data gain ~1: the posterior is the data-only point, d ~ 0).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from frictionwatch.core.monitor.identify.posterior import Posterior
from frictionwatch.core.monitor.identify.spd import lapack_spd_inverse_of_sum, spd_inverse
from frictionwatch.core.monitor.report.results import FrictionEstimate
from frictionwatch.core.tuned import MONITOR_RECORD, read_tuned

_TUNED = read_tuned(MONITOR_RECORD)


@dataclass(frozen=True)
class DataPull:
    """Per cylinder (z,) [N m]: d the data-only point's figure minus the posterior's, v its variance [N^2 m^2] where
    the equations hold, shift the posterior's figure minus the Eq. 6 share; cov (z, z) [N^2 m^2] the variance of d
    as a whole (its diagonal v; None: the cylinders' distances taken independent)."""

    d: np.ndarray
    v: np.ndarray
    shift: np.ndarray
    cov: np.ndarray | None = None


def data_only_pull(acc: Accumulator, post: Posterior, rows: np.ndarray, share: np.ndarray) -> DataPull | None:
    """The data-only point's distance from the posterior per cylinder (``DataPull``); rows (z, p) the cylinders'
    rows over the leading p parameters, share (z,) the Eq. 6 shares [N m]. None where the accumulated equations
    alone do not fix a point (N not positive definite: nothing accumulated yet, or a direction only the prior
    holds) or a number is not finite (no share without a balance): then there is nothing to check against. The
    data-only covariance is scaled by the posterior's reduced chi^2 where that is above 1, as the posterior's
    statistical one is."""
    rows = np.asarray(rows, dtype=np.float64)
    p = rows.shape[1]
    if acc.weight <= 0.0:
        return None
    inv = spd_inverse(acc.info)
    if inv is None:
        return None
    theta_d = inv @ acc.rhs
    if not np.all(np.isfinite(theta_d)):
        return None
    d = rows @ (theta_d[:p] - post.params[:p])
    gap = max(1.0, float(post.chi2_reduced)) * inv[:p, :p] - post.cov_statistical[:p, :p]
    cov = rows @ gap @ rows.T
    cov = 0.5 * (cov + cov.T)
    shift = rows @ post.params[:p] - np.asarray(share, dtype=np.float64)
    if not (np.all(np.isfinite(cov)) and np.all(np.isfinite(d)) and np.all(np.isfinite(shift))):
        return None  # (a share not at hand, a posterior not finite: nothing to check against)
    return DataPull(d, np.maximum(np.diag(cov), 0.0), shift, cov)


def pull_sigma(pull: DataPull, kappa: float) -> np.ndarray:
    """(z,) [N m] sigma_pull of the module's formula, taken along the independent directions of d (the
    eigenvectors u_j of its covariance, variance lambda_j): per direction e_j^2 = max(0, (u_j d)^2 - kappa^2
    lambda_j) and sigma_j = |u_j shift| e_j / |u_j d|; a cylinder gets sum_j (u_jk sigma_j)^2. So a cylinder's
    move that the data made consistently (a worn ring the speed sees) is not charged for an inconsistency of
    the data in another direction (k9k-4cyl at 200 cycles: the data-only point 2.5-2.8 of its scatter off in
    the pairs' contrast, cylinders 1 and 4 against 2 and 3, on every cylinder alike). Without ``cov`` it is the
    per-cylinder formula. Directions of no scatter (the total the balance fixes, a
    direction the data alone decide: lambda <= 1e-12 of the largest) carry nothing."""
    if pull.cov is None:
        lam, u = np.asarray(pull.v, dtype=np.float64), np.eye(pull.d.shape[0])
    else:
        lam, u = np.linalg.eigh(np.asarray(pull.cov, dtype=np.float64))
    dj, sj = u.T @ pull.d, u.T @ pull.shift
    live = lam > 1e-12 * max(float(lam.max(initial=0.0)), 1e-300)
    e = np.sqrt(np.maximum(dj ** 2 - kappa ** 2 * np.where(live, lam, 0.0), 0.0))
    span = np.abs(dj)
    ratio = np.minimum(1.0, np.divide(e, span, out=np.zeros_like(e), where=live & (span > 0.0)))
    sig_j = np.abs(sj) * ratio
    return np.sqrt((u * u) @ (sig_j * sig_j))


def pull_sigma_reference(acc: Accumulator, post: Posterior, rows: np.ndarray, share: np.ndarray,
                         kappa: float) -> np.ndarray:
    """(z,) [N m] ``PullCheck.sigma`` by numpy and LAPACK (``data_only_pull``, ``pull_sigma``): the reference of
    ``pull_sigma_kernel``, and what the check computes, readably."""
    pull = data_only_pull(acc, post, rows, share)
    if pull is None:
        return np.zeros(np.asarray(rows).shape[0])
    return pull_sigma(pull, kappa)


@numba.njit(cache=True)
def pull_sigma_kernel(inv_lower, rhs, params, chi2_reduced, cov_statistical, rows, share, kappa):
    """``pull_sigma_reference`` after its LAPACK inverse: inv_lower (P, P) holds N^-1 of the accumulated equations
    in its lower triangle (potrf then potri, the calls ``spd_inverse`` makes: the figure's rounding is theirs, see
    below), rhs (P,) their right-hand side, params (P,), chi2_reduced and cov_statistical (P, P) the posterior's,
    rows (z, p), share (z,). Returns (z,) [N m], zeros where a number is not finite (the reference's None).

    The inverse stays LAPACK's potri: another route to N^-1 (potri of the unit-diagonal form, core.monitor.identify.spd) is
    as exact, but d = c (N^-1 r - theta) is sensitive to the last digits of N^-1 (genset-v20: the two inverses
    differ by 5e-11 of sqrt(C_ii C_jj), the pull sigmas by up to 3e-8 of their largest; design note 42). The rest
    is loops or numba's BLAS in the order of the reference's products, and numba's eigh (LAPACK syevd, as numpy's)."""
    n = inv_lower.shape[0]
    inv = np.empty((n, n))
    for i in range(n):  # spd_inverse's tril(inv) + tril(inv, -1).T
        for j in range(i + 1):
            inv[i, j] = inv_lower[i, j]
            inv[j, i] = inv_lower[i, j]
    return _pull_sigma_of_inverse(inv, rhs, params, chi2_reduced, cov_statistical, rows, share, kappa)


@numba.njit(cache=True)
def pull_sigma_of_info_kernel(info, rhs, params, chi2_reduced, cov_statistical, rows, share, kappa):
    """``pull_sigma_reference`` from the accumulated information info (P, P) in one dispatch (design note 88): N^-1
    by the calls ``spd_inverse`` makes (LAPACK potrf then potri on the raw matrix, core.monitor.identify.spd's
    ``lapack_spd_inverse_of_sum`` with nothing added: its bits, note 80), mirrored, then ``pull_sigma_kernel``'s
    arithmetic. Zeros (z,) where info is not positive definite (no data-only point) or a number is not finite."""
    n = info.shape[0]
    inv = np.empty((n, n))
    if lapack_spd_inverse_of_sum(info, np.zeros((n, n)), inv, 1.0) < 0.0:
        return np.zeros(rows.shape[0])
    return _pull_sigma_of_inverse(inv, rhs, params, chi2_reduced, cov_statistical, rows, share, kappa)


@numba.njit(cache=True)
def _pull_sigma_of_inverse(inv, rhs, params, chi2_reduced, cov_statistical, rows, share, kappa):
    """The pull sigmas (z,) from N^-1 (P, P), symmetric (the two kernels above)."""
    n = inv.shape[0]
    z, p = rows.shape
    sigma = np.zeros(z)
    theta_d = inv @ rhs
    for i in range(n):
        if not np.isfinite(theta_d[i]):
            return sigma
    scale = max(1.0, chi2_reduced)
    delta = theta_d[:p] - params[:p]
    gap = scale * inv[:p, :p] - cov_statistical[:p, :p]
    d = rows @ delta
    half = rows @ gap
    cov = np.empty((z, z))
    for a in range(z):
        for b in range(z):
            acc = 0.0
            for k in range(p):
                acc += half[a, k] * rows[b, k]
            cov[a, b] = acc
    for a in range(z):
        for b in range(a):
            v = 0.5 * (cov[a, b] + cov[b, a])
            cov[a, b] = v
            cov[b, a] = v
    shift = rows @ params[:p] - share
    for a in range(z):
        if not (np.isfinite(d[a]) and np.isfinite(shift[a])):
            return sigma
        for b in range(z):
            if not np.isfinite(cov[a, b]):
                return sigma
    lam, u = np.linalg.eigh(cov)
    top = 0.0
    for j in range(z):
        top = max(top, lam[j])
    floor = 1e-12 * max(top, 1e-300)
    sig2 = np.zeros(z)
    for j in range(z):
        dj = 0.0
        sj = 0.0
        for k in range(z):
            dj += u[k, j] * d[k]
            sj += u[k, j] * shift[k]
        live = lam[j] > floor
        e = np.sqrt(max(dj * dj - kappa * kappa * (lam[j] if live else 0.0), 0.0))
        span = abs(dj)
        ratio = min(1.0, e / span) if live and span > 0.0 else 0.0
        sig2[j] = (abs(sj) * ratio) ** 2
    for k in range(z):
        acc = 0.0
        for j in range(z):
            acc += u[k, j] * u[k, j] * sig2[j]
        sigma[k] = np.sqrt(acc)
    return sigma


@dataclass(frozen=True)
class PullCheck:
    """kappa: how many sigmas of its own scatter the data-only point may lie from a figure before the distance
    counts as a repeated error (core/monitor/tuned.json PULL_CHECK_KAPPA = 2.5: tuned on genset-v20 seed 43, its
    3,000-cycle base-load log and its 8,000-cycle +-20 % profile log; validated on seed 47's base-load log, its cost
    checked on seeds 29, 31, 37 under the profile; bench/calibrate_pull_check.py, design note 42)."""

    kappa: float = _TUNED["PULL_CHECK_KAPPA"].value

    def sigma(self, acc: Accumulator, post: Posterior, rows: np.ndarray, share: np.ndarray) -> np.ndarray:
        """(z,) [N m] each cylinder's pull sigma (zeros where ``data_only_pull`` finds no data-only point):
        ``pull_sigma_kernel``, the arithmetic of ``pull_sigma_reference`` in one call."""
        f64 = np.float64
        rows = np.ascontiguousarray(rows, dtype=f64)
        z, p = rows.shape
        if acc.weight <= 0.0:
            return np.zeros(z)
        share = np.ascontiguousarray(share, dtype=f64)
        n = acc.info.shape[0]
        if acc.info.shape != (n, n) or acc.rhs.shape != (n,) or share.shape != (z,) or not p <= n or \
                post.params.shape[0] < p or post.cov_statistical.shape[0] < p:
            raise ValueError(f"pull check: info {acc.info.shape}, rhs {acc.rhs.shape}, rows {rows.shape}, share "
                             f"{share.shape}, params {post.params.shape}, cov {post.cov_statistical.shape} do not fit")
        # the inverse (LAPACK's calls, as spd_inverse) and the arithmetic in one dispatch (design note 88)
        return pull_sigma_of_info_kernel(np.ascontiguousarray(acc.info, dtype=f64),
                                         np.ascontiguousarray(acc.rhs, dtype=f64),
                                         np.ascontiguousarray(post.params, dtype=f64), float(post.chi2_reduced),
                                         np.ascontiguousarray(post.cov_statistical, dtype=f64), rows, share,
                                         float(self.kappa))


def with_pull(est: FrictionEstimate, sigma: np.ndarray, resolve_rel: float, spec: EngineSpec) -> FrictionEstimate:
    """``est`` with ``sigma`` (z,) [N m] added in quadrature to each cylinder's friction sigma (the figure itself
    unchanged) and "measured" decided again on the sigma before the calibration's (as the estimate decides it): a
    cylinder no longer within ``resolve_rel`` is a share. The engine total is not touched (the balance holds it)."""
    sigma = np.asarray(sigma, dtype=np.float64)
    if not (sigma > 0.0).any():  # (the method: np.any's wrapper was ~0.6 % of a k9k cycle)
        return est
    sig = np.sqrt(est.friction_torque_mean_sigma ** 2 + sigma ** 2)
    cal = est.calibration_sigma if est.calibration_sigma is not None else np.zeros_like(sig)
    before_cal = np.sqrt(np.maximum(sig ** 2 - cal ** 2, 0.0))
    t_cyl = np.where(np.isfinite(est.friction_torque_mean), est.friction_torque_mean, est.prior_friction_torque_mean)
    resolved = est.resolved & (before_cal <= resolve_rel * np.abs(t_cyl))
    t_mean = np.where(resolved, est.friction_torque_mean, np.nan)
    to_cyl = spec.mep_per_torque_cyl
    return replace(est, friction_torque_mean=t_mean, friction_torque_mean_sigma=sig, fmep=t_mean * to_cyl,
                   fmep_sigma=sig * to_cyl, resolved=resolved, pulled=est.resolved & ~resolved)
