"""From a posterior over the parameters to a reported ``FrictionEstimate`` (per-cylinder means, coefficients,
sigmas, resolved masks; results.py)."""

from __future__ import annotations

import numpy as np

from frictionwatch.core.monitor.accumulate import Posterior
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.frozen_init import fast_constructor
from frictionwatch.core.monitor.identify import ParameterLayout
from frictionwatch.core.monitor.monitor_kernels import estimate_into
from frictionwatch.core.monitor.results import FrictionEstimate

FOUR_PI = 4.0 * np.pi
_make_estimate = fast_constructor(FrictionEstimate)  # FrictionEstimate(**fields), cheaper


def friction_estimate(
    spec: EngineSpec,
    layout: ParameterLayout,
    post: Posterior,
    basis_mean: np.ndarray,
    prior_mean: np.ndarray,
    resolve_rel: float,
    coefficient_snr: float,
    min_data_gain: float = 0.0,
    cylinder_rows: np.ndarray | None = None,
) -> FrictionEstimate:
    """Report a posterior.

    basis_mean (z, 6): work means <F_kl> of this cycle (they turn a_kl into N m); prior_mean (z,) Eq. 6 shares [N m].
    A per-cylinder mean is resolved when its 1-sigma is at most ``resolve_rel`` of its value; a coefficient when
    its normalised value exceeds ``coefficient_snr`` sigmas; both only when the speed signal gave at least
    ``min_data_gain`` of what is known about them (the rest coming from the priors and the mean balance).
    cylinder_rows (z, P): ``layout.cylinder_rows(basis_mean)`` if already at hand.
    """
    p_f = layout.n_params
    theta = np.ascontiguousarray(post.theta, dtype=np.float64)
    if theta.shape != (p_f,):
        raise ValueError(f"the posterior must be over the {p_f} friction parameters, got theta of shape {theta.shape}")
    basis_mean = np.ascontiguousarray(basis_mean, dtype=np.float64)
    rows = layout.cylinder_rows(basis_mean) if cylinder_rows is None else cylinder_rows  # (z, P)
    return friction_estimate_leading(spec, layout, post, basis_mean, prior_mean, resolve_rel, coefficient_snr,
                                     min_data_gain, np.ascontiguousarray(rows, dtype=np.float64))


def friction_estimate_leading(spec: EngineSpec, layout: ParameterLayout, post: Posterior, basis_mean: np.ndarray,
                              prior_mean: np.ndarray, resolve_rel: float, coefficient_snr: float,
                              min_data_gain: float, cylinder_rows: np.ndarray,
                              mep_factors: tuple[float, float] | None = None) -> FrictionEstimate:
    """``friction_estimate`` of the leading ``layout.n_params`` parameters of a posterior over more (friction
    first, then nuisances), without slicing it: the kernel reads the leading block of the full, contiguous
    covariances (the same numbers as ``friction_estimate(post.head(n_params), ...)``). basis_mean (z, 6) and
    cylinder_rows (z, n_params) contiguous float64. mep_factors: (4 pi / displacement_cyl, 4 pi / displacement)
    [1/m^3] if already at hand."""
    z = spec.n_cyl
    p_f = layout.n_params
    theta = post.theta
    if mep_factors is None:
        mep_factors = (FOUR_PI / spec.displacement_cyl, FOUR_PI / spec.displacement)
    if theta.shape[0] < p_f or cylinder_rows.shape != (z, p_f) or basis_mean.shape != (z, 6):
        raise ValueError(f"need >= {p_f} parameters, rows ({z}, {p_f}) and basis means ({z}, 6)")
    rows = cylinder_rows
    group = layout.group
    # one buffer for the float outputs (fresh per call: they go into the result), one for the masks
    shape = group.shape
    n6 = shape[0] * shape[1]
    buf = np.empty(5 * z + 4 * n6 + 4)
    per_cyl = buf[:5 * z].reshape(5, z)
    t_mean, t_sig, fmep, fmep_sig, gain = per_cyl[0], per_cyl[1], per_cyl[2], per_cyl[3], per_cyl[4]
    per_term = buf[5 * z:5 * z + 4 * n6].reshape(4, *shape)
    coef, coef_sig, coef_norm, coef_norm_sig = per_term[0], per_term[1], per_term[2], per_term[3]
    totals = buf[5 * z + 4 * n6:]
    masks = np.empty(z + n6, dtype=bool)
    resolved = masks[:z]
    coef_ok = masks[z:].reshape(shape)
    # one kernel: coefficients and their sigmas, per-cylinder and total means with sigmas (quadratic forms through
    # the covariance, row by row), data gains of the deviations from the equal share, resolved masks
    estimate_into(np.ascontiguousarray(theta, dtype=np.float64), np.ascontiguousarray(post.covariance),
                  np.ascontiguousarray(post.cov_statistical), np.ascontiguousarray(post.cov_reference), group,
                  layout.prior if layout.prior.flags.c_contiguous else np.ascontiguousarray(layout.prior),
                  basis_mean, rows, float(resolve_rel), float(coefficient_snr), float(min_data_gain),
                  float(mep_factors[0]), float(mep_factors[1]), t_mean, t_sig, fmep, fmep_sig, coef,
                  coef_sig, coef_norm, coef_norm_sig, resolved, coef_ok, gain, totals)
    return _make_estimate(
        friction_torque_mean=t_mean,
        friction_torque_mean_sigma=t_sig,
        fmep=fmep,
        fmep_sigma=fmep_sig,
        coefficients=coef,
        coefficients_sigma=coef_sig,
        coefficients_normalised=coef_norm,
        coefficients_normalised_sigma=coef_norm_sig,
        resolved=resolved,
        coefficient_resolved=coef_ok,
        total_friction_torque=float(totals[0]),
        total_friction_torque_sigma=float(totals[1]),
        total_fmep=float(totals[2]),
        total_fmep_sigma=float(totals[3]),
        prior_friction_torque_mean=np.asarray(prior_mean, dtype=np.float64).reshape(z),
        data_gain=gain,
        weight=float(post.weight),
        chi2_reduced=float(post.chi2_reduced),
    )
