"""One cycle's identification step in one kernel call (issue 26 item 7; design note 115): the accumulation of the
whitened rows (core.monitor.identify.accumulate), the Eq. 6 shares of the running and of this cycle's mean balance
and their prior rows (core.monitor.identify.parameters), both posteriors (core.monitor.identify.posterior), both
reported estimates with the model-error floor and the calibration's variance (core.monitor.identify.estimate) and
the smoothed estimate's pull check (core.monitor.identify.pull_check).

``identify_step_kernel`` is glue around those files' own kernels, called in the order and on the arrays their
Python wrappers give them, so each number is theirs; its reference is ``identify_step_reference``, the same step
by the wrappers one after another (the chain identify_cycle ran before, ~15 kernel dispatches, a dozen records and
small arrays a cycle; tests/core/test_identify_step.py compares the two on real cycles). The kernel answers only
the common case: a posterior whose bound is active (NNLS decides) or whose factor needs LAPACK's general path, or
an accumulator of another shape, returns ok False and the reference computes the cycle.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.identify.accumulate import Accumulator, CycleTerms, accumulate_cycle, cycle_step_kernel
from frictionwatch.core.monitor.identify.bounded_solve import BAD_SHAPE, OK
from frictionwatch.core.monitor.identify.estimate import (
    BalanceCheck,
    CalibrationSensitivity,
    ModelErrorFloor,
    ReportLimits,
    estimate_from_tables,
    estimate_kernel,
    floor_calibration_kernel,
    reported_estimate,
)
from frictionwatch.core.monitor.identify.parameters import FIRING_FRACTION as FIRING_FRACTION_DEFAULT
from frictionwatch.core.monitor.identify.parameters import MOTORED_SPREAD as MOTORED_SPREAD_DEFAULT
from frictionwatch.core.monitor.identify.parameters import (
    ParameterLayout,
    PriorNormal,
    share_kernel,
    share_mean_loss,
    share_rows_kernel,
)
from frictionwatch.core.monitor.identify.posterior import (
    REFERENCE_MAX_CONDITION,
    Posterior,
    posterior_from_normal,
    posterior_kernel,
    read_only,
)
from frictionwatch.core.monitor.identify.pull_check import PullCheck, pull_sigma_of_info_kernel, with_pull
from frictionwatch.core.monitor.report.results import FrictionEstimate

# the step's scalars and settings, one float64 vector (as noise_model's NOISE_FIELDS: a typed record costs more to
# build and pass per cycle); FOLD and FLOOR_ON hold flags as floats
STEP_FIELDS = (
    "forgetting",  # lambda of the accumulated equations
    "fold",  # 1.0: this cycle is folded into them (the warm-up is over)
    "raw_weight",  # the raw sums' effective cycles after this step
    "model_rel_error",  # repeatable model error of a speed harmonic, relative
    "acc_yty", "acc_weight", "acc_rows",  # the accumulator's scalars before this step
    "balance_mean",  # the running mean balance after this cycle [N m] (NaN: none yet)
    "balance",  # this cycle's mean balance [N m] (NaN: no load measurement)
    "motored",  # one motored cylinder's friction [N m]
    "share_spread", "motored_spread", "firing_fraction",  # share_mean_loss's settings
    "resolve_rel", "coefficient_snr", "min_data_gain",  # ReportLimits
    "floor_on", "balance_check", "indicated_rel", "coupling_per_misfit", "misfit_free",  # ModelErrorFloor (0: None)
    "coupling_loss", "misfit",  # BalanceCheck's of both estimates
    "same_balance_offset",  # the noise statistics' balance_mean (identify_cycle's ``same``; NaN: none)
    "same_sigma", "balance_sigma",  # the two checks' balance sigmas [N m]
    "tdc_wheel2", "gain_common2",  # the calibration's variances common to the cylinders (each one's own: StepCylinders)
    "kinetic2_smoothed", "kinetic2_cycle",  # (inertia sigma x the kinetic term)^2 of each estimate [N^2 m^2]
    "load2",  # (the load reading's sigma x this cycle's load)^2 [N^2 m^2], both estimates (Calibration.load_variance)
    "to_cyl", "to_engine",  # MEP per N m of a cylinder, of the engine
    "kappa",  # the pull check's
)
(FORGETTING, FOLD, RAW_WEIGHT, MODEL_REL_ERROR, ACC_YTY, ACC_WEIGHT, ACC_ROWS, BALANCE_MEAN, BALANCE, MOTORED,
 SHARE_SPREAD, MOTORED_SPREAD, FIRING_FRACTION, RESOLVE_REL, COEFFICIENT_SNR, MIN_DATA_GAIN, FLOOR_ON, BALANCE_CHECK,
 INDICATED_REL, COUPLING_PER_MISFIT, MISFIT_FREE, COUPLING_LOSS, MISFIT, SAME_OFFSET, SAME_SIGMA, BALANCE_SIGMA,
 TDC_WHEEL2, GAIN_COMMON2, KINETIC2_S, KINETIC2_C, LOAD2, TO_CYL, TO_ENGINE,
 KAPPA) = range(len(STEP_FIELDS))


class StepRows(NamedTuple):
    """This cycle's whitened equations (noise_model.WhitenedCycle's arrays): a (R, P), y (R,), inv_sigma (R,),
    sys_var (R,), the noise statistics' var (M,), freq (M,) and the fitted angle harmonics (M,) complex."""

    a: np.ndarray
    y: np.ndarray
    inv_sigma: np.ndarray
    sys_var: np.ndarray
    var: np.ndarray
    freq: np.ndarray
    harmonics: np.ndarray


