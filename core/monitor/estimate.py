"""From a posterior over the parameters to a reported ``FrictionEstimate`` (per-cylinder means, coefficients,
sigmas, resolved masks; results.py). The numbers come from two kernels (core.monitor.estimate_kernels)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.accumulate import Posterior
from frictionwatch.core.monitor.estimate_kernels import estimate_kernel
from frictionwatch.core.monitor.identify import ParameterLayout
from frictionwatch.core.monitor.results import FrictionEstimate

FOUR_PI = 4.0 * np.pi


@dataclass(frozen=True)
class ReportLimits:
    """When an estimate is reported: a per-cylinder mean when its 1-sigma is at most ``resolve_rel`` of its value,
    a coefficient when its normalised value exceeds ``coefficient_snr`` sigmas; both only when the speed signal gave
    at least ``min_data_gain`` of what is known about them (the rest coming from the priors and the mean balance)."""

    resolve_rel: float
    coefficient_snr: float
    min_data_gain: float = 0.0


@dataclass(frozen=True)
class ModelErrorFloor:
    """The systematic part of the friction sigma that the monitor's own equations cannot see: errors that repeat
    every cycle and move the estimate the same way on every log of one engine and operating point (a drive train or a
    friction law of another shape than the model's, the indicated work's discretisation), calibrated on logs of
    model mismatches (bench/mismatch_coverage.py).

    Added in quadrature to each reported friction torque (total and per cylinder):
        (indicated_rel T_i)^2 + (friction_rel T_f)^2 max(1, chi2_reduced)
    T_i the indicated torque behind it: the mean balance passes an error of the indicated work into friction whole,
    so the floor grows where friction is a small part of the indicated work (high load); T_f the friction itself: a
    law of another shape moves the split the speed fit makes, more where the fit's residual says the model misses."""

    indicated_rel: float = 0.0
    friction_rel: float = 0.0

    def apply(self, est: FrictionEstimate, indicated: np.ndarray, spec: EngineSpec,
              resolve_rel: float) -> FrictionEstimate:
        """``est`` with the floor added to its sigmas; a cylinder no longer within ``resolve_rel`` is unresolved."""
        if self.indicated_rel == 0.0 and self.friction_rel == 0.0:
            return est
        ind = np.asarray(indicated, dtype=np.float64)
        fit = max(1.0, est.chi2_reduced)
        t_cyl = np.where(np.isfinite(est.friction_torque_mean), est.friction_torque_mean,
                         est.prior_friction_torque_mean)
        sig = np.sqrt(est.friction_torque_mean_sigma ** 2 + (self.indicated_rel * ind) ** 2
                      + (self.friction_rel * t_cyl) ** 2 * fit)
        tot_sig = math.sqrt(est.total_friction_torque_sigma ** 2 + (self.indicated_rel * float(ind.sum())) ** 2
                            + (self.friction_rel * est.total_friction_torque) ** 2 * fit)
        resolved = est.resolved & (sig <= resolve_rel * np.abs(t_cyl))
        t_mean = np.where(resolved, est.friction_torque_mean, np.nan)
        to_cyl = FOUR_PI / spec.displacement_cyl
        return replace(est, friction_torque_mean=t_mean, friction_torque_mean_sigma=sig, fmep=t_mean * to_cyl,
                       fmep_sigma=sig * to_cyl, resolved=resolved, total_friction_torque_sigma=tot_sig,
                       total_fmep_sigma=tot_sig * to_cyl / spec.n_cyl)


def friction_estimate(spec: EngineSpec, layout: ParameterLayout, post: Posterior, basis_mean: np.ndarray,
                      prior_mean: np.ndarray, limits: ReportLimits,
                      cylinder_rows: np.ndarray | None = None, floor: ModelErrorFloor | None = None,
                      indicated: np.ndarray | None = None) -> FrictionEstimate:
    """Report the friction part of a posterior: its leading ``layout.n_params`` parameters (friction scales first,
    then any nuisances, which are not reported).

    basis_mean (z, n_terms): work means <F_kl> of this cycle (they turn a_kl into N m); prior_mean (z,) Eq. 6 shares
    [N m]; cylinder_rows (z, n_params): ``layout.cylinder_rows(basis_mean)`` if already at hand; floor: the model-error
    floor added to the sigmas, with ``indicated`` (z,) the cylinders' indicated torques [N m]."""
    z = spec.n_cyl
    p_f = layout.n_params
    n_terms = layout.prior.shape[1]
    params = post.params[:p_f]
    basis_mean = np.asarray(basis_mean, dtype=np.float64)
    rows = layout.cylinder_rows(basis_mean) if cylinder_rows is None else np.asarray(cylinder_rows, dtype=np.float64)
    # no copies to C order: the kernel reads any layout (another layout is another compiled specialisation)
    cov, cov_stat, cov_ref = post.covariance, post.cov_statistical, post.cov_reference
    if (params.shape[0] != p_f or rows.shape != (z, p_f) or basis_mean.shape != (z, n_terms)
            or not cov.shape == cov_stat.shape == cov_ref.shape or cov.shape[0] < p_f or cov.shape[0] != cov.shape[1]):
        raise ValueError(f"need a posterior over >= {p_f} parameters, rows ({z}, {p_f}) and basis means "
                         f"({z}, {n_terms}); got {params.shape}, {rows.shape}, {basis_mean.shape}")
    coef_table, coef_ok, cylinder_table, resolved, t_tot, t_tot_sig = estimate_kernel(
        params, cov, cov_stat, cov_ref, layout.group, layout.prior, basis_mean, rows, float(limits.resolve_rel),
        float(limits.coefficient_snr), float(limits.min_data_gain))
    coef, coef_sig, norm, norm_sig = coef_table
    t_mean, t_sig, gain = cylinder_table
    to_cyl = FOUR_PI / spec.displacement_cyl
    to_eng = to_cyl / z
    est = FrictionEstimate(
        friction_torque_mean=t_mean,
        friction_torque_mean_sigma=t_sig,
        fmep=t_mean * to_cyl,
        fmep_sigma=t_sig * to_cyl,
        coefficients=coef,
        coefficients_sigma=coef_sig,
        coefficients_normalised=norm,
        coefficients_normalised_sigma=norm_sig,
        resolved=resolved,
        coefficient_resolved=coef_ok,
        total_friction_torque=float(t_tot),
        total_friction_torque_sigma=float(t_tot_sig),
        total_fmep=float(t_tot * to_eng),
        total_fmep_sigma=float(t_tot_sig * to_eng),
        prior_friction_torque_mean=np.asarray(prior_mean, dtype=np.float64).reshape(z),
        data_gain=gain,
        weight=float(post.weight),
        chi2_reduced=float(post.chi2_reduced),
    )
    if floor is None or indicated is None:
        return est
    return floor.apply(est, indicated, spec, float(limits.resolve_rel))
