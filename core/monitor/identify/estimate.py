"""From a posterior over the parameters to a reported ``FrictionEstimate`` (per-cylinder means, coefficients,
sigmas, resolved masks; results.py). The numbers come from two kernels (``estimate_kernel`` and ``floor_calibration_kernel``, below)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numba
import numpy as np
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.identify.parameters import ParameterLayout
from frictionwatch.core.monitor.identify.posterior import Posterior
from frictionwatch.core.monitor.report.results import FrictionEstimate
from frictionwatch.core.tuned import MONITOR_RECORD, read_tuned

_TUNED = read_tuned(MONITOR_RECORD)  # the floor's tuned numbers with their provenance (core.tuned)


@dataclass(frozen=True)
class ReportLimits:
    """When an estimate is reported: a per-cylinder mean when its 1-sigma is at most ``resolve_rel`` of its value,
    a coefficient when its normalised value exceeds ``coefficient_snr`` sigmas; both only when the speed signal gave
    at least ``min_data_gain`` of what is known about them (the rest coming from the priors and the mean balance)."""

    resolve_rel: float
    coefficient_snr: float
    min_data_gain: float = 0.0


class BalanceCheck(NamedTuple):
    """What the floor compares an estimate with: the cylinders' indicated torques (z,) [N m], the mean balance
    T_i - T_L - coupling loss over the same cycles [N m] (NaN without a load) and its 1-sigma from the balance's own
    scatter [N m], the modelled damper/coupling dissipation in that balance [N m] and the window's mean reduced chi^2
    of the speed fit (core.monitor.checks.condition's ``model_misfit`` statistic; 1 where the noise model holds)."""

    indicated: np.ndarray
    balance: float
    balance_sigma: float
    coupling_loss: float = 0.0
    misfit: float = 1.0


@dataclass(frozen=True)
class ModelErrorFloor:
    """The systematic part of the friction sigma that the monitor's equations cannot see: errors that repeat every
    cycle because the model is not the engine (a drive train stiffer or softer than the spec, a friction law of
    another shape), checked on logs of such mismatches (bench/mismatch_coverage.py).

    The speed fit and the mean balance both measure the total friction; where the model is right they agree within
    their own sigmas. Their disagreement beyond that, excess^2 = max(0, (T_fit - T_balance)^2 - sigma_fit^2 -
    sigma_balance^2), is what the data says about the model error at this operating point, and is added in
    quadrature to the total's sigma and, in proportion, to each cylinder's (a healthy log adds ~0; a chain 20 %
    too soft, where the fit reads the K9K's friction +30 %, adds about that). ``indicated_rel`` adds
    (indicated_rel T_i)^2, T_i the indicated torque behind the figure: an error of the indicated work that the balance
    passes into friction whole (off by default: no simulator case needs it; the sensor checks own pressure errors).
    ``balance_check`` off leaves only that term.

    A drive train other than the model's moves both alike: the balance subtracts the damper and coupling dissipation
    the model computes from its own chain (physics.md §12.4), and a chain 20 % softer and better damped than the
    spec's dissipates 2.4 times the modelled 3.6 N m on the K9K at 1700 rpm, so both the fit and the balance read
    friction +29 %. What shows it is the speed fit's residual: the window's reduced chi^2 (per effective degree of
    freedom, core.monitor.checks.condition) rises. ``coupling_per_misfit`` k adds (k max(0, misfit - misfit_free)
    coupling_loss)^2: the modelled dissipation is not trusted once the fit says the chain is not the engine's.
    k and misfit_free are tuned numbers (core/monitor/tuned.json: MODEL_ERROR_COUPLING_PER_MISFIT,
    MODEL_ERROR_MISFIT_FREE, with the logs, figure and date): bench/calibrate_model_error_floor.py tunes them on k9k
    points and seeds that no test validates on, maruti-3cyl held out; tests/core/test_mismatch_coverage.py and
    bench/mismatch_coverage.py validate them (design note 29). Before that they were set by hand on the very K9K
    1700 / 1100 rpm chain logs the test checks (k = 1.0, misfit_free = 1.0; the old k = 0.6 at 1.25 on the cycle's
    own degrees of freedom)."""

    indicated_rel: float = 0.0
    balance_check: bool = True
    coupling_per_misfit: float = _TUNED["MODEL_ERROR_COUPLING_PER_MISFIT"].value
    misfit_free: float = _TUNED["MODEL_ERROR_MISFIT_FREE"].value

    def apply(self, est: FrictionEstimate, check: BalanceCheck, spec: EngineSpec,
              resolve_rel: float) -> FrictionEstimate:
        """``est`` with the floor added to its sigmas; a cylinder no longer within ``resolve_rel`` is unresolved."""
        ind = np.asarray(check.indicated, dtype=np.float64)
        t_tot, s_tot = est.total_friction_torque, est.total_friction_torque_sigma
        excess2 = 0.0
        if self.balance_check and math.isfinite(check.balance) and t_tot > 0:
            excess2 = max(0.0, (t_tot - check.balance) ** 2 - s_tot ** 2 - check.balance_sigma ** 2)
        excess2 += (self.coupling_per_misfit * max(0.0, check.misfit - self.misfit_free) * check.coupling_loss) ** 2
        if excess2 == 0.0 and self.indicated_rel == 0.0:
            return est
        t_cyl = np.where(np.isfinite(est.friction_torque_mean), est.friction_torque_mean,
                         est.prior_friction_torque_mean)
        rel2 = excess2 / t_tot ** 2 if t_tot > 0 else 0.0
        sig = np.sqrt(est.friction_torque_mean_sigma ** 2 + (self.indicated_rel * ind) ** 2 + rel2 * t_cyl ** 2)
        tot_sig = math.sqrt(s_tot ** 2 + (self.indicated_rel * float(ind.sum())) ** 2 + excess2)
        resolved = est.resolved & (sig <= resolve_rel * np.abs(t_cyl))
        t_mean = np.where(resolved, est.friction_torque_mean, np.nan)
        to_cyl = spec.mep_per_torque_cyl
        return replace(est, friction_torque_mean=t_mean, friction_torque_mean_sigma=sig, fmep=t_mean * to_cyl,
                       fmep_sigma=sig * to_cyl, resolved=resolved, total_friction_torque_sigma=tot_sig,
                       total_fmep_sigma=tot_sig * spec.mep_per_torque_engine)


class CalibrationSensitivity(NamedTuple):
    """How one cycle's mean balance moves with the calibration: tdc (z,) [N m/rad] dT_iM,k/dDelta_k, each cylinder's
    work-mean indicated torque per radian of its TDC (``indicated_tdc_sensitivity``); indicated (z,) [N m] T_iM,k,
    which a relative gain error scales; kinetic [N m] the kinetic-energy term J a, which a relative J error scales
    (NaN: no term, e.g. no cycle before); load [N m] the load the balance subtracts, which a relative error of the
    load reading scales (NaN: none), read as electrical power where ``load_from_power``."""

    tdc: np.ndarray
    indicated: np.ndarray
    kinetic: float = float("nan")
    load: float = float("nan")
    load_from_power: bool = False


def calibration_variances(cal: Calibration, sens: CalibrationSensitivity) -> np.ndarray:
    """The four variances common to the cylinders that ``_calibration_variance_kernel`` reads (its ``var``): the
    wheel's TDC [rad^2], the gain common to every channel, the kinetic term's and the load's [N^2 m^2]. Each
    cylinder's own TDC and gain variances are ``Calibration.own_variances`` (its ``own``)."""
    kinetic = sens.kinetic if math.isfinite(sens.kinetic) else 0.0
    return np.array([cal.tdc_wheel_sigma_rad ** 2, cal.gain_common_sigma ** 2, (cal.inertia_sigma * kinetic) ** 2,
                     cal.load_variance(sens.load, sens.load_from_power)])


def calibration_variance(cal: Calibration, sens: CalibrationSensitivity,
                         share: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """(per cylinder (z,), engine total) [N^2 m^2]: the variance the calibration's remaining uncertainty adds to the
    friction figures. The mean balance passes an error of the indicated work into friction whole: the wheel's TDC
    moves every cylinder alike (the total by sum_k dT_k, fully correlated), a cylinder's own TDC and gain its own;
    J's error moves the kinetic-energy term (the engine total only: it is not a cylinder's; it changes sign from
    cycle to cycle). A gain common to all channels moves the total by its sum, like the wheel's TDC. The load
    reading's error moves the total whole, and each cylinder's figure by its part of the engine's friction: ``share``
    (z,) [N m] (the Eq. 6 share the estimate's prior holds; None or not positive: equal parts). One kernel
    (``_calibration_variance_kernel``; its numpy reference ``calibration_variance_reference``)."""
    tdc, t_i = np.asarray(sens.tdc, dtype=np.float64), np.asarray(sens.indicated, dtype=np.float64)
    if tdc.shape != t_i.shape or tdc.ndim != 1:
        raise ValueError(f"the TDC sensitivities {tdc.shape} and indicated torques {t_i.shape} need one per cylinder")
    share = np.ones(tdc.shape[0]) if share is None else np.asarray(share, dtype=np.float64)
    return _calibration_variance_kernel(tdc, t_i, share, calibration_variances(cal, sens),
                                        cal.own_variances(tdc.shape[0]))


def load_split(share: np.ndarray) -> np.ndarray:
    """Each cylinder's part of the engine's friction (z,), summing to 1: ``share`` normalised where every value is
    finite and their sum positive, else equal parts (the numpy reference of the kernel's split)."""
    share = np.asarray(share, dtype=np.float64)
    total = float(np.sum(share))
    if not (np.isfinite(share).all() and total > 0.0):
        return np.full(share.shape[0], 1.0 / share.shape[0])
    return share / total


def calibration_variance_reference(cal: Calibration, sens: CalibrationSensitivity,
                                   share: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """``calibration_variance`` in plain numpy (its reference)."""
    s, t_i = np.abs(sens.tdc), np.abs(sens.indicated)
    w2, gc2 = cal.tdc_wheel_sigma_rad ** 2, cal.gain_common_sigma ** 2
    c2, g2 = cal.own_variances(s.shape[0])  # each cylinder's own TDC and gain (z,)
    load2 = cal.load_variance(sens.load, sens.load_from_power)
    split = load_split(np.ones(s.shape[0]) if share is None else share)
    per = s * s * w2 + t_i * t_i * gc2 + (s * s * c2 + t_i * t_i * g2) + load2 * split ** 2
    kinetic = sens.kinetic if math.isfinite(sens.kinetic) else 0.0
    total = (float(np.sum(sens.tdc)) ** 2 * w2 + float(np.sum(s * s * c2)) + float(np.sum(t_i * t_i * g2))
             + float(np.sum(sens.indicated)) ** 2 * gc2 + (cal.inertia_sigma * kinetic) ** 2 + load2)
    return per, total


@numba.njit(cache=True)
def _calibration_variance_kernel(tdc, indicated, share, var, own):
    """(per (z,), total) of ``calibration_variance_reference``; share (z,) the cylinders' parts of the friction
    [N m] (``load_split``); var: ``calibration_variances``; own (2, z): ``Calibration.own_variances``."""
    w2, gc2, kinetic2, load2 = var[0], var[1], var[2], var[3]
    z = tdc.shape[0]
    per = np.empty(z)
    s_sum = 0.0
    own_sum = 0.0  # sum over cylinders of their own TDC's and gain's parts
    t_sum = 0.0
    share_sum = 0.0
    share_ok = True
    for k in range(z):
        share_sum += share[k]
        share_ok = share_ok and np.isfinite(share[k])
    share_ok = share_ok and share_sum > 0.0
    for k in range(z):
        s, t = abs(tdc[k]), abs(indicated[k])
        part = share[k] / share_sum if share_ok else 1.0 / z
        own_k = s * s * own[0, k] + t * t * own[1, k]
        per[k] = s * s * w2 + t * t * gc2 + own_k + load2 * part * part
        s_sum += tdc[k]
        own_sum += own_k
        t_sum += indicated[k]
    return per, s_sum ** 2 * w2 + own_sum + t_sum ** 2 * gc2 + kinetic2 + load2


def with_calibration(est: FrictionEstimate, cal: Calibration, sens: CalibrationSensitivity,
                     spec: EngineSpec) -> FrictionEstimate:
    """``est`` with the calibration's variance added to every friction and FMEP sigma (the figures themselves
    unchanged; ``resolved`` stays what the data resolve), the part it added and the calibration's status kept."""
    var_cyl, var_tot = calibration_variance(cal, sens, est.prior_friction_torque_mean)
    sig = np.sqrt(est.friction_torque_mean_sigma ** 2 + var_cyl)
    tot_sig = math.sqrt(est.total_friction_torque_sigma ** 2 + var_tot)
    return replace(est, friction_torque_mean_sigma=sig, fmep_sigma=sig * spec.mep_per_torque_cyl,
                   total_friction_torque_sigma=tot_sig, total_fmep_sigma=tot_sig * spec.mep_per_torque_engine,
                   calibration=cal.status,
                   calibration_sigma=np.sqrt(var_cyl), total_calibration_sigma=math.sqrt(var_tot))


def friction_estimate(spec: EngineSpec, layout: ParameterLayout, post: Posterior, basis_mean: np.ndarray,
                      prior_mean: np.ndarray, limits: ReportLimits,
                      cylinder_rows: np.ndarray | None = None, floor: ModelErrorFloor | None = None,
                      check: BalanceCheck | None = None) -> FrictionEstimate:
    """Report the friction part of a posterior: its leading ``layout.n_params`` parameters (friction scales first,
    then any nuisances, which are not reported).

    basis_mean (z, n_terms): work means <F_kl> of this cycle (they turn a_kl into N m); prior_mean (z,) Eq. 6 shares
    [N m]; cylinder_rows (z, n_params): ``layout.cylinder_rows(basis_mean)`` if already at hand; floor: the model-error
    floor added to the sigmas, from ``check`` (the indicated torques and the mean balance over the same cycles)."""
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
    to_cyl = spec.mep_per_torque_cyl
    to_eng = spec.mep_per_torque_engine
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
    if floor is None or check is None:
        return est
    return floor.apply(est, check, spec, float(limits.resolve_rel))


def reported_estimate(spec: EngineSpec, layout: ParameterLayout, post: Posterior, basis_mean: np.ndarray,
                      prior_mean: np.ndarray, limits: ReportLimits, cylinder_rows: np.ndarray,
                      floor: ModelErrorFloor | None, check: BalanceCheck, cal: Calibration,
                      sens: CalibrationSensitivity) -> FrictionEstimate:
    """``with_calibration(friction_estimate(..., floor, check), cal, sens, spec)`` (its reference, tested equal) with
    one FrictionEstimate built instead of three: the floor's and the calibration's per-cylinder arithmetic in one
    kernel (``floor_calibration_kernel``) after the estimate's, the scalars in Python in the reference's order.
    Per monitored cycle this runs twice (the smoothed and the cycle's estimate)."""
    z = spec.n_cyl
    p_f = layout.n_params
    params = post.params[:p_f]
    basis_mean = np.asarray(basis_mean, dtype=np.float64)
    rows = np.asarray(cylinder_rows, dtype=np.float64)
    cov, cov_stat, cov_ref = post.covariance, post.cov_statistical, post.cov_reference
    n_terms = layout.prior.shape[1]
    if (params.shape[0] != p_f or rows.shape != (z, p_f) or basis_mean.shape != (z, n_terms)
            or not cov.shape == cov_stat.shape == cov_ref.shape or cov.shape[0] < p_f or cov.shape[0] != cov.shape[1]):
        raise ValueError(f"need a posterior over >= {p_f} parameters, rows ({z}, {p_f}) and basis means "
                         f"({z}, {n_terms}); got {params.shape}, {rows.shape}, {basis_mean.shape}")
    resolve_rel = float(limits.resolve_rel)
    coef_table, coef_ok, cylinder_table, resolved, t_tot, s_tot = estimate_kernel(
        params, cov, cov_stat, cov_ref, layout.group, layout.prior, basis_mean, rows, resolve_rel,
        float(limits.coefficient_snr), float(limits.min_data_gain))
    prior = np.asarray(prior_mean, dtype=np.float64).reshape(z)
    ind = np.asarray(check.indicated, dtype=np.float64)
    # the floor's scalars (ModelErrorFloor.apply's arithmetic, its order)
    floor_on, rel2, ind_rel = False, 0.0, 0.0
    if floor is not None:
        excess2 = 0.0
        if floor.balance_check and math.isfinite(check.balance) and t_tot > 0:
            excess2 = max(0.0, (t_tot - check.balance) ** 2 - s_tot ** 2 - check.balance_sigma ** 2)
        excess2 += (floor.coupling_per_misfit * max(0.0, check.misfit - floor.misfit_free) * check.coupling_loss) ** 2
        floor_on = not (excess2 == 0.0 and floor.indicated_rel == 0.0)
        if floor_on:
            ind_rel = floor.indicated_rel
            rel2 = excess2 / t_tot ** 2 if t_tot > 0 else 0.0
            s_tot = math.sqrt(s_tot ** 2 + (ind_rel * float(ind.sum())) ** 2 + excess2)
    to_cyl, to_eng = spec.mep_per_torque_cyl, spec.mep_per_torque_engine
    settings = np.concatenate((np.array([1.0 if floor_on else 0.0, ind_rel, rel2, resolve_rel, to_cyl]),
                               calibration_variances(cal, sens)))
    tdc, t_i = np.asarray(sens.tdc, dtype=np.float64), np.asarray(sens.indicated, dtype=np.float64)
    if tdc.shape != t_i.shape or tdc.shape != (z,) or ind.shape != (z,):
        raise ValueError(f"the TDC sensitivities {tdc.shape}, indicated torques {t_i.shape} and the check's "
                         f"{ind.shape} need one per cylinder ({z})")
    floored = floor_calibration_kernel(cylinder_table, resolved, prior, ind, tdc, t_i, settings, cal.own_variances(z))
    return estimate_from_tables((coef_table, coef_ok, cylinder_table, t_tot, s_tot, floored), prior, post, cal.status,
                                to_eng)


def estimate_from_tables(tables: tuple, prior: np.ndarray, post: Posterior, calibration: str,
                         to_engine: float) -> FrictionEstimate:
    """The FrictionEstimate of ``reported_estimate``'s kernels' answers: ``tables`` = (estimate_kernel's coefficient
    table (4, z, L) and flags (z, L), its cylinder table (3, z), the total [N m] and its sigma after the floor, and
    floor_calibration_kernel's (table (5, z), resolved (z,), the calibration's total variance)); prior (z,) the Eq. 6
    share, ``calibration`` its status, to_engine MEP per N m of the engine (also core.monitor.identify.step's)."""
    coef_table, coef_ok, cylinder_table, t_tot, s_tot, (table, resolved, var_tot) = tables
    tot_sig = math.sqrt(s_tot ** 2 + var_tot)
    coef, coef_sig, norm, norm_sig = coef_table
    return FrictionEstimate(
        friction_torque_mean=table[0], friction_torque_mean_sigma=table[1], fmep=table[2], fmep_sigma=table[3],
        coefficients=coef, coefficients_sigma=coef_sig, coefficients_normalised=norm,
        coefficients_normalised_sigma=norm_sig, resolved=resolved, coefficient_resolved=coef_ok,
        total_friction_torque=float(t_tot), total_friction_torque_sigma=tot_sig, total_fmep=float(t_tot * to_engine),
        total_fmep_sigma=tot_sig * to_engine, prior_friction_torque_mean=prior, data_gain=cylinder_table[2],
        weight=float(post.weight), chi2_reduced=float(post.chi2_reduced), calibration=calibration,
        calibration_sigma=table[4], total_calibration_sigma=math.sqrt(var_tot))


@numba.njit(cache=True)
def floor_calibration_kernel(cylinder_table, resolved, prior, ind, tdc, indicated, settings, own):
    """The per-cylinder part of ``ModelErrorFloor.apply`` then ``with_calibration`` on ``estimate_kernel``'s
    cylinder_table (3, z) (t_mean NaN where unresolved, t_sig, gain) and resolved (z,); prior (z,) the Eq. 6 share
    [N m], ind (z,) the floor check's indicated torques, tdc and indicated (z,) the calibration's sensitivities;
    settings: floor on (0/1), its indicated_rel, rel2 (excess^2 / T_tot^2), resolve_rel, MEP per N m of a cylinder,
    then the calibration's four common variances (``calibration_variances``); own (2, z) each cylinder's own TDC
    and gain variances (``Calibration.own_variances``); the load's reaches each cylinder by its part of ``prior``.

    Returns (table (5, z): t_mean, sigma, fmep, fmep_sigma, calibration sigma; resolved (z,); the calibration's
    total variance)."""
    z = prior.shape[0]
    floor_on, ind_rel, rel2, resolve_rel, to_cyl = settings[0] != 0.0, settings[1], settings[2], settings[3], settings[4]
    var_cyl, var_tot = _calibration_variance_kernel(tdc, indicated, prior, settings[5:9], own)
    out = np.empty((5, z))
    ok = resolved.copy()
    for k in range(z):
        t_mean = cylinder_table[0, k]
        sig = cylinder_table[1, k]
        if floor_on:
            t_cyl = t_mean if np.isfinite(t_mean) else prior[k]
            a = ind_rel * ind[k]
            sig = np.sqrt(sig * sig + a * a + rel2 * (t_cyl * t_cyl))
            ok[k] = ok[k] and sig <= resolve_rel * abs(t_cyl)
            if not ok[k]:
                t_mean = np.nan
        sig = np.sqrt(sig * sig + var_cyl[k])
        out[0, k] = t_mean
        out[1, k] = sig
        out[2, k] = t_mean * to_cyl
        out[3, k] = sig * to_cyl
        out[4, k] = np.sqrt(var_cyl[k])
    return out, ok, var_tot


@numba.njit(cache=True)
def _quadratic_form(r, cov, tmp):
    """r^T C r over the leading len(r) rows/columns of cov (zero entries of r skipped)."""
    p = r.shape[0]
    for j in range(p):
        tmp[j] = 0.0
    for i in range(p):
        ri = r[i]
        if ri != 0.0:
            for j in range(p):
                tmp[j] += ri * cov[i, j]
    s = 0.0
    for j in range(p):
        s += tmp[j] * r[j]
    return s


@numba.njit(cache=True)
def _gain(post, ref, out):
    """1 - post / ref clipped to [0, 1]; 1 where ref is pinned down already (the share the data contributed)."""
    ref_max = 0.0
    for i in range(ref.shape[0]):
        ref_max = max(ref_max, ref[i])
    pin = 1e-12 * max(ref_max, 1e-300) + 1e-300
    for i in range(ref.shape[0]):
        if ref[i] <= pin:
            out[i] = 1.0
        else:
            out[i] = min(max(1.0 - post[i] / max(ref[i], 1e-300), 0.0), 1.0)


@numba.njit(cache=True)
def coefficient_kernel(params, cov, cov_stat, cov_ref, group, prior, basis_mean, coefficient_snr, min_data_gain):
    """Coefficients a_kl = prior_kl params_g(k,l) (z, n_terms), their sigmas, normalised values a_kl <F_kl> [N m] and
    sigmas, and which are resolved (above ``coefficient_snr`` sigmas, prior > 0, data gain of their parameter at
    least ``min_data_gain``). params (p_f,) the friction scales; the covariances (>= p_f, >= p_f) are read over
    their leading p_f block (friction first, then nuisances)."""
    z, n_terms = group.shape
    p_f = params.shape[0]
    diag_stat = np.empty(p_f)
    diag_ref = np.empty(p_f)
    sd = np.empty(p_f)
    for i in range(p_f):
        diag_stat[i] = cov_stat[i, i]
        diag_ref[i] = cov_ref[i, i]
        sd[i] = math.sqrt(max(cov[i, i], 0.0))
    gain_p = np.empty(p_f)
    _gain(diag_stat, diag_ref, gain_p)
    coef = np.empty((z, n_terms))
    coef_sig = np.empty((z, n_terms))
    norm = np.empty((z, n_terms))
    norm_sig = np.empty((z, n_terms))
    ok = np.empty((z, n_terms), dtype=np.bool_)
    for k in range(z):
        for term in range(n_terms):
            g = group[k, term]
            if g < 0:
                g += p_f  # numpy's negative index (an unused term: its prior is 0)
            coef[k, term] = prior[k, term] * params[g]
            coef_sig[k, term] = prior[k, term] * sd[g]
            norm[k, term] = coef[k, term] * basis_mean[k, term]
            norm_sig[k, term] = coef_sig[k, term] * basis_mean[k, term]
            ok[k, term] = ((norm[k, term] > coefficient_snr * norm_sig[k, term]) and prior[k, term] > 0
                           and gain_p[g] >= min_data_gain)
    return coef, coef_sig, norm, norm_sig, ok


@numba.njit(cache=True)
def cylinder_kernel(params, cov, cov_stat, cov_ref, rows):
    """Per-cylinder friction torques rows @ params (z,) and their sigmas, the total and its sigma, and the data
    gain of each cylinder's deviation from the equal share (what the speed adds is the split among cylinders).
    rows (z, p_f) act on the leading p_f parameters; the covariances are read over their leading block."""
    z, p_f = rows.shape
    tmp = np.empty(p_f)
    total_row = np.zeros(p_f)
    for k in range(z):
        for i in range(p_f):
            total_row[i] += rows[k, i]
    t_cyl = np.empty(z)
    t_sig = np.empty(z)
    for k in range(z):
        s = 0.0
        for i in range(p_f):
            s += rows[k, i] * params[i]
        t_cyl[k] = s
        t_sig[k] = math.sqrt(max(_quadratic_form(rows[k], cov, tmp), 0.0))
    t_tot = 0.0
    for i in range(p_f):
        t_tot += total_row[i] * params[i]
    t_tot_sig = math.sqrt(max(_quadratic_form(total_row, cov, tmp), 0.0))
    dev = np.empty(p_f)
    post = np.empty(z)
    refs = np.empty(z)
    for k in range(z):
        for i in range(p_f):
            dev[i] = rows[k, i] - total_row[i] / z
        post[k] = _quadratic_form(dev, cov_stat, tmp)
        refs[k] = _quadratic_form(dev, cov_ref, tmp)
    gain = np.empty(z)
    _gain(post, refs, gain)
    return t_cyl, t_sig, t_tot, t_tot_sig, gain


@numba.njit(cache=True)
def estimate_kernel(params, cov, cov_stat, cov_ref, group, prior, basis_mean, rows, resolve_rel, coefficient_snr,
                    min_data_gain):
    """``coefficient_kernel`` and ``cylinder_kernel`` with the masks applied: unresolved coefficients and
    per-cylinder means are NaN. A per-cylinder mean is resolved when its sigma is at most ``resolve_rel`` of it and
    its data gain at least ``min_data_gain``.

    Returns coef_table (4, z, n_terms) = (coef, coef_sig, norm, norm_sig), coef_ok (z, n_terms), cylinder_table
    (3, z) = (t_mean, t_sig, gain), resolved (z,), t_tot, t_tot_sig (stacked: every array returned to Python
    costs about as much as a small kernel's arithmetic)."""
    coef, coef_sig, norm, norm_sig, coef_ok = coefficient_kernel(params, cov, cov_stat, cov_ref, group, prior,
                                                                 basis_mean, coefficient_snr, min_data_gain)
    z, n_terms = coef.shape
    coef_table = np.empty((4, z, n_terms))
    for k in range(z):
        for term in range(n_terms):
            masked = not coef_ok[k, term]
            coef_table[0, k, term] = np.nan if masked else coef[k, term]
            coef_table[1, k, term] = coef_sig[k, term]
            coef_table[2, k, term] = np.nan if masked else norm[k, term]
            coef_table[3, k, term] = norm_sig[k, term]
    t_cyl, t_sig, t_tot, t_tot_sig, gain = cylinder_kernel(params, cov, cov_stat, cov_ref, rows)
    cylinder_table = np.empty((3, z))
    resolved = np.empty(z, dtype=np.bool_)
    for k in range(z):
        resolved[k] = t_sig[k] <= resolve_rel * abs(t_cyl[k]) and gain[k] >= min_data_gain
        cylinder_table[0, k] = t_cyl[k] if resolved[k] else np.nan
        cylinder_table[1, k] = t_sig[k]
        cylinder_table[2, k] = gain[k]
    return coef_table, coef_ok, cylinder_table, resolved, t_tot, t_tot_sig