class StepModel(NamedTuple):
    """What the step reads of the model and this cycle's rows: the fixed priors' info (P, P) and rhs (P,), the
    bounds (P,), the layout's group and prior (z, L), this cycle's basis means (z, L), the cylinders' rows over the
    friction parameters (z, p_f), the mean-balance row (P,) and the previous estimate (P,)."""

    prior_info: np.ndarray
    prior_rhs: np.ndarray
    lower: np.ndarray
    group: np.ndarray
    prior: np.ndarray
    basis_mean: np.ndarray
    cylinder_rows: np.ndarray
    mean_row: np.ndarray
    params: np.ndarray


class StepCylinders(NamedTuple):
    """Per cylinder (z,): the running indicated means (the smoothed estimate's), this cycle's indicated means, the
    TDC sensitivities of the mean balance, and (2, z) each cylinder's own TDC and gain variances of the calibration
    (``Calibration.own_variances``)."""

    indicated_mean: np.ndarray
    indicated: np.ndarray
    tdc: np.ndarray
    calibration_own: np.ndarray


@numba.njit(cache=True)
def _prior_with_share(info, rhs, rows, share, sigma):
    """PriorNormal.with_share: the fixed priors alone where a share is not finite."""
    for k in range(share.shape[0]):
        if not np.isfinite(share[k]):
            return info, rhs
    return share_rows_kernel(info, rhs, rows, share, sigma)


@numba.njit(cache=True)
def _estimate(post, share, model, check, sens, s):
    """reported_estimate's numbers from a posterior (params, cov_stat, cov, cov_ref) and its Eq. 6 share (z,):
    estimate_kernel, then the floor's scalars in its order, then floor_calibration_kernel. check = (indicated
    (z,), balance, its sigma); sens = (tdc (z,), indicated (z,), the kinetic term's variance, the load's, each
    cylinder's own calibration variances (2, z))."""
    params, cov_stat, cov, ref = post
    ind, balance, balance_sigma = check
    tdc, t_i, kinetic2, load2, own = sens
    p_f = model.cylinder_rows.shape[1]
    resolve_rel = s[RESOLVE_REL]
    coef_table, coef_ok, cylinder_table, resolved, t_tot, s_tot = estimate_kernel(
        params[:p_f], cov, cov_stat, ref, model.group, model.prior, model.basis_mean, model.cylinder_rows,
        resolve_rel, s[COEFFICIENT_SNR], s[MIN_DATA_GAIN])
    floor_on, rel2, ind_rel = False, 0.0, 0.0
    if s[FLOOR_ON] != 0.0:
        excess2 = 0.0
        if s[BALANCE_CHECK] != 0.0 and math.isfinite(balance) and t_tot > 0:
            excess2 = max(0.0, (t_tot - balance) ** 2 - s_tot ** 2 - balance_sigma ** 2)
        excess2 += (s[COUPLING_PER_MISFIT] * max(0.0, s[MISFIT] - s[MISFIT_FREE]) * s[COUPLING_LOSS]) ** 2
        floor_on = not (excess2 == 0.0 and s[INDICATED_REL] == 0.0)
        if floor_on:
            ind_rel = s[INDICATED_REL]
            rel2 = excess2 / t_tot ** 2 if t_tot > 0 else 0.0
            s_tot = math.sqrt(s_tot ** 2 + (ind_rel * np.sum(ind)) ** 2 + excess2)
    settings = np.array([1.0 if floor_on else 0.0, ind_rel, rel2, resolve_rel, s[TO_CYL], s[TDC_WHEEL2],
                         s[GAIN_COMMON2], kinetic2, load2])
    return coef_table, coef_ok, cylinder_table, t_tot, s_tot, floor_calibration_kernel(
        cylinder_table, resolved, share, ind, tdc, t_i, settings, own)


