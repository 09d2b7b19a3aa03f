"""The identification steps of core.monitor.monitor.process_cycle in one compiled call for the common case
(core.monitor.identify_step_kernels): noise model and whitened rows (core.monitor.monitor_glue.noise_model_rows), the cycle's terms
and their fold (core.monitor.accumulate.Accumulator), the Eq. 6 shares (core.monitor.monitor_glue.shares_pair), both posteriors
(core.monitor.accumulate.posterior_from_normal) and both estimates (core.monitor.estimate.friction_estimate_leading).

Same numbers as those steps, bit for bit (the same kernels, called with the same inputs); the same result types.
``identify_step`` returns None whenever any step would leave its kernel path (another harmonic count, shapes that
do not fit, another dtype or layout, a posterior with an active bound or a near-singular factor): the caller then
runs the separate steps, which stay the reference and the general path (and raise their errors).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from frictionwatch.core.monitor.accumulate import _REFERENCE_MAX_CONDITION, Accumulator, Posterior, ResidualStats
from frictionwatch.core.monitor.frozen_init import fast_constructor
from frictionwatch.core.monitor.identify_step_kernels import FUSED_OK, identify_step_kernel
from frictionwatch.core.monitor.results import FrictionEstimate

if TYPE_CHECKING:
    from frictionwatch.core.model.engine import EngineSpec
    from frictionwatch.core.monitor.flywheel import FlywheelMotion
    from frictionwatch.core.monitor.identify import CycleRows
    from frictionwatch.core.monitor.monitor import MonitorConfig, MonitorState

_make_stats = fast_constructor(ResidualStats)
_make_accumulator = fast_constructor(Accumulator)
_make_posterior = fast_constructor(Posterior)
_make_estimate = fast_constructor(FrictionEstimate)


def identify_step(cfg: MonitorConfig, spec: EngineSpec, state: MonitorState, fly: FlywheelMotion, rows: CycleRows,
                  indicated_mean: np.ndarray, pmax: np.ndarray, basis_mean: np.ndarray, cyl_rows: np.ndarray,
                  balance: float, t_i: float, drift_var: float, coupling_loss: float, lam: float, g: float,
                  bal_mean: float, rpm: float, prior_normal: tuple, plan: tuple):
    """The steps of process_cycle from ``noise_model_rows`` to the two ``friction_estimate_leading`` calls.

    Inputs as process_cycle has them (indicated_mean (z,) N m, pmax (z,) Pa, basis_mean (z, 6), cyl_rows
    (z, n_params) contiguous; lam the forgetting factor, g and bal_mean the running-mean gain and balance [N m],
    rpm; prior_normal and plan as in MonitorState). Returns None (use the separate steps) or (stats, acc,
    post_s, ind_mean, fire, n_fire, freq, drift_col, est_s, est_c) as the separate steps give them
    (drift_col None without the drift nuisance)."""
    m = state.n_harmonics
    acc = state.accumulator
    st = state.stats
    z = spec.n_cyl
    p_f = state.layout.n_params
    do_fold = state.cycles >= cfg.warmup_cycles
    lam = float(lam)
    # the conditions under which a separate step raises or takes a general path: left to them
    if (fly.harmonics.shape[0] != m or indicated_mean.shape != (z,) or cyl_rows.shape != (z, p_f)
            or basis_mean.shape != (z, 6) or (do_fold and not 0.0 <= lam <= 1.0)):
        return None
    sys_balance = ((cfg.balance_rel_error * t_i) ** 2 + (cfg.coupling_rel_error * coupling_loss) ** 2
                   + (cfg.load_rel_error * spec.rated_torque_nm) ** 2)
    total_c = balance if math.isfinite(balance) else bal_mean
    mep = plan[3]
    group = state.layout.group
    n_terms = group.shape[1]
    cplx_out = np.empty((2, m), dtype=np.complex128)
    real_out = np.empty((2, m))
    p = acc.info.shape[0]
    shares_out = np.empty((5, z))
    fire = np.empty(z, dtype=np.bool_)
    theta_s = np.empty(p)
    per_cyl = np.empty((10, z))
    per_term = np.empty((8, z, n_terms))
    resolved = np.empty((2, z), dtype=np.bool_)
    coef_ok = np.empty((2, z, n_terms), dtype=np.bool_)
    numbers_out = np.empty(16)
    _, n_base, r_base = prior_normal
    try:
        scalars = np.array([
            fly.omega_mean, st.balance_mean, st.balance_var, st.count, cfg.noise_memory, balance, fly.residual_rms,
            fly.n_edges, t_i, drift_var, fly.period, cfg.model_rel_error, sys_balance,
            1.0 if cfg.drift_nuisance else 0.0, lam, g, bal_mean, total_c, rpm, cfg.share_spread, cfg.resolve_rel,
            cfg.coefficient_snr, cfg.min_data_gain, mep[0], mep[1], _REFERENCE_MAX_CONDITION, acc.yty, acc.rows],
            dtype=np.float64)
        status, cov_s, cov_stat_s, ref_s, info, rhs, sys_map, info_ref = identify_step_kernel(
            rows.design, rows.target, state.theta, fly.pattern_harmonics, fly.harmonics, st.mean, st.var,
            rows.mean_row, scalars, acc.info, acc.rhs, acc.sys_map, acc.info_reference, do_fold, indicated_mean,
            pmax, state.indicated_mean, state.cycles == 0, plan[1], n_base, r_base, rows.cylinder_rows, plan[2],
            group, state.layout.prior, basis_mean, cyl_rows, cplx_out, real_out, shares_out, fire, theta_s, per_cyl,
            per_term, resolved, coef_ok, numbers_out)
    except TypeError:  # another dtype or layout than the kernel's (or a non-numeric input): the separate steps
        return None
    if status != FUSED_OK:
        return None
    (tot_s, tot_s_sig, fmep_s, fmep_s_sig, chi2_s, tot_c, tot_c_sig, fmep_c, fmep_c_sig, chi2_c, n_fire, yty, n_rows,
     bal_m, bal_v, _) = numbers_out.tolist()
    stats = _make_stats(mean=cplx_out[0], var=real_out[0], balance_mean=bal_m, balance_var=bal_v, count=st.count + 1)
    if do_fold:
        acc = _make_accumulator(info=info, rhs=rhs, yty=yty, weight=lam * acc.weight + 1.0, rows=n_rows,
                                sys_map=sys_map, info_reference=info_ref)
    weight = acc.weight
    post_s = _make_posterior(theta=theta_s, covariance=cov_s, cov_statistical=cov_stat_s, chi2_reduced=chi2_s,
                             weight=weight, cov_reference=ref_s)
    t_s, t_s_sig, fmep_cyl_s, fmep_cyl_s_sig, gain_s, t_c, t_c_sig, fmep_cyl_c, fmep_cyl_c_sig, gain_c = per_cyl
    coef_s, coef_s_sig, norm_s, norm_s_sig, coef_c, coef_c_sig, norm_c, norm_c_sig = per_term
    resolved_s, resolved_c = resolved
    coef_ok_s, coef_ok_c = coef_ok
    est_s = _make_estimate(
        friction_torque_mean=t_s, friction_torque_mean_sigma=t_s_sig, fmep=fmep_cyl_s, fmep_sigma=fmep_cyl_s_sig,
        coefficients=coef_s, coefficients_sigma=coef_s_sig, coefficients_normalised=norm_s,
        coefficients_normalised_sigma=norm_s_sig, resolved=resolved_s, coefficient_resolved=coef_ok_s,
        total_friction_torque=tot_s, total_friction_torque_sigma=tot_s_sig, total_fmep=fmep_s,
        total_fmep_sigma=fmep_s_sig, prior_friction_torque_mean=shares_out[1], weight=float(weight),
        chi2_reduced=chi2_s, data_gain=gain_s)
    est_c = _make_estimate(
        friction_torque_mean=t_c, friction_torque_mean_sigma=t_c_sig, fmep=fmep_cyl_c, fmep_sigma=fmep_cyl_c_sig,
        coefficients=coef_c, coefficients_sigma=coef_c_sig, coefficients_normalised=norm_c,
        coefficients_normalised_sigma=norm_c_sig, resolved=resolved_c, coefficient_resolved=coef_ok_c,
        total_friction_torque=tot_c, total_friction_torque_sigma=tot_c_sig, total_fmep=fmep_c,
        total_fmep_sigma=fmep_c_sig, prior_friction_torque_mean=shares_out[3], weight=1.0, chi2_reduced=chi2_c,
        data_gain=gain_c)
    return (stats, acc, post_s, shares_out[0], fire, int(n_fire), real_out[1],
            cplx_out[1] if cfg.drift_nuisance else None, est_s, est_c)
