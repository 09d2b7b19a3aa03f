"""From a posterior over the parameters to a reported ``FrictionEstimate`` (per-cylinder means, coefficients,
sigmas, resolved masks; results.py)."""

from __future__ import annotations

import numpy as np

from core.accumulate import Posterior
from core.engine import EngineSpec
from core.identify import ParameterLayout
from core.results import FrictionEstimate

FOUR_PI = 4.0 * np.pi


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
    z = spec.n_cyl
    theta = post.theta
    a = layout.coefficients(theta)
    a_sig = layout.prior * np.sqrt(np.clip(np.diag(post.covariance), 0.0, None))[layout.group]
    a_norm = a * basis_mean
    a_norm_sig = a_sig * basis_mean
    rows = layout.cylinder_rows(basis_mean) if cylinder_rows is None else cylinder_rows  # (z, P)
    t_cyl = rows @ theta
    t_sig = post.sigma_of(rows)
    total_row = rows.sum(axis=0)
    t_tot = float(total_row @ theta)
    t_tot_sig = float(post.sigma_of(total_row)[0])
    # what the speed adds is the split among cylinders (the total is the mean balance's): judge the deviation of
    # each cylinder from the equal share
    gain = post.data_gain(rows - rows.sum(axis=0) / z)
    resolved = (t_sig <= resolve_rel * np.abs(t_cyl)) & (gain >= min_data_gain)
    gain_p = post.diagonal_gain()[layout.group]  # = post.data_gain(np.eye(P))
    coef_ok = (a_norm > coefficient_snr * a_norm_sig) & (layout.prior > 0) & (gain_p >= min_data_gain)
    to_mep_cyl = FOUR_PI / spec.displacement_cyl
    to_mep_eng = FOUR_PI / spec.displacement
    return FrictionEstimate(
        friction_torque_mean=np.where(resolved, t_cyl, np.nan),
        friction_torque_mean_sigma=t_sig,
        fmep=np.where(resolved, t_cyl * to_mep_cyl, np.nan),
        fmep_sigma=t_sig * to_mep_cyl,
        coefficients=np.where(coef_ok, a, np.nan),
        coefficients_sigma=a_sig,
        coefficients_normalised=np.where(coef_ok, a_norm, np.nan),
        coefficients_normalised_sigma=a_norm_sig,
        resolved=resolved,
        coefficient_resolved=coef_ok,
        total_friction_torque=t_tot,
        total_friction_torque_sigma=t_tot_sig,
        total_fmep=t_tot * to_mep_eng,
        total_fmep_sigma=t_tot_sig * to_mep_eng,
        prior_friction_torque_mean=np.asarray(prior_mean, dtype=np.float64).reshape(z),
        data_gain=gain,
        weight=float(post.weight),
        chi2_reduced=float(post.chi2_reduced),
    )
