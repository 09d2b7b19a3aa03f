"""The per-cycle monitor: one assembled ``Cycle`` in, one ``CycleResult`` out, state explicit (design.md §4).

    state = initial_state(spec)
    for cycle in cycles:
        state, result = process_cycle(spec, state, cycle)

Per cycle:
1. Fit the flywheel motion to the raw tooth times (core.monitor.flywheel): harmonics of the cycle period, no sinc to undo.
   The tooth-spacing error above the band is learned from the fit residuals; inside the band it is fixed in angle and
   repeats every revolution, so at one operating point it cannot be told from a steady engine response at integer
   orders: it is carried as accumulated nuisance parameters E_n with a prior of its expected size, their columns
   computed exactly by passing the angle patterns through the same fit.
2. Torques on the cycle's time grid (core.monitor.excitation): gas from the measured pressure, the reciprocating remainder,
   the six friction basis terms per cylinder, each at its own throw's angle and speed, static twist included.
3. Harmonic balance through the torsional chain (core.model.dynamics; the transfer functions depend on Omega only and are
   rebuilt only when the operating point moves): known response W0 and the friction design, affine in the
   coefficients. The frozen terms (twist, throw speeds, J(theta) remainder) come from the previous cycle's model
   motion (warm start), refreshed once on the first cycle (physics.md §12.3: one refresh is enough).
4. Mean balance T_fM = T_iM - T_LM - modelled damper/coupling dissipation (physics.md §6, §12.4), T_iM as the work of
   each throw. No per-cycle kinetic-energy term: an estimate of it is biased by whatever the fit lacks, while the
   uncorrected balance telescopes and its cycle-to-cycle noise averages out.
5. The cycle's own speed drift is a per-cycle random effect (never accumulated); the whitened equations are
   accumulated with forgetting and solved with the priors (core.monitor.priors) and theta >= 0, per cycle and smoothed
   (core.monitor.accumulate); reported with honest sigmas and resolved flags (core.monitor.estimate, core.monitor.cycle_report).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from frictionwatch.core.monitor.accumulate import Accumulator, ResidualStats, posterior_from_normal
from frictionwatch.core.monitor.cycle_report import build_result
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.estimate import friction_estimate_leading
from frictionwatch.core.monitor.flywheel import ToothLearner
from frictionwatch.core.monitor.frozen_init import fast_constructor
from frictionwatch.core.monitor.harmonic_balance import OperatingPoint, harmonic_balance, operating_point
from frictionwatch.core.monitor.identify import ParameterLayout, parameter_layout
from frictionwatch.core.monitor.identify_step import identify_step
from frictionwatch.core.model.indicated import _peak_pressure_finite, peak_pressure
from frictionwatch.core.monitor.monitor_glue import freq_times_1j, glue_plan, noise_model_rows, shares_pair  # noqa: F401 (re-export)
from frictionwatch.core.model.pairwise import pairwise_sum
from frictionwatch.core.monitor.priors import build_priors
from frictionwatch.core.monitor.results import CycleResult
from frictionwatch.core.monitor.tooth_fit import fit_cycle_teeth
from frictionwatch.core.types import Cycle

FOUR_PI = 4.0 * np.pi


class CycleRejected(ValueError):
    """The cycle cannot be analysed honestly. ``reason`` is a short tag the pipeline counts; str() explains."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass(frozen=True)