@numba.njit(cache=True)
def report_kernel(post_s, post_c, shares, model, cylinders, s, acc):
    """Both reported estimates and the smoothed one's pull check from the two posteriors (params, chi2_reduced,
    cov_stat, covariance, cov_reference): shares = the Eq. 6 shares (z,) of the smoothed and of the cycle's
    estimate; acc = (the accumulated info (P, P), rhs (P,), weight). Returns (the two estimates' tables: _estimate's,
    the pull sigmas (z,)). The tail of ``identify_step_kernel``, and called alone where a posterior needed NNLS."""
    params_s, chi2_s, stat_s, cov_s, ref_s = post_s
    params_c, chi2_c, stat_c, cov_c, ref_c = post_c
    share_s, share_c = shares
    info, rhs, weight = acc
    # the smoothed estimate's floor compares it with the balance at the same operating points (no balance: NaN)
    same = np.nan
    fit_total = np.dot(model.mean_row, params_s)
    if math.isfinite(s[BALANCE_MEAN]) and math.isfinite(s[SAME_OFFSET]) and math.isfinite(fit_total):
        same = fit_total + s[SAME_OFFSET]
    est_s = _estimate((params_s, stat_s, cov_s, ref_s), share_s, model,
                      (cylinders.indicated_mean, same, s[SAME_SIGMA]),
                      (cylinders.tdc, cylinders.indicated_mean, s[KINETIC2_S], s[LOAD2], cylinders.calibration_own), s)
    est_c = _estimate((params_c, stat_c, cov_c, ref_c), share_c, model,
                      (cylinders.indicated, s[BALANCE], s[BALANCE_SIGMA]),
                      (cylinders.tdc, cylinders.indicated, s[KINETIC2_C], s[LOAD2], cylinders.calibration_own), s)
    pull = np.zeros(share_s.shape[0])
    if weight > 0.0:  # PullCheck.sigma
        pull = pull_sigma_of_info_kernel(info, rhs, params_s, chi2_s, stat_s, model.cylinder_rows, share_s,
                                         s[KAPPA])
    return est_s, est_c, pull


