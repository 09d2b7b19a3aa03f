"""From a posterior over the parameters to a reported ``FrictionEstimate`` (per-cylinder means, coefficients,
sigmas, resolved masks; results.py). The numbers come from two kernels (core.monitor.estimate_kernels)."""

from __future__ import annotations

from dataclasses import dataclass

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


def friction_estimate(spec: EngineSpec, layout: ParameterLayout, post: Posterior, basis_mean: np.ndarray,
                      prior_mean: np.ndarray, limits: ReportLimits,
                      cylinder_rows: np.ndarray | None = None) -> FrictionEstimate:
    """Report the friction part of a posterior: its leading ``layout.n_params`` parameters (friction scales first,
    then any nuisances, which are not reported).

    basis_mean (z, n_terms): work means <F_kl> of this cycle (they turn a_kl into N m); prior_mean (z,) Eq. 6 shares
    [N m]; cylinder_rows (z, n_params): ``layout.cylinder_rows(basis_mean)`` if already at hand."""
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
    return FrictionEstimate(
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