class MonitorConfig:
    """Hyper-parameters of the monitor (all have defaults that suit the presets).

    max_order: highest engine order used in the identification (None: from the wheel, <= 12)
    fit_order: highest order fitted to the teeth (None: max_order); fit_drift: fit a linear speed drift per cycle
    (off: over one cycle it is nearly collinear with order 0.5 and drags in content from above the band)
    drift_nuisance: instead, treat each cycle's linear speed drift as a random effect of that cycle's equations (its
    shape passed through the same tooth fit, its prior size from the cycle-to-cycle mean-speed steps), so speed
    changes between cycles neither bias nor add noise to the estimate
    time_samples: samples per cycle of the harmonic-balance time grid (192 = 8x the highest harmonic at M = 24).
    Against 256: per-cylinder errors within 0.5 points (K9K, Maruti; V20 within its sigma), total FMEP within 0.1
    point, deutz NRMSE within 0.5 point; 128 shifted the K9K total by up to -0.25 point (the friction terms' sharp
    features alias into the band), 512 moved nothing beyond noise
    scheme, prior_coefficients: parameter grouping and baseline a0 (core.monitor.identify.parameter_layout)
    forgetting: per-cycle factor of the accumulated equations, 1 - 1/N_window (None: N_window = max(400, 100 z)
    cycles, since more cylinders need more cycles; physics.md §12.5)
    noise_memory: EWMA factor of the residual statistics that whiten the equations
    share_spread: 1-sigma of the Eq. 6 sharing prior, relative; parameter_sigma: weak prior on each scale (theta ~ 1)
    sibling_spread: 1-sigma of a per-cylinder scale about the mean of its siblings (0: no sibling prior)
    model_rel_error: repeatable model error of a speed harmonic, relative to its size (physics.md §12.3: 0.2 %)
    balance_rel_error: repeatable error of the mean balance relative to T_iM (pressure gain/TDC, load sensor)
    coupling_rel_error: relative error of the modelled damper/coupling dissipation
    load_rel_error: load-sensor accuracy as a fraction of the rated torque (a class-0.05 torque flange: 0.05 %)
    resolve_rel: a per-cylinder mean is reported when its 1-sigma is at most this fraction of it
    coefficient_snr: a coefficient is reported when it exceeds this many sigmas
    min_data_gain: ... and either only when the speed signal, not the priors, gave at least this share of what is
    known about it (core.monitor.accumulate.Posterior.data_gain; for a cylinder: its deviation from the equal share)
    passes: harmonic-balance passes per cycle; rebuild_tolerance: relative Omega change that rebuilds Z^-1
    tooth_nuisance: carry the in-band tooth-spacing error (integer orders) as accumulated nuisance parameters with
    a prior from ``tooth_error_deg``, the expected rms per-tooth angle error (core.monitor.identify.tooth_patterns)
    variable_inertia: model J(theta) and the mass torque (off only to analyse a plant without them)
    learn_teeth: learn the out-of-band tooth pattern from the fit residuals (core.monitor.flywheel.ToothLearner) with EWMA
    factor ``tooth_memory``; the fit is repeated with the fresh correction for the first ``tooth_refit_cycles``
    warmup_cycles: cycles whose equations are not accumulated (the tooth learner and noise model settle first)
    """

    max_order: float | None = None
    fit_order: float | None = None
    fit_drift: bool = False
    drift_nuisance: bool = True
    time_samples: int = 192
    scheme: str | None = None
    prior_coefficients: np.ndarray | None = None
    forgetting: float | None = None
    noise_memory: float = 1.0 - 1.0 / 100.0
    share_spread: float = 0.3
    sibling_spread: float = 0.15
    parameter_sigma: float = 1.0
    model_rel_error: float = 0.003
    balance_rel_error: float = 0.001
    coupling_rel_error: float = 0.1
    load_rel_error: float = 5e-4
    resolve_rel: float = 0.10
    coefficient_snr: float = 2.0
    min_data_gain: float = 0.5
    passes: int = 2
    rebuild_tolerance: float = 0.005
    tooth_nuisance: bool = True
    tooth_error_deg: float = 0.05
    learn_teeth: bool = True
    variable_inertia: bool = True
    tooth_memory: float = 1.0 - 1.0 / 100.0
    tooth_refit_cycles: int = 50
    warmup_cycles: int = 20


@dataclass(frozen=True)
class MonitorState:
    """Everything carried from one cycle to the next (scipy ``zi`` style: in and out of ``process_cycle``)."""

    layout: ParameterLayout
    n_harmonics: int
    n_nuisance: int
    accumulator: Accumulator
    stats: ResidualStats
    theta: np.ndarray
    op: OperatingPoint | None
    relative_motion: np.ndarray | None
    static: np.ndarray | None
    teeth: ToothLearner
    balance_mean: float
    indicated_mean: np.ndarray
    cycles: int
    prev_omega: float = float("nan")
    drift_var: float = 0.0
    tooth_pattern_cache: tuple[np.ndarray, np.ndarray] | None = None  # (edge angles from the first, patterns)
    prior_normal: tuple | None = None  # (config key, N, r): normal equations of the fixed priors (core.monitor.priors)
    glue_plan: tuple | None = None  # per-spec constants of the glue (core.monitor.monitor_glue)


_DEFAULT_CONFIG = MonitorConfig()  # frozen: one instance serves every call without a config

# the per-cycle frozen objects, built without the per-field frozen __setattr__ (core.monitor.frozen_init)
_make_state = fast_constructor(MonitorState)
_make_accumulator = fast_constructor(Accumulator)


def default_max_order(spec: EngineSpec) -> float:
    """Half the per-revolution tooth count over 5 (enough edges per harmonic), capped at order 12."""
    teeth = spec.sensors.wheel_teeth - spec.sensors.wheel_missing
    return float(min(12.0, np.floor(teeth / 5.0 * 2.0) / 2.0))