@numba.njit(cache=True)
def identify_step_kernel(rows, acc, model, cylinders, s):
    """``identify_step_reference``'s numbers in one call: rows a StepRows, acc the accumulator's arrays (info, rhs,
    sys_map, info_reference, raw rows, raw targets; accumulate.cycle_step_kernel's), model a StepModel, cylinders a
    StepCylinders, s the STEP_FIELDS vector.

    Returns (ok: the shapes fit; the cycle's terms, the accumulator's arrays after the step, the speed rows' budget,
    its scalars (yty, weight, rows); the shares (z,) of the smoothed and the cycle's estimate; the priors with them
    in normal form (n_s, r_s, n_c, r_c); the two posteriors' status (bounded_solve's OK, NEEDS_BOUND, FALLBACK) and
    kernels' answers (params, chi2_reduced, cov_stat, covariance, cov_reference); ``report_kernel``'s answer, empty
    unless both posteriors are OK: else the caller decides them (NNLS, LAPACK's general path) and calls
    ``report_kernel`` itself)."""
    ok, terms, arrays, budget = cycle_step_kernel(
        rows.a, rows.y, rows.inv_sigma, s[FORGETTING], s[FOLD] != 0.0, acc, s[RAW_WEIGHT], model.params,
        (rows.sys_var, rows.var, rows.freq, rows.harmonics), s[MODEL_REL_ERROR])
    t_info, t_rhs, t_yty, t_map, t_ref = terms
    info, rhs, sys_map, ref = arrays[0], arrays[1], arrays[2], arrays[3]
    lam, n_rows = s[FORGETTING], float(rows.a.shape[0])
    if s[FOLD] != 0.0:
        yty, weight, acc_rows = lam * s[ACC_YTY] + t_yty, lam * s[ACC_WEIGHT] + 1.0, lam * s[ACC_ROWS] + n_rows
    else:
        yty, weight, acc_rows = s[ACC_YTY], s[ACC_WEIGHT], s[ACC_ROWS]
    # the Eq. 6 shares: of the running balance by the running indicated means, of this cycle's by its own
    balance = s[BALANCE] if math.isfinite(s[BALANCE]) else s[BALANCE_MEAN]
    share_s, sig_s, _ = share_kernel(s[BALANCE_MEAN], cylinders.indicated_mean, s[MOTORED], s[SHARE_SPREAD],
                                     s[MOTORED_SPREAD], s[FIRING_FRACTION])
    share_c, sig_c, _ = share_kernel(balance, cylinders.indicated, s[MOTORED], s[SHARE_SPREAD], s[MOTORED_SPREAD],
                                     s[FIRING_FRACTION])
    n_s, r_s = _prior_with_share(model.prior_info, model.prior_rhs, model.cylinder_rows, share_s, sig_s)
    n_c, r_c = _prior_with_share(model.prior_info, model.prior_rhs, model.cylinder_rows, share_c, sig_c)
    e1, e2 = np.empty(0), np.empty((0, 0))
    post_s = post_c = (e1, 1.0, e2, e2, e2)
    status_s = status_c = BAD_SHAPE
    if ok:
        status_s, params_s, chi2_s, stat_s, cov_s, ref_s = posterior_kernel(
            info, rhs, yty, acc_rows, sys_map, ref, n_s, r_s, budget, model.lower, REFERENCE_MAX_CONDITION)
        status_c, params_c, chi2_c, stat_c, cov_c, ref_c = posterior_kernel(
            t_info, t_rhs, t_yty, n_rows, t_map, t_ref, n_c, r_c, rows.sys_var, model.lower, REFERENCE_MAX_CONDITION)
        post_s = (params_s, chi2_s, stat_s, cov_s, ref_s)
        post_c = (params_c, chi2_c, stat_c, cov_c, ref_c)
    report = _report_stub(share_s.shape[0])
    if status_s == OK and status_c == OK:
        report = report_kernel(post_s, post_c, (share_s, share_c), model, cylinders, s, (info, rhs, weight))
    return (ok, terms, arrays, budget, (yty, weight, acc_rows), (share_s, share_c), (n_s, r_s, n_c, r_c),
            (status_s, status_c), post_s, post_c, report)


@numba.njit(cache=True)
def _report_stub(z):
    """report_kernel's answer's types, empty (a posterior not OK)."""
    e2 = np.empty((0, 0))
    est = (np.empty((0, 0, 0)), np.empty((0, 0), dtype=np.bool_), e2, 0.0, 0.0, (e2, np.empty(0, dtype=np.bool_), 0.0))
    return est, est, np.zeros(z)


class StepResult(NamedTuple):
    """One identification step's answer: this cycle's terms, the accumulator after it, the speed rows' budget
    (R,), the posteriors of the smoothed and of the cycle's estimate, and the two reported estimates (the smoothed
    one after its pull check; both before ``measured_or_withheld``)."""

    terms: CycleTerms
    accumulator: Accumulator
    budget: np.ndarray
    smoothed: Posterior
    cycle: Posterior
    smoothed_estimate: FrictionEstimate
    cycle_estimate: FrictionEstimate


class StepSettings(NamedTuple):
    """The step's settings (MonitorConfig's): the forgetting factor, whether this cycle is folded in, the report
    limits, the model-error floor (None: none), the calibration, the pull check, model_rel_error and the Eq. 6
    share's spread."""

    forgetting: float
    fold: bool
    limits: ReportLimits
    floor: ModelErrorFloor | None
    calibration: Calibration
    pull_check: PullCheck
    model_rel_error: float
    share_spread: float


class StepInputs(NamedTuple):
    """One cycle's inputs to the step: the whitened rows (noise_model.WhitenedCycle, free end and free response
    included), the fitted angle harmonics (M,) complex, the mean-balance row (P,), the cylinders' rows over the
    friction parameters (z, p_f), the basis means (z, L), the running and this cycle's indicated means (z,), the
    running and this cycle's balance [N m], one motored cylinder's friction [N m], the two checks' (balance
    offset of identify_cycle's ``same``, its sigma; the cycle's balance sigma), the coupling loss and misfit, the TDC
    sensitivities (z,), the kinetic term [N m], and the load the balance subtracts [N m] and whether it was read as
    electrical power (the calibration's load term)."""

    white: object
    harmonics: np.ndarray
    mean_row: np.ndarray
    cylinder_rows: np.ndarray
    basis_mean: np.ndarray
    indicated_mean: np.ndarray
    indicated: np.ndarray
    balance_mean: float
    balance: float
    motored: float
    same: tuple[float, float, float]
    coupling_loss: float
    misfit: float
    tdc: np.ndarray
    kinetic: float
    load: float = float("nan")
    load_from_power: bool = False


