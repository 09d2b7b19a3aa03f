"""The per-cycle monitor: one assembled ``Cycle`` in, one ``CycleResult`` out, state explicit (design.md §4).

    state = initial_state(model)                 # an EngineModel (core.model), or an EngineSpec: its default model
    for cycle in cycles:
        state, result = process_cycle(model, state, cycle)

Per cycle:
1. Fit the flywheel motion to the raw tooth times (core.monitor.teeth.flywheel): harmonics of the cycle period, no sinc to undo.
   The tooth-spacing error above the band is learned from the fit residuals; inside the band it is fixed in angle and
   repeats every revolution, so at one operating point it cannot be told from a steady engine response at integer
   orders: it is carried as accumulated nuisance parameters E_n with a prior of its expected size, their columns
   computed exactly by passing the angle patterns through the same fit.
2. Torques on the cycle's time grid (core.monitor.balance.excitation): gas from the measured pressure, the reciprocating remainder,
   the model's loss terms per cylinder (core.model.terms: the six Rezeka-Henein terms by default), each at its own
   throw's angle and speed, static twist included.
3. Harmonic balance through the torsional chain (core.model.dynamics; the transfer functions depend on Omega only and are
   rebuilt only when the operating point moves): known response W0 and the friction design, affine in the
   coefficients. The frozen terms (twist, throw speeds, J(theta) remainder) come from the previous cycle's model
   motion (warm start), refreshed once on the first cycle (physics.md §12.3: one refresh is enough).
4. Mean balance T_fM = T_iM - T_LM - modelled damper/coupling dissipation - d/dt(1/2 J w^2)/w (physics.md §6, §12.4)
   over the window centred on cylinder 1's firing TDC, from this cycle and the one before (two measured mid-cycle
   speeds, no drift fitted: core.monitor.balance.mean_balance.transient_balance); IMEP over each cylinder's own window.
5. The cycle's own speed drift is a per-cycle random effect (never accumulated); the whitened equations are
   accumulated with forgetting and solved with the priors (core.monitor.identify.parameters) and params >= 0, per cycle and smoothed
   (core.monitor.identify.accumulate); reported with honest sigmas and resolved flags (core.monitor.identify.estimate, core.monitor.report.cycle_report).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numba
import numpy as np
from frictionwatch.core.model.dynamics import node_torque_harmonics
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.engine_model import EngineModel, as_model
from frictionwatch.core.model.indicated import peak_pressure
from frictionwatch.core.monitor.balance.harmonic_balance import harmonic_balance, operating_point
from frictionwatch.core.monitor.balance.mean_balance import (
    MeanBalance,
    cycle_energy,
    energy_weights,
    grid_geometry,
    shaft_load,
    transient_balance,
)
from frictionwatch.core.monitor.checks.check import Check, CheckInput
from frictionwatch.core.monitor.checks.condition import ConditionCheck
from frictionwatch.core.monitor.checks.ring_pressure import ThrowMotion
from frictionwatch.core.monitor.checks.sensor_health import SensorHealthCheck, SensorHealthState, corrected_inputs
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from frictionwatch.core.monitor.identify.identification import identify_cycle
from frictionwatch.core.monitor.identify.noise_model import (
    ResidualStats,
    free_end_whitened,
    half_order_rows,
    no_free_end_rows,
)
from frictionwatch.core.monitor.identify.parameters import parameter_layout, prior_normal
from frictionwatch.core.monitor.report.cycle_report import StageReport, build_result, trig_tables
from frictionwatch.core.monitor.report.results import ChainSample, CycleResult
from frictionwatch.core.monitor.state import MonitorConfig, MonitorState, PreviousCycle
from frictionwatch.core.monitor.teeth.flywheel import ToothLearner
from frictionwatch.core.monitor.teeth.pattern_spread import pattern_spread
from frictionwatch.core.monitor.teeth.tooth_fit import fit_cycle_teeth, fit_second_wheel, free_end_input
from frictionwatch.core.types import Cycle

__all__ = ["CHECKS", "CycleRejected", "MonitorConfig", "MonitorState", "default_max_order", "initial_state",
           "nonpositive_flags", "process_cycle"]

FOUR_PI = 4.0 * np.pi


class CycleRejected(ValueError):
    """The cycle cannot be analysed honestly. ``reason`` is a short tag the pipeline counts; str() explains."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