def initial_state(spec: EngineSpec, config: MonitorConfig | None = None,
                  tooth_correction: np.ndarray | None = None) -> MonitorState:
    """A fresh state: no accumulated cycles, parameters at the prior (theta = 1)."""
    cfg = config or MonitorConfig()
    layout = parameter_layout(spec, cfg.scheme, cfg.prior_coefficients)
    m = round(2 * (cfg.max_order or default_max_order(spec)))
    if m < 1 or 2 * m >= cfg.time_samples:
        raise ValueError(f"max_order gives {m} harmonics; need 1 <= M < time_samples/2 = {cfg.time_samples // 2}")
    if tooth_correction is not None and np.shape(tooth_correction) != (spec.sensors.wheel_teeth,):
        raise ValueError(f"tooth_correction must have one angle per wheel position ({spec.sensors.wheel_teeth})")
    n_nuis = 2 * (m // 2) if cfg.tooth_nuisance else 0
    p = layout.n_params + n_nuis
    return MonitorState(layout=layout, n_harmonics=m, n_nuisance=n_nuis, accumulator=Accumulator.empty(p, 2 * m + 1),
                        stats=ResidualStats.empty(m), theta=np.concatenate([np.ones(layout.n_params),
                                                                             np.zeros(n_nuis)]),
                        op=None, relative_motion=None, static=None,
                        teeth=ToothLearner(np.zeros(spec.sensors.wheel_teeth) if tooth_correction is None
                                           else np.asarray(tooth_correction, dtype=np.float64).copy(), 0),
                        balance_mean=float("nan"),
                        indicated_mean=np.full(spec.n_cyl, np.nan), cycles=0)


def process_cycle(spec: EngineSpec, state: MonitorState, cycle: Cycle,
                  config: MonitorConfig | None = None) -> tuple[MonitorState, CycleResult]:
    """Analyse one cycle. Raises ``CycleRejected`` (state unchanged) when the cycle cannot be used."""
    cfg = config or _DEFAULT_CONFIG
    pressure, flags, pmax, pmax_angle = _checked_pressure_peaks(spec, cycle)
    m = state.n_harmonics
    try:
        fly, teeth, theta_start, pattern_cache = fit_cycle_teeth(
            cycle, spec.sensors.wheel_teeth, m, state.n_nuisance, state.teeth, state.tooth_pattern_cache,
            cfg.drift_nuisance, round(2 * cfg.fit_order) if cfg.fit_order else m, cfg.fit_drift, cfg.learn_teeth,
            cfg.tooth_memory, cfg.tooth_refit_cycles)
    except ValueError as exc:
        raise CycleRejected("bad_teeth", str(exc)) from exc
    omega = fly.omega_mean
    load = cycle.load_torque if math.isfinite(cycle.load_torque) else cycle.load_power / omega
    if not math.isfinite(load):
        flags.append("no_load_measurement")
    op = operating_point(spec, state.op, omega, load, m, cfg.rebuild_tolerance, cfg.variable_inertia, state.layout)
    if op is not state.op and state.op is not None:
        flags.append("operating_point_changed")

    bal = harmonic_balance(op, state.theta, state.n_nuisance, state.relative_motion, state.static, cycle.grid,
                           pressure, fly, theta_start, cfg.passes, cfg.time_samples)
    exc, rows, node_speed, rel, static, p_rel, p_gnd = (bal.excitation, bal.rows, bal.node_speed, bal.relative_motion,
                                                        bal.static, bal.power_relative, bal.power_ground)
    # relative dampers (damper, shaft, coupling) dissipate mean power that a balance against the load behind the
    # coupling would book as friction (physics.md §12.4); the load's own ripple work (ground damping) belongs to
    # the load: the measured torque is a time mean, the work it absorbs is that plus <T_L~ omega_L~>
    coupling_loss = p_rel / omega
    if math.isfinite(load):
        load = load + p_gnd / omega
    t_ind = exc.indicated_mean
    if t_ind.dtype == np.float64 and t_ind.ndim == 1 and t_ind.flags.c_contiguous:
        t_i = pairwise_sum(t_ind, 0, t_ind.shape[0])  # numpy's sum, bit for bit, without the ufunc machinery
    else:
        t_i = float(t_ind.sum())
    # no kinetic-energy term: a per-cycle estimate of it from the fitted drift is biased by any content the fit
    # lacks, while the uncorrected balance telescopes (its cycle-to-cycle noise averages out in the accumulation)
    balance = t_i - load - coupling_loss if math.isfinite(load) else float("nan")

    # cycle-to-cycle speed change: a random walk of the mean speed, its step variance tracks the within-cycle drift
    step = omega - state.prev_omega if math.isfinite(state.prev_omega) else 0.0
    drift_var = step**2 if state.cycles <= 1 else state.drift_var + max(1.0 - cfg.noise_memory, 1.0 / state.cycles) * (
        step**2 - state.drift_var)
    # noise model from past residuals (the residual without this cycle's best-fitting drift), floor from the
    # tooth-fit residual; whitened rows; this cycle's drift a random effect of prior variance s^2 (never
    # accumulated): whitened with (I + s^2 d d^T)^-1 = W^T W, W = I - c d d^T, c ||d||^2 = 1 - 1/sqrt(1 + s^2 ||d||^2)
    # (Sherman-Morrison), so a large drift projects its column out and a small one leaves the order-0.5
    # information in place; the last row is the mean balance (zero when there is no load measurement);
    # systematic variances from the persistent residual and the model-error floors (core.monitor.monitor_kernels)
    lam = cfg.forgetting if cfg.forgetting is not None else 1.0 - 1.0 / max(400.0, 100.0 * spec.n_cyl)

    # running means for the sharing prior of the smoothed estimate
    g = max(1.0 - lam, 1.0 / (state.cycles + 1))
    if not math.isfinite(balance):
        bal_mean = state.balance_mean
    elif not math.isfinite(state.balance_mean):
        bal_mean = balance
    else:
        bal_mean = state.balance_mean + g * (balance - state.balance_mean)
    rpm = omega * 60.0 / (2.0 * np.pi)
    z = spec.n_cyl

    layout = state.layout
    p_f = layout.n_params
    prior_key = (cfg.parameter_sigma, cfg.tooth_error_deg, cfg.sibling_spread)
    if state.prior_normal is not None and state.prior_normal[0] == prior_key:
        prior_normal = state.prior_normal
    else:  # the fixed priors do not change from cycle to cycle: their normal equations are kept in the state
        base = build_priors(spec, layout, state.n_nuisance, np.zeros((spec.n_cyl, p_f + state.n_nuisance)),
                            cfg.parameter_sigma, cfg.tooth_error_deg, cfg.sibling_spread).base
        prior_normal = (prior_key, *base.normal())
    plan = state.glue_plan if state.glue_plan is not None and state.glue_plan[0] is spec else glue_plan(spec, state)
    lower = plan[2]
    # the steps below in one compiled call, same numbers (core.monitor.identify_step); None: the separate steps decide
    fused = identify_step(cfg, spec, state, fly, rows, exc.indicated_mean, pmax, exc.basis_mean, rows.cylinder_rows,
                          balance, t_i, drift_var, coupling_loss, lam, g, bal_mean, rpm, prior_normal, plan)
    if fused is not None:
        stats, acc, post_s, ind_mean, fire, n_fire, freq, drift_col, est_s, est_c = fused
    else:
        # the friction block of each posterior, read in place (no head(): the kernel reads the leading p_f rows)
        basis_mean = exc.basis_mean
        cyl_rows = rows.cylinder_rows
        if not (basis_mean.dtype == np.float64 and basis_mean.flags.c_contiguous):
            basis_mean = np.ascontiguousarray(basis_mean, dtype=np.float64)
        if not (cyl_rows.dtype == np.float64 and cyl_rows.flags.c_contiguous and cyl_rows.shape[1] == p_f):
            cyl_rows = np.ascontiguousarray(cyl_rows[:, :p_f], dtype=np.float64)
        stats, a, y, inv_sigma, sys_var, freq, drift_col = noise_model_rows(cfg, spec, state, fly, rows, balance,
                                                                            t_i, drift_var, coupling_loss)
        terms = state.accumulator.cycle_terms(a, y, inv_sigma, 1)  # shared by the running and this cycle's equations
        acc = state.accumulator.fold(terms, lam) if state.cycles >= cfg.warmup_cycles else state.accumulator
        # Eq. 6 shares of the running and of this cycle's mean balance, firing mask, motored friction, running
        # indicated means and both sets of prior normal equations in one kernel (core.monitor.monitor_kernels.shares_pair_into)
        ind_mean, fric_s, fric_c, fire, n_fire, n_s, r_s, n_c, r_c = shares_pair(
            spec, state, prior_normal, rows.cylinder_rows, exc.indicated_mean, pmax, g, bal_mean,
            balance if math.isfinite(balance) else bal_mean, rpm, plan[1], cfg.share_spread)
        post_s = posterior_from_normal(acc, n_s, r_s, sys_var, lower)
        # this cycle's equations alone: lambda = 0 folded into an empty accumulator is the cycle's terms themselves
        one = _make_accumulator(info=terms.info, rhs=terms.rhs, yty=terms.yty, weight=1.0, rows=terms.rows,
                                sys_map=terms.sys_map, info_reference=terms.info_reference)
        post_c = posterior_from_normal(one, n_c, r_c, sys_var, lower)
        est_s = friction_estimate_leading(spec, layout, post_s, basis_mean, fric_s, cfg.resolve_rel,
                                          cfg.coefficient_snr, cfg.min_data_gain, cyl_rows, plan[3])
        est_c = friction_estimate_leading(spec, layout, post_c, basis_mean, fric_c, cfg.resolve_rel,
                                          cfg.coefficient_snr, cfg.min_data_gain, cyl_rows, plan[3])
    if n_fire < z:
        flags += [f"misfire_cyl{k + 1}" for k in np.flatnonzero(~fire)]

    result = build_result(spec, cycle, fly, exc, rows, post_s.theta, layout, drift_col, load, balance,
                          coupling_loss, pmax, pmax_angle, est_c, est_s, flags, freq)
    new_state = _make_state(
        layout=layout, n_harmonics=m, n_nuisance=state.n_nuisance, accumulator=acc, stats=stats, theta=post_s.theta,
        op=op, relative_motion=rel, static=static, teeth=teeth, balance_mean=bal_mean, indicated_mean=ind_mean,
        cycles=state.cycles + 1, prev_omega=omega, drift_var=drift_var, tooth_pattern_cache=pattern_cache,
        prior_normal=prior_normal, glue_plan=plan)
    return new_state, result


# ---- steps -------------------------------------------------------------------------------------------------


def _checked_pressure(spec: EngineSpec, cycle: Cycle) -> tuple[np.ndarray, list[str]]:
    p = np.asarray(cycle.pressure, dtype=np.float64)
    n = cycle.grid.shape[0]
    if p.shape != (spec.n_cyl, n):
        raise CycleRejected("bad_pressure", f"pressure has shape {p.shape}; expected ({spec.n_cyl}, {n})")
    span = (cycle.grid[-1] - cycle.grid[0]) * n / max(n - 1, 1)
    if n < 64 or abs(span - FOUR_PI) > 1e-6 * FOUR_PI:
        raise CycleRejected("bad_grid", f"the crank-angle grid must cover 720 deg uniformly ({n} points)")
    flags = list(cycle.flags)
    bad = ~np.isfinite(p)
    if bad.any():
        p = p.copy()
        for k in np.flatnonzero(bad.any(axis=1)):
            b = bad[k]
            longest = max((len(r) for r in "".join("x" if v else " " for v in b).split()), default=0)
            if longest > 3 or b.mean() > 0.02:
                raise CycleRejected("bad_pressure", f"cylinder {k + 1}: {int(b.sum())} invalid samples "
                                                    f"(longest gap {longest})")
            idx = np.arange(n)
            p[k, b] = np.interp(idx[b], idx[~b], p[k, ~b], period=n)
            flags.append(f"pressure_repaired_cyl{k + 1}")
    return p, flags




def _checked_pressure_peaks(spec: EngineSpec, cycle: Cycle) -> tuple[np.ndarray, list[str], np.ndarray, np.ndarray]:
    """``_checked_pressure`` and ``peak_pressure`` of the checked pressure: one pass over clean samples."""
    p = cycle.pressure
    n = cycle.grid.shape[0]
    phases = spec.firing_angles
    if (type(p) is np.ndarray and p.dtype == np.float64 and p.flags.c_contiguous and p.shape == (spec.n_cyl, n)
            and n >= 64 and cycle.grid.dtype == np.float64 and cycle.grid.flags.c_contiguous
            and phases.dtype == np.float64 and phases.flags.c_contiguous):
        span = (cycle.grid[-1] - cycle.grid[0]) * n / max(n - 1, 1)
        if abs(span - FOUR_PI) <= 1e-6 * FOUR_PI:
            pmax = np.empty(p.shape[0])
            angle = np.empty(p.shape[0])
            if _peak_pressure_finite(cycle.grid, p, phases, pmax, angle) == 0:
                return p, list(cycle.flags), pmax, angle
    pressure, flags = _checked_pressure(spec, cycle)  # the general path: checks, repairs, flags
    pmax, angle = peak_pressure(cycle.grid, pressure, phases)
    return pressure, flags, pmax, angle