def identify_step_reference(spec: EngineSpec, layout: ParameterLayout, prior: PriorNormal, lower: np.ndarray,
                            acc: Accumulator, params: np.ndarray, inp: StepInputs, cfg: StepSettings) -> StepResult:
    """The step by its files' wrappers one after another (``identify_step_kernel``'s reference and the general
    path): accumulate_cycle, share_mean_loss twice, PriorNormal.with_share twice, posterior_from_normal twice,
    reported_estimate twice, PullCheck.sigma and with_pull."""
    white = inp.white
    terms, acc, budget = accumulate_cycle(acc, white, cfg.forgetting, cfg.fold, params, cfg.model_rel_error,
                                          inp.harmonics)
    acc_c = Accumulator.of_terms(terms)  # this cycle's equations alone
    balance = inp.balance
    share_s = share_mean_loss(inp.balance_mean, inp.indicated_mean, inp.motored, cfg.share_spread)
    share_c = share_mean_loss(balance if math.isfinite(balance) else inp.balance_mean, inp.indicated, inp.motored,
                              cfg.share_spread)
    rows = inp.cylinder_rows
    prior_s, prior_c = prior.with_share(rows, share_s), prior.with_share(rows, share_c)
    post_s = posterior_from_normal(acc, *prior_s, budget, lower)
    post_c = posterior_from_normal(acc_c, *prior_c, white.sys_var, lower)
    offset, same_sigma, bal_sigma = inp.same
    fit_total = float(inp.mean_row @ post_s.params)
    same = (fit_total + offset if math.isfinite(inp.balance_mean) and math.isfinite(offset)
            and math.isfinite(fit_total) else float("nan"))
    check_s = BalanceCheck(inp.indicated_mean, same, same_sigma, inp.coupling_loss, inp.misfit)
    check_c = BalanceCheck(inp.indicated, balance, bal_sigma, inp.coupling_loss, inp.misfit)
    est_s = reported_estimate(spec, layout, post_s, inp.basis_mean, share_s.friction_mean, cfg.limits, rows,
                              cfg.floor, check_s, cfg.calibration,
                              CalibrationSensitivity(inp.tdc, inp.indicated_mean, load=inp.load,
                                                     load_from_power=inp.load_from_power))
    est_c = reported_estimate(spec, layout, post_c, inp.basis_mean, share_c.friction_mean, cfg.limits, rows,
                              cfg.floor, check_c, cfg.calibration,
                              CalibrationSensitivity(inp.tdc, inp.indicated, inp.kinetic, inp.load, inp.load_from_power))
    # the smoothed figures drawn by a repeated error the sandwich does not see (one cycle's equations alone fix no
    # data-only point: the cycle's estimate is not checked)
    est_s = with_pull(est_s, cfg.pull_check.sigma(acc, post_s, rows, share_s.friction_mean),
                      cfg.limits.resolve_rel, spec)
    return StepResult(terms, acc, budget, post_s, post_c, est_s, est_c)