_DEFAULT_CONFIG = MonitorConfig()  # frozen: one instance serves every call without a config
# the per-cycle checks in the order they run (core.monitor.checks.check): a new check is one class, one line here
# and the MonitorState field that carries its state (its name)
CHECKS: tuple[Check, ...] = (SensorHealthCheck(), ConditionCheck())


def default_max_order(spec: EngineSpec) -> float:
    """Half the per-revolution tooth count over 5 (enough edges per harmonic), capped at order 12."""
    teeth = spec.sensors.wheel_teeth - spec.sensors.wheel_missing
    return float(min(12.0, np.floor(teeth / 5.0 * 2.0) / 2.0))


def initial_state(engine: EngineModel | EngineSpec, config: MonitorConfig | None = None,
                  tooth_correction: np.ndarray | None = None) -> MonitorState:
    """A fresh state: no accumulated cycles, parameters at the prior (params = 1).

    engine : the model the monitor identifies (its loss-term library, and its coefficients as the prior a0 unless
    ``config.prior_coefficients`` says otherwise), or a spec (its default Rezeka-Henein model). An added term needs
    a non-zero coefficient: a_kl = a0_kl * scale, so a zero a0 keeps that term out.
    """
    cfg = config or MonitorConfig()
    model = as_model(engine)
    spec = model.spec
    prior = model.coefficients if cfg.prior_coefficients is None else cfg.prior_coefficients
    layout = parameter_layout(spec, cfg.scheme, prior, model.terms)
    m = round(2 * (cfg.max_order or default_max_order(spec)))
    if m < 1 or 2 * m >= cfg.time_samples:
        raise ValueError(f"max_order gives {m} harmonics; need 1 <= M < time_samples/2 = {cfg.time_samples // 2}")
    if tooth_correction is not None and np.shape(tooth_correction) != (spec.sensors.wheel_teeth,):
        raise ValueError(f"tooth_correction must have one angle per wheel position ({spec.sensors.wheel_teeth})")
    n_nuis = 2 * (m // 2) if cfg.tooth_nuisance else 0
    p = layout.n_params + n_nuis
    rows = 2 * m + 1 + (2 * half_order_rows(m, cfg.second_wheel_max_order).size if cfg.second_wheel else 0)
    lower = np.concatenate([np.zeros(layout.n_params), np.full(n_nuis, -np.inf)])
    lower.flags.writeable = False
    correction = (np.zeros(spec.sensors.wheel_teeth) if tooth_correction is None
                  else np.asarray(tooth_correction, dtype=np.float64).copy())
    return MonitorState(layout=layout, n_harmonics=m, n_nuisance=n_nuis, accumulator=Accumulator.empty(p, rows),
                        stats=ResidualStats.empty(m), params=np.concatenate([np.ones(layout.n_params),
                                                                             np.zeros(n_nuis)]),
                        op=None, relative_motion=None, static=None, teeth=ToothLearner(correction, 0),
                        balance_mean=float("nan"), indicated_mean=np.full(spec.n_cyl, np.nan), cycles=0,
                        prior=prior_normal(spec, layout, n_nuis, cfg.parameter_sigma, cfg.tooth_error_deg,
                                           cfg.sibling_spread),
                        lower=lower, report_tables=trig_tables(m, cfg.time_samples))


def process_cycle(engine: EngineModel | EngineSpec, state: MonitorState, cycle: Cycle,
                  config: MonitorConfig | None = None, checks: tuple[Check, ...] = CHECKS
                  ) -> tuple[MonitorState, CycleResult]:
    """Analyse one cycle of ``engine`` (the model ``state`` was made for, or its spec: the loss terms travel in the
    state). Raises ``CycleRejected`` (state unchanged) when the cycle cannot be used. ``checks``: the per-cycle
    checks, in order, each carrying its state in the ``MonitorState`` field of its name."""
    cfg = config or _DEFAULT_CONFIG
    spec = engine.spec if isinstance(engine, EngineModel) else engine
    pressure, flags = checked_pressure(spec, cycle)
    m = state.n_harmonics
    # the fit's settings, the same for both wheels: nuisance drift, band, drift term, the tooth learner's
    fit_settings = (cfg.drift_nuisance, round(2 * cfg.fit_order) if cfg.fit_order else m, cfg.fit_drift,
                    cfg.tooth_learning)
    try:
        fly, teeth, theta_start, patterns = fit_cycle_teeth(
            cycle, spec.sensors.wheel_teeth, m, state.n_nuisance, state.teeth, state.tooth_patterns, *fit_settings)
    except ValueError as exc:
        raise CycleRejected("bad_teeth", str(exc)) from exc
    free_end, wheel2, wheel2_flag = fit_second_wheel(  # the free end's own speed and tooth spacing (none: nothing)
        cycle, state.wheel2, m, state.n_nuisance, fit_settings)
    omega = fly.omega_mean
    load, load_from_power = shaft_load(cycle.load_torque, cycle.load_power, omega, cfg.calibration.generator_efficiency)
    if not math.isfinite(load):
        flags.append("no_load_measurement")
    op = operating_point(spec, state.op, omega, load, m, cfg.rebuild_tolerance, cfg.variable_inertia, state.layout,
                         cfg.load_ripple)
    if op is not state.op and state.op is not None:
        flags.append("operating_point_changed")

    # sensor corrections in use (TDC as each cylinder's kinematic phase, gain, pegging) before the balance and IMEP
    sensor = state.sensor if state.sensor is not None else SensorHealthState.empty(spec.n_cyl)
    raw_pressure, (pressure, op_used) = pressure, (corrected_inputs(sensor, pressure, op) if cfg.sensor_health
                                                   else (pressure, op))
    free_in = free_end_input(spec, op_used, free_end) if cfg.second_wheel else None
    bal = harmonic_balance(op_used, state.params, state.n_nuisance, state.relative_motion, state.static, cycle.grid,
                           pressure, fly, theta_start, cfg.passes, cfg.time_samples, free_in)
    exc, rows, rel, static = bal.excitation, bal.rows, bal.relative_motion, bal.static
    p_rel, p_gnd = bal.power_relative, bal.power_ground
    # relative dampers (damper, shaft, coupling) dissipate mean power that a balance against the load behind the
    # coupling would book as friction (physics.md §12.4); the load's own ripple work (ground damping) belongs to
    # the load: the measured torque is a time mean, the work it absorbs is that plus <T_L~ omega_L~>
    coupling_loss = p_rel / omega
    # the load under the halves of the balance's triangle (the readings' own spans: a step late in a cycle enters
    # the window as it entered the shaft, design note 76); not given: the cycle's mean
    early, late = cycle.load_early, cycle.load_late
    if not (math.isfinite(early) and math.isfinite(late)):
        early = late = load
    if math.isfinite(load):
        load, early, late = load + p_gnd / omega, early + p_gnd / omega, late + p_gnd / omega
    t_i = float(exc.indicated_mean.sum())
    prev = state.previous_of(int(cycle.tooth_ticks[0]))
    weights = state.energy_weights if state.energy_weights is not None and state.energy_weights.fits(cycle) \
        else energy_weights(spec, cycle.tooth_angle)
    geometry = (state.grid_geometry if state.grid_geometry is not None and state.grid_geometry.fits(cycle.grid)
                else grid_geometry(spec, cycle.grid))
    energy = cycle_energy(cycle, weights)
    balance, kinetic, accel, t_window, imep_c, tdc_sens = transient_balance(
        spec, cycle, pressure, exc.indicated_mean, energy, prev, load, coupling_loss, geometry, early)
    # the peak pressure of the pressure as it came (before the sensor corrections), beside the balance's indicated
    # works: both are core.model.indicated's, so a cycle enters that file once
    pmax, pmax_angle = peak_pressure(cycle.grid, raw_pressure, spec.firing_angles)
    mean = MeanBalance(indicated=t_i, load=load, coupling_loss=coupling_loss, friction=balance, kinetic=kinetic,
                       imep_centred=imep_c, acceleration=accel, indicated_window=t_window,
                       tdc_sensitivity=tdc_sens, load_from_power=load_from_power)
    if prev is None:
        flags.append("no_previous_cycle")  # IMEP over the assembled cycle's window, no mean balance

    # cycle-to-cycle speed change: a random walk of the mean speed, its step variance tracks the within-cycle drift
    step = omega - state.prev_omega if math.isfinite(state.prev_omega) else 0.0
    drift_var = step**2 if state.cycles <= 1 else state.drift_var + max(1.0 - cfg.noise_memory, 1.0 / state.cycles) * (
        step**2 - state.drift_var)
    prior = state.prior
    if prior.key != (cfg.parameter_sigma, cfg.tooth_error_deg, cfg.sibling_spread):  # another config than the state's
        prior = prior_normal(spec, state.layout, state.n_nuisance, cfg.parameter_sigma, cfg.tooth_error_deg,
                             cfg.sibling_spread)
        state = replace(state, prior=prior)
    tables = state.report_tables
    if tables.shape != (m, cfg.time_samples):
        tables = trig_tables(m, cfg.time_samples)
    free_rows = None
    if cfg.second_wheel:  # the joint fit: the free end's rows (zero rows for a cycle without them)
        if bal.free_rows is not None and free_end is not None:
            drift2 = None if free_end.drift_harmonics is None else free_end.harmonics_at(0.0, free_end.drift_harmonics)
            stats2, *free_rows = free_end_whitened(
                wheel2.stats, *bal.free_rows, state.params, free_end.harmonics,
                (free_end.omega_mean, FOUR_PI / free_end.omega_mean, free_end.residual_rms, free_end.n_edges),
                (drift2, drift_var), (cfg.noise_memory, cfg.model_rel_error), cfg.second_wheel_max_order)
            wheel2 = replace(wheel2, stats=stats2)
        else:
            free_rows = no_free_end_rows(m, state.params.shape[0], cfg.second_wheel_max_order)
    ident = identify_cycle(cfg, spec, state, fly, rows, exc, pmax, mean, drift_var, free_rows,
                           op_used.modes if cfg.free_response_carry > 0.0 else None)
    # the checks in order, each seeing the identification the one before left (sigmas inflated by the sensors'
    # uncertainty, the accumulator discounted after a change) and filling its fields of the result
    node = op_used.cylinders.node
    motion = (ThrowMotion(static[node], rel[node], float(theta_start))  # each cylinder's throw against the wheel
              if static.shape[0] == op_used.cylinders.n_nodes and rel.shape[0] == static.shape[0] else None)
    inp = CheckInput(spec, cfg, cycle.grid, raw_pressure, pressure, op_used, bal, state.params, prior.info, pmax,
                     rows.cylinder_rows[:, :state.layout.n_params], op is not state.op and state.op is not None, ident,
                     motion)
    checked, report = {}, {}
    for check in checks:
        step = check.update(getattr(state, check.name), inp)
        checked[check.name] = step.state
        flags += step.flags
        report.update(step.report)
        if step.ident is not inp.ident:  # (a check that leaves it as it was costs no new input: ~14 fields)
            inp = replace(inp, ident=step.ident)
    ident = inp.ident

    # the stage results not in build_result go in with the rest: one CycleResult made, not one and a replace
    report.update(free_end=free_end, chain=None if free_end is None or not cfg.drive_train_inputs else ChainSample(
        node_torque_harmonics(op_used.shaft, op_used.receptance, bal.node_speed),
        0.5j * fly.omega_mean * np.arange(1, m + 1) * fly.harmonics,
        fly.pattern_harmonics[:, :state.n_nuisance].copy()))
    if cfg.nuisance_spread:  # the tooth pattern's remaining uncertainty in the residual (the discrepancy's null)
        # the statistical covariance (data and priors), not the systematic part: that is made from the accumulated
        # persistent residual itself, so a missing effect at an integer order would widen its own sigma there
        p_f, n_nuis = state.layout.n_params, state.n_nuisance
        report["residual_pattern_sigma"] = pattern_spread(
            rows.design[:, p_f:p_f + n_nuis], ident.smoothed.cov_statistical[p_f:p_f + n_nuis, p_f:p_f + n_nuis])
    result = build_result(spec, cycle, fly, exc, rows, state.layout, ident, mean, pmax, pmax_angle, tables,
                          StageReport(flags, cfg.r_squared_floor, () if wheel2_flag is None else (wheel2_flag,), report))
    new_state = MonitorState(
        layout=state.layout, n_harmonics=m, n_nuisance=state.n_nuisance, accumulator=ident.accumulator,
        stats=ident.stats, params=ident.smoothed.params, op=op, relative_motion=rel, static=static, teeth=teeth,
        balance_mean=ident.balance_mean, indicated_mean=ident.indicated_mean, cycles=state.cycles + 1,
        prior=state.prior, lower=state.lower, report_tables=tables, prev_omega=omega, drift_var=drift_var,
        tooth_patterns=patterns, **checked,
        previous=PreviousCycle(int(cycle.tooth_ticks[0]), int(cycle.tooth_ticks[-1]), pressure.copy(), energy,
                               load, t_i, coupling_loss, late),  # a copy: a live source may reuse the cycle's buffer
        grid_geometry=geometry, energy_weights=weights, wheel2=wheel2, motion=motion,
    )  # every field (dataclasses.replace costs twice as much per cycle)
    return new_state, result


# ---- steps -------------------------------------------------------------------------------------------------


def checked_pressure(spec: EngineSpec, cycle: Cycle) -> tuple[np.ndarray, list[str]]:
    """The cycle's pressure (z, n) [Pa] with short gaps of invalid samples repaired (flagged), and its flags;
    CycleRejected when the pressure or its grid cannot be used."""
    p = np.asarray(cycle.pressure, dtype=np.float64)
    n = cycle.grid.shape[0]
    if p.shape != (spec.n_cyl, n):
        raise CycleRejected("bad_pressure", f"pressure has shape {p.shape}; expected ({spec.n_cyl}, {n})")
    span = (cycle.grid[-1] - cycle.grid[0]) * n / max(n - 1, 1)
    if n < 64 or abs(span - FOUR_PI) > 1e-6 * FOUR_PI:
        raise CycleRejected("bad_grid", f"the crank-angle grid must cover 720 deg uniformly ({n} points)")
    flags = list(cycle.flags)
    finite, low = pressure_scan(p if p.flags.c_contiguous else np.ascontiguousarray(p))
    if finite:  # the common case: one pass over the pressure answers both questions (nonpositive_flags' below)
        return p, flags + [f for f in _nonpositive_names(low) if f not in flags] if low.any() else flags
    bad = ~np.isfinite(p)
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
    flags += [f for f in nonpositive_flags(p) if f not in flags]
    return p, flags


@numba.njit(cache=True, fastmath={"reassoc", "nsz"})
def pressure_scan(p):
    """(whether every sample of p (z, n) is finite, (z,) whether a channel reads 0 or less) in one pass over p:
    ``pressure_scan_reference``'s answers, checked_pressure's two questions (its numpy calls took ~15 us a genset-v20
    cycle, (20, 720), ~9 us a k9k one; this ~3 and ~1). A sample's v * 0 is 0 when it is finite and NaN when it
    is NaN or inf, so a row's sum of them says whether the row is finite; the flags allow the sums to be reordered
    (vectorised) but not NaN or inf to be assumed away. A min per sample was a serial chain (~20 us)."""
    z, n = p.shape
    finite = True
    low = np.zeros(z, dtype=np.bool_)
    for k in range(z):
        row = p[k]
        zero = 0.0
        nonpositive = 0
        for i in range(n):
            v = row[i]
            zero += v * 0.0
            nonpositive += v <= 0.0
        row_finite = zero == 0.0
        finite &= row_finite
        low[k] = row_finite and nonpositive > 0
    return finite, low


def pressure_scan_reference(p: np.ndarray) -> tuple[bool, np.ndarray]:
    """``pressure_scan`` by numpy: all finite, and each row's minimum <= 0 (a row with NaN: False, as np.min's NaN;
    the mask is read only when all are finite)."""
    with np.errstate(invalid="ignore"):
        return bool(np.isfinite(p).all()), np.isfinite(p).all(axis=1) & (p.min(axis=1) <= 0.0)


def nonpositive_flags(pressure: np.ndarray) -> list[str]:
    """``sensor_pressure_nonpositive_cyl<k>`` for each channel of ``pressure`` (z, n) [Pa] that reads 0 or less: an
    absolute pressure never does, so the channel is clipped at its converter's floor or pegged wrong (maruti at
    part load with a -1.5 bar offset: the intake and early compression read 0), and its gas torque and work are
    wrong there; the sensor_ prefix withholds the figures it touches (figure_status). Read on the reading as it
    came (core.monitor.pipeline: before a view's pegging correction lifts a clipped floor off zero) and as the
    monitor gets it."""
    p = np.asarray(pressure)
    if p.ndim != 2 or p.size == 0:  # not a channel per row: checked_pressure refuses the cycle
        return []
    low = p.min(axis=1) <= 0.0
    return _nonpositive_names(low) if low.any() else []


def _nonpositive_names(low: np.ndarray) -> list[str]:
    return [f"sensor_pressure_nonpositive_cyl{k + 1}" for k in np.flatnonzero(low)]
