"""Plant simulator: time-domain torsional engine model with per-cylinder thermodynamics, friction, sensors, effects.

    simulate(spec_or_model, rpm, load, cycles, seed, effects=None, without=(), cov_imep=0.02, load_steps=None,
             progress=None) -> SimResult
    sim = start_simulation(spec_or_model, rpm, load, cycles, seed, ...)     # the same run, streamed:
    sim.info                                          # AcquisitionInfo, known before the run
    for chunk in sim.chunks(chunk_cycles=8):          # SimChunk: records, truth entries of the cycles it completes
        ...
    sim.truth                                         # the per-run truth (without "cycles") once chunks() ended
    ck = sim.checkpoint()                             # between two chunks: the run's state as plain (picklable) data
    sim2 = start_simulation(<same arguments>); sim2.resume(ck); sim2.chunks()   # the rest of it, to the bit

``simulate`` collects ``start_simulation(...).chunks()``: there is one simulator, and a run's memory is one chunk's
worth whatever the number of cycles when its chunks are consumed as they come. The records and truth do not depend
on the chunk size (tests/core/test_simulate_chunks.py).

This is deliberately a different route from the monitor's harmonic balance (design.md §4): fixed steps in time on
the full nonlinear chain (core.plant.plant; the cylinders evaluated once a step and the shaft line by RK4,
core.plant.plant_advance), with J(theta) per throw, pressure and friction at each throw's own angle.

Conventions (truth and records):
- Crank angle: cylinder 1's convention, 0 = its firing TDC. The truth uses the TRUE flywheel-node angle theta_F;
  the wheel's *stated* ``first_tooth_deg`` (AcquisitionInfo) is the nominal one, so with ``tdc_offset`` (cylinder 0)
  the wheel frame is theta_W = theta_F + offset.
- Cycle n is the interval where theta_F is in [4 pi n, 4 pi (n+1)), n = 0 the first output cycle. Times are seconds
  in the tick time base: tick 0 (t = 0) is the start of the records, one crank revolution (theta_F = -2 pi) before
  cycle 0, so a monitor can find the gap and the cam before cycle 0.
- Mean torques are cycle work / 4 pi [N m] (work at each node's own speed); mep = work / displacement.
  Friction = mechanical friction only (six Rezeka-Henein terms + extra_friction); the power dissipated in relative
  dampers (torsional damper, shaft damping, coupling) is reported as ``damper_coupling_loss_nm``, not as friction.
- Signs: gas torque positive driving; friction and load torques are magnitudes opposing rotation (physics.md §0).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from frictionwatch.core.model.effects import ChainSetup, CylinderSetup, Effect, LoadSetup, SensorSetup
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.thermo import charge_pressures, cylinder_model
from frictionwatch.core.plant.operating_point import (
    engine_brake_torque,
    fuel_for_load,
    idle_fuel,
    leak_area_for_loss,
    sized_transfers,
    variability_sensitivity,
)
from frictionwatch.core.plant.plant_setup import build_plant, chain_matrices, static_twist
from frictionwatch.core.plant.sim_run import PlantRun
from frictionwatch.core.plant.sim_stream import SETTLE_A_CYCLES, SETTLE_B_CYCLES, Simulation, StageSwitches
from frictionwatch.core.plant.sim_truth import GRID_MAX_CYL
from frictionwatch.core.types import AcquisitionInfo, StreamRecord
from scipy.linalg import eigh

STEP_DEG = 0.5  # integrator step at the mean speed (capped by the fastest mode: 0.5 / w_max); design note 123
MIN_SLOPE_FRACTION = 0.25  # dyno law slope never below 25 % of the full-load brake torque / omega^s


def cylinders_at(spec: EngineSpec, effects: Sequence[Effect], coefficients: np.ndarray, term_names: tuple[str, ...],
                 cycle: int) -> CylinderSetup:
    """The cylinders' set-up in output cycle ``cycle``: every effect whose onset is at or before it, in order, each
    at its ramp's fraction there (``Effect.ramp_fraction``)."""
    cyl = CylinderSetup.nominal(spec, coefficients, term_names)
    for e in effects:
        if e.onset_cycle <= cycle:
            cyl = e.scaled(e.ramp_fraction(cycle)).apply_cylinders(cyl)
    return cyl