def identify_step(spec: EngineSpec, layout: ParameterLayout, prior: PriorNormal, lower: np.ndarray,
                  acc: Accumulator, params: np.ndarray, inp: StepInputs, cfg: StepSettings) -> StepResult:
    """``identify_step_reference``'s answer from one ``identify_step_kernel`` call (its reference where the kernel
    says ok False, or the arrays are of another dtype or layout than the kernel was compiled for)."""
    white = inp.white
    kept = acc.raw_rows is not None and acc.raw_target is not None
    lam = float(cfg.forgetting)
    if not 0.0 <= lam <= 1.0:
        return identify_step_reference(spec, layout, prior, lower, acc, params, inp, cfg)
    raw_weight = (lam * acc.raw_weight + 1.0 if kept else 1.0) if cfg.fold else acc.raw_weight
    raw = (acc.raw_rows, acc.raw_target) if kept else (np.empty((0, 0)), np.empty(0))
    floor, cal, lim = cfg.floor, cfg.calibration, cfg.limits
    offset, same_sigma, bal_sigma = inp.same
    kinetic = inp.kinetic if math.isfinite(inp.kinetic) else 0.0
    settings = np.array((
        lam, 1.0 if cfg.fold else 0.0, raw_weight, cfg.model_rel_error, acc.yty, acc.weight, acc.rows,
        inp.balance_mean, inp.balance, inp.motored, cfg.share_spread, MOTORED_SPREAD_DEFAULT, FIRING_FRACTION_DEFAULT,
        lim.resolve_rel, lim.coefficient_snr, lim.min_data_gain, 0.0 if floor is None else 1.0,
        1.0 if floor is not None and floor.balance_check else 0.0, floor.indicated_rel if floor else 0.0,
        floor.coupling_per_misfit if floor else 0.0, floor.misfit_free if floor else 0.0, inp.coupling_loss,
        inp.misfit, offset, same_sigma, bal_sigma, cal.tdc_wheel_sigma_rad ** 2,
        cal.gain_common_sigma ** 2, 0.0, (cal.inertia_sigma * kinetic) ** 2,
        cal.load_variance(inp.load, inp.load_from_power),
        spec.mep_per_torque_cyl, spec.mep_per_torque_engine, cfg.pull_check.kappa), dtype=np.float64)  # STEP_FIELDS
    f64 = np.float64
    rows = StepRows(white.a, white.y, white.inv_sigma, white.sys_var, white.stats.var, white.freq, inp.harmonics)
    model = StepModel(prior.info, prior.rhs, read_only(lower), layout.group, layout.prior,
                      np.ascontiguousarray(inp.basis_mean, dtype=f64),
                      np.ascontiguousarray(inp.cylinder_rows, dtype=f64),
                      np.ascontiguousarray(inp.mean_row, dtype=f64), np.asarray(params, dtype=f64))
    cylinders = StepCylinders(np.ascontiguousarray(inp.indicated_mean, dtype=f64),
                              np.ascontiguousarray(inp.indicated, dtype=f64), np.ascontiguousarray(inp.tdc, dtype=f64),
                              cal.own_variances(spec.n_cyl))
    try:
        (ok, terms, arrays, budget, (yty, weight, acc_rows), shares, priors, status, post_s, post_c,
         report) = identify_step_kernel(rows, (acc.info, acc.rhs, acc.sys_map, acc.info_reference, *raw), model,
                                        cylinders, settings)
    except TypeError:  # another dtype or layout (cycle_step_kernel's explicit signature): the reference converts
        ok = False
    if not ok:
        return identify_step_reference(spec, layout, prior, lower, acc, params, inp, cfg)
    t_info, t_rhs, t_yty, t_map, t_ref = terms
    terms = CycleTerms(t_info, t_rhs, t_yty, float(white.a.shape[0]), t_map, t_ref)
    if cfg.fold:
        acc = Accumulator(arrays[0], arrays[1], yty, weight, acc_rows, arrays[2], arrays[3], arrays[4], arrays[5],
                          raw_weight)
    smoothed = Posterior(post_s[0], post_s[3], post_s[2], float(post_s[1]), weight, post_s[4])
    cycle = Posterior(post_c[0], post_c[3], post_c[2], float(post_c[1]), 1.0, post_c[4])
    if status != (OK, OK):  # a bound active (NNLS decides) or LAPACK's general path: posterior_from_normal's
        n_s, r_s, n_c, r_c = priors
        if status[0] != OK:
            smoothed = posterior_from_normal(acc, n_s, r_s, budget, lower)
        if status[1] != OK:
            cycle = posterior_from_normal(Accumulator.of_terms(terms), n_c, r_c, white.sys_var, lower)
        report = report_kernel(*(_posterior_tuple(p) for p in (smoothed, cycle)), shares, model, cylinders, settings,
                               (acc.info, acc.rhs, float(acc.weight)))
    est_s, est_c, pull = report
    est_s = estimate_from_tables(est_s, shares[0], smoothed, cal.status, spec.mep_per_torque_engine)
    est_c = estimate_from_tables(est_c, shares[1], cycle, cal.status, spec.mep_per_torque_engine)
    est_s = with_pull(est_s, pull, lim.resolve_rel, spec)
    return StepResult(terms, acc, budget, smoothed, cycle, est_s, est_c)


def _posterior_tuple(post: Posterior) -> tuple:
    """(params, chi2_reduced, cov_stat, covariance, cov_reference): a Posterior as report_kernel reads it."""
    return (post.params, float(post.chi2_reduced), post.cov_statistical, post.covariance, post.cov_reference)