def sensors_at(effects: Sequence[Effect], n_cyl: int, cycle: int) -> SensorSetup:
    """The acquisition's set-up in output cycle ``cycle``: every effect whose onset is at or before it, in order
    (a sensor fault with ``from_cycle``: the wheel frame, a channel's gain or pegging from that cycle on)."""
    sensors = SensorSetup.ideal(n_cyl)
    for e in effects:
        if e.onset_cycle <= cycle:
            sensors = e.apply_sensors(sensors)
    return sensors


MAX_RAMP_STEPS = 200  # a ramp switches the plant at most this many times (each switch sizes a leak orifice)


def stage_onsets(effects: Sequence[Effect], cycles: int) -> list[int]:
    """Output cycles where the cylinders' set-up changes: 0, each onset, and along each ramp every cycle (a ramp
    longer than MAX_RAMP_STEPS cycles: every ceil(ramp / MAX_RAMP_STEPS) cycles, a staircase of equal steps under
    the line), before ``cycles``."""
    out = {0}
    for e in effects:
        out.add(e.onset_cycle)
        if e.ramp_cycles > 1:
            step = -(-e.ramp_cycles // MAX_RAMP_STEPS)
            out.update(range(e.onset_cycle, e.onset_cycle + e.ramp_cycles, step))
    return sorted(c for c in out if c < cycles)


@dataclass
class SimResult:
    """records: stream records in arrival order; info: what the acquisition states; truth: JSON-able ground truth;
    diagnostics: numpy arrays for tests (true flywheel speed and friction on the 1-deg grid, tooth errors, ...)."""

    records: list[StreamRecord]
    info: AcquisitionInfo
    truth: dict
    diagnostics: dict = field(default_factory=dict)


def _validate(spec: EngineSpec, rpm: float, load: float, cycles: int, cov_imep: float, load_steps) -> list:
    if not (np.isfinite(rpm) and 0.2 * spec.speed_range_rpm[0] <= rpm <= 1.2 * spec.speed_range_rpm[1]):
        raise ValueError(f"rpm = {rpm!r} is outside {spec.name}'s usable range {spec.speed_range_rpm}")
    if not (np.isfinite(load) and 0.0 <= load <= 1.2):
        raise ValueError(f"load = {load!r} must be a fraction of full load in 0..1.2")
    if not (isinstance(cycles, (int, np.integer)) and 1 <= cycles <= 1_000_000):
        raise ValueError(f"cycles = {cycles!r} must be an integer >= 1")
    if not (np.isfinite(cov_imep) and 0.0 <= cov_imep <= 0.2):
        raise ValueError(f"cov_imep = {cov_imep!r} must be in 0..0.2 (a fraction)")
    steps = sorted(tuple(float(x) for x in st) for st in (load_steps or []))
    for st in steps:
        t, f = st[:2]
        if len(st) not in (2, 3) or not (np.isfinite(t) and t >= 0 and np.isfinite(f) and 0.0 <= f <= 1.2):
            raise ValueError(f"load step {st} needs time >= 0 s and a fraction in 0..1.2 (and an rpm: a speed step)")
        if len(st) == 3 and not (0.2 * spec.speed_range_rpm[0] <= st[2] <= 1.2 * spec.speed_range_rpm[1]):
            raise ValueError(f"speed step to {st[2]!r} rpm is outside {spec.name}'s usable range {spec.speed_range_rpm}")
        if len(st) == 3 and spec.load.kind == "grid":
            raise ValueError(f"{spec.name}'s load is the grid: its speed is the grid's, a speed step is not possible")
    return steps


def _as_model(engine: EngineSpec | EngineModel, effects, without, coefficients) -> EngineModel:
    if isinstance(engine, EngineModel):
        if effects or without or coefficients is not None:
            raise ValueError("an EngineModel carries its own effects and coefficients; give effects, without and "
                             "coefficients only with an EngineSpec")
        return engine
    if coefficients is not None:
        z = engine.n_cyl
        coef = np.array(coefficients, dtype=float)
        if coef.shape != (z, 6) or not np.all(np.isfinite(coef)) or np.any(coef < 0):
            raise ValueError(f"coefficients must be a ({z}, 6) array of finite values >= 0")
        coefficients = coef
    return EngineModel.from_spec(engine, effects=effects, without=without, coefficients=coefficients)


def simulate(engine: EngineSpec | EngineModel, rpm: float, load: float, cycles: int, seed: int,
             progress: Callable[[float], None] | None = None, friction_grid: bool | None = None,
             **options) -> SimResult:
    """Simulate ``cycles`` steady engine cycles (after an unlogged settling period) and return records and truth:
    ``start_simulation`` (the same parameters; ``options`` its keyword ones: effects, without, cov_imep,
    load_steps, coefficients, fuel_spread, second_wheel) with its chunks collected; ``friction_grid`` True also
    evaluates the 1-deg friction grid of an engine of more than 4 cylinders (``PlantRun.record_friction_grid``)."""
    sim = start_simulation(engine, rpm, load, cycles, seed, **options)
    if friction_grid is not None:
        sim.run.record_friction_grid(friction_grid)
    chunks = list(sim.chunks(progress=progress))
    records = [r for c in chunks for r in c.records]
    truth = {**sim.truth, "cycles": [e for c in chunks for e in c.cycles]}
    diag: dict = {"t_out0": sim.run.t_out0, "tooth_errors_deg": sim.run.tooth_err.copy()}
    for key in chunks[0].diagnostics:
        diag[key] = np.concatenate([c.diagnostics[key] for c in chunks if key in c.diagnostics])
    return SimResult(records=records, info=sim.info, truth=truth, diagnostics=diag)


def start_simulation(engine: EngineSpec | EngineModel, rpm: float, load: float, cycles: int, seed: int,
                     effects: Mapping[str, dict] | Sequence[Effect] | None = None, without: set[str] | tuple = (),
                     cov_imep: float = 0.02, load_steps: list[tuple[float, float]] | None = None,
                     coefficients: np.ndarray | None = None, fuel_spread: float = 0.01,
                     second_wheel: bool = False) -> Simulation:
    """Set up a run of ``cycles`` steady engine cycles (after an unlogged settling period); ``chunks()`` runs it.

    Parameters
    ----------
    engine : an EngineModel (its effects applied, its coefficients the truth) or an EngineSpec, wrapped as
    ``EngineModel.from_spec(spec, effects, without, coefficients)``. rpm : requested mean speed [rpm];
    load : fraction of full load (0 = zero brake torque); cycles : output cycles; seed : all randomness (combustion,
    spread, wheel errors, noise) derives from it. effects : Effect instances or {name: {param: value}} turned on
    (core.model.effects); without : default-on effects turned off (both only with an EngineSpec).
    cov_imep : cycle-to-cycle COV of IMEP (fraction, default 2 %). load_steps : [(time_s, fraction)], time in the
    tick time base; (time_s, fraction, rpm) is a speed step as well (a dyno only: the dyno holds the new speed for a
    few cycles, core.plant.sim_stream.SPEED_HOLD_CYCLES; effects sized at the operating point stay sized at the
    requested one, so a friction law differs from the model's at the new speed as a real one would). coefficients : (z, 6) raw a_kl per cylinder (default: the preset's a_l for every cylinder).
    fuel_spread : rms of the fixed cylinder-to-cylinder fuel spread (fraction). second_wheel : log the engine
    file's second wheel too (``[sensors.second_wheel]``, at its node of the shaft; its own tooth errors of the
    ``tooth_spacing_error`` effect's size and edge jitter from a ninth generator, so every other stream is unchanged). The ``coast_down`` effect turns the
    ignition off and disconnects the load at its ``time_s`` (after any load steps). The total friction on the 1-deg
    grid (the diagnostics' "friction_grid_nm") is evaluated only where the truth keeps it (engines of at most
    sim_truth.GRID_MAX_CYL cylinders; elsewhere NaN: it was a third of the cylinders' evaluations for a diagnostic
    only tests read, design note 129); ``run.record_friction_grid(True)`` before ``chunks()`` asks for it.
    """
    model = _as_model(engine, effects, without, coefficients)
    spec = model.spec
    steps = _validate(spec, rpm, load, cycles, cov_imep, load_steps)
    z = spec.n_cyl
    if second_wheel and spec.sensors.second_wheel is None:
        raise ValueError(f"{spec.name} has no second wheel: add [sensors.second_wheel] (teeth, missing, "
                         "first_tooth_deg, node) to its engine file")
    seeds = np.random.SeedSequence(seed)
    rngs = [np.random.default_rng(s) for s in seeds.spawn(8)]
    if second_wheel:  # child 8 of the same sequence: the first eight are those of a run without it
        rngs.append(np.random.default_rng(seeds.spawn(1)[0]))
    omega = rpm * np.pi / 30.0
    tmodel = cylinder_model(spec)

    lib = model.terms  # the plant evaluates the model's loss-term library, added terms included, and the terms of
    for e in model.effects:  # the model mismatches the monitor is not told about (Effect.plant_terms)
        for t in e.plant_terms(spec):
            lib = lib if t.name in lib.names else lib + t
    coef_nominal = np.zeros((z, len(lib)))
    coef_nominal[:, :len(model.terms)] = model.coefficients
    chain, load_fx = ChainSetup(), LoadSetup()
    for e in model.effects:  # each hook returns a new set-up: instances compose in the order listed
        chain, load_fx = e.apply_chain(chain), e.apply_load(load_fx)
    # a change mid-run: the cylinders' and the sensors' set-up from each effect's onset cycle on (stage 0 from the
    # start)
    onsets = stage_onsets(model.effects, cycles)
    stages = [cylinders_at(spec, model.effects, coef_nominal, lib.names, c) for c in onsets]
    sensor_stages = [sensors_at(model.effects, z, c) for c in onsets]
    sensors = sensor_stages[0]
    cyl = stages[0]
    coef, phase, misfire = cyl.coefficients, cyl.firing_angles, cyl.misfire
    spread = np.ones(z)
    if z > 1 and fuel_spread > 0:
        spread = 1.0 + fuel_spread * rngs[1].standard_normal(z)
        spread = np.clip(spread / spread.mean(), 0.5, 1.5)

    # ---- operating point estimate (quasi-static), leak sizing, extra friction reference ----
    leak, extra, no_extra = np.zeros(z), np.zeros((z, 4)), np.zeros(z)
    m0 = idle_fuel(spec, tmodel, omega, spread, coef, leak, misfire, no_extra, lib)
    fuel_op = fuel_for_load(m0, spec, load) * spread
    coefs = [sized_transfers(spec, tmodel, omega, fuel_op, load, s.coefficients, s.transfers, lib) for s in stages]
    leaks = [np.array([leak_area_for_loss(spec, tmodel, omega, fuel_op[k], load, s.mass_loss[k]) for k in range(z)])
             for s in stages]
    coef, leak = coefs[0].copy(), leaks[0]  # the plant's array is switched in place at an onset
    with_extra = np.nonzero(np.any(cyl.extra_friction != 0.0, axis=1))[0]
    if with_extra.size:  # T_ref = the cylinder's mean friction at the operating point, without the extra term
        _, means0 = engine_brake_torque(spec, tmodel, omega, fuel_for_load(m0, spec, load) * spread, load, coef,
                                        leak, misfire, no_extra, lib)
        for k in with_extra:
            ref = means0[k].friction_nm
            mean_frac, amp_frac, order, phase_rad = cyl.extra_friction[k]
            extra[k] = [ref * mean_frac, ref * amp_frac, order, phase_rad]
    m0 = idle_fuel(spec, tmodel, omega, spread, coef, leak, misfire, extra[:, 0], lib)

    def point(frac: float, w: float = omega) -> tuple[float, float, list]:
        fuel = fuel_for_load(m0, spec, frac)
        tb, means = engine_brake_torque(spec, tmodel, w, fuel * spread, frac, coef, leak, misfire, extra[:, 0], lib)
        return fuel, tb, means

    fuel0, brake0, means = point(load)
    brake_full = point(1.0)[1] if spec.load.kind == "speed_power" else brake0

    # ---- cycle-to-cycle variability, calibrated to the requested COV of IMEP ----
    imep0, d_q, d_soc = variability_sensitivity(spec, tmodel, omega, fuel0, load)
    sig_soc = sig_beta = sig_q = 0.0
    if cov_imep > 0:
        target = cov_imep * abs(imep0)
        sig_soc = 0.5 * cov_imep / 0.02
        if (d_soc * sig_soc) ** 2 > 0.5 * target**2:
            sig_soc = np.sqrt(0.5) * target / abs(d_soc)
        sig_beta = 0.1 * cov_imep / 0.02
        sig_q = np.sqrt(max(target**2 - (d_soc * sig_soc) ** 2, 0.0)) / max(d_q, 1e-9)

    # ---- plant ----
    plant = build_plant(spec, flexible=chain.flexible, variable=chain.variable_inertia, coef=coef, phase=phase, extra=extra,
                        library=lib, stiffness_scale=chain.stiffness_scale, damping_scale=chain.damping_scale,
                        flywheel_inertia_scale=chain.flywheel_inertia_scale)
    grid_k = spec.load.grid_stiffness_nm_per_rad if spec.load.kind == "grid" else 0.0
    mm, kk, _ = chain_matrices(plant, grid_k)
    w_max = np.sqrt(max(eigh(kk, mm, eigvals_only=True).max(), 0.0))
    h = min(np.radians(STEP_DEG) / omega, 0.5 / w_max if w_max > 0 else np.inf)
    node_torque = np.zeros(plant.n)
    for k in range(z):
        node_torque[plant.cyl_node[k]] += means[k].indicated_nm - means[k].friction_nm - extra[k, 0]
    node_torque[plant.load] -= node_torque.sum()

    run = PlantRun(spec, plant, tmodel, h=h, omega=omega, sensors=sensors, rngs=rngs, second_wheel=second_wheel)
    run.record_friction_grid(z <= GRID_MAX_CYL)
    theta_start = -4.0 * np.pi * (SETTLE_A_CYCLES + SETTLE_B_CYCLES) - 2.0 * np.pi
    theta_switch = -4.0 * np.pi * SETTLE_B_CYCLES
    run.set_state(theta_start + static_twist(plant, node_torque), omega)
    run.set_leak(leak)
    run.set_operating(fuel0, *charge_pressures(spec, load))
    # misfires from the start act in the settling cycles too (the load law settles on the misfiring engine); those
    # that start mid-run are drawn from their onset cycle on
    misfire_from = np.full(z, np.iinfo(np.int64).min // 2, dtype=np.int64)
    for c, before, after in zip(onsets[1:], stages, stages[1:]):
        misfire_from[after.misfire != before.misfire] = c
    run.set_perturbations(spread, stages[-1].misfire, sig_q, sig_soc, sig_beta, theta_start, theta_switch, cycles,
                          misfire_from)
    ripple = load_fx.amplitude_nm if load_fx.amplitude_nm > 0 else load_fx.fraction * abs(brake0)
    run.set_ripple(ripple, load_fx.order, load_fx.phase_rad)
    run.settle_law(brake0, brake_full, MIN_SLOPE_FRACTION)
    operating = {
        "omega_requested_rad_s": omega, "fuel_kg_per_cycle": fuel0, "idle_fuel_kg": m0,
        "fuel_spread": spread.tolist(), "leak_area_m2": leak.tolist(), "brake_torque_estimate_nm": brake0,
        "load_law": {}, "load_steps": [], "cov_imep": cov_imep,
        "variability": {"sigma_fuel": sig_q, "sigma_soc_deg": sig_soc, "sigma_premixed": sig_beta},
        "step_s": h, "settle_cycles": SETTLE_A_CYCLES + SETTLE_B_CYCLES, "load_ripple_nm": ripple,
    }
    if np.isfinite(load_fx.coast_down_s):  # ignition off and the load disconnected: a step to "coasting" (None)
        steps = sorted([*steps, (float(load_fx.coast_down_s), None)], key=lambda st: st[0])
    return Simulation(model, run, cycles=cycles, steps=steps, point=point, theta_start=theta_start,
                      operating=operating, request={"rpm": rpm, "load": load, "seed": seed}, sensors=sensors,
                      rngs=rngs, stages=StageSwitches(onsets, coefs, leaks, [s.firing_angles for s in stages],
                                                      sensor_stages))
