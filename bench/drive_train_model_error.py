"""The drive train's model error per harmonic at both wheels: the monitor's speed equations at the true friction.

    nice .venv/bin/python -m bench.drive_train_model_error [--cycles 150] [--seed 7] [--load 0.75]
        [--without variable_inertia,...] [--damping-scale 1] [--stiffness-scale 1] [--node front_hub]

genset-v20 with its free-end wheel (bench/genset-v20-two-wheels.toml) at one load through the monitor with the
joint fit on; every cycle's flywheel and free-end speed equations (design, target = measured - modelled speed
harmonic) are kept as the balance forms them (core.monitor.monitor.harmonic_balance, wrapped here) and evaluated at
the truth (every friction scale 1, tooth nuisances 0). Per harmonic (engine order m/2), after ``--skip`` cycles:
the mean residual in % of the measured speed harmonic and in standard errors (its cycle-to-cycle scatter over
sqrt(n)), for the flywheel and the free end, and at the free end the predicted/measured magnitude ratio and the
phase difference [deg] (a timing or reference-angle error grows in phase with the order; a wrong natural frequency
moves magnitude and phase most near the mode).

Switches, to find what makes the error (the same engine for plant and monitor unless said):
  --without       plant effects off (comma list); variable_inertia off also turns it off in the monitor.
                  Default tooth_spacing_error: a wheel's in-band tooth errors sit at integer orders and the free end
                  carries no nuisance for them, so they would hide the model error there.
  --damping-scale every section's damping x this, plant and monitor (the damping model near the mode)
  --stiffness-scale  the plant's sections x this, the monitor not told (chain_mismatch: a mismatch case)
  --node          the second wheel's node (a name of the shaft's nodes), plant and monitor
  --teeth-errors  which wheel has tooth-spacing errors in the plant (both, flywheel, free_end: the other one's are
                  zeroed; with tooth_spacing_error in --without neither has any)
"""

from __future__ import annotations

import argparse
from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np
from frictionwatch.core.model.engine import EngineSpec, load_engine
from frictionwatch.core.monitor import monitor as mon
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.plant import sim_run
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import EnginePipeline

from bench.accuracy_v20_wheels import TWO_WHEELS


@dataclass(frozen=True)
class WheelError:
    """Per harmonic (M,): |mean residual| / |mean measured speed harmonic|, / its standard error; the mean
    predicted and measured speed harmonics [rad/s]."""

    rel: np.ndarray
    se: np.ndarray
    predicted: np.ndarray
    measured: np.ndarray


def wheel_error(design: np.ndarray, target: np.ndarray, measured: np.ndarray, n_params: int) -> WheelError:
    """design (n, M, P), target (n, M), measured (n, M) speed harmonics: the residual at theta = (1.., 0..)."""
    theta = np.zeros(design.shape[2])
    theta[:n_params] = 1.0
    resid = target - design @ theta
    mean = resid.mean(axis=0)
    meas = measured.mean(axis=0)
    se = np.sqrt((resid.real.var(axis=0) + resid.imag.var(axis=0)) / resid.shape[0])
    return WheelError(np.abs(mean) / np.abs(meas), np.abs(mean) / se, meas - mean, meas)


def run(spec: EngineSpec, cycles: int, seed: int, load: float, without: tuple[str, ...], stiffness_scale: float,
        damping_scale_plant: float = 1.0, skip: int = 30, config: MonitorConfig | None = None,
        teeth_errors: str = "both") -> tuple[WheelError, WheelError, dict]:
    """Simulate and monitor; (flywheel, free end) errors at the truth and the kept rows {"fly": (design, target,
    speed), "free": (...)} of the cycles after ``skip``."""
    kept: list = []
    balance = mon.harmonic_balance

    def keep(op, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, passes, samples, free_end=None):
        bal = balance(op, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, passes, samples, free_end)
        if bal.free_rows is not None:
            w = 0.5 * fly.omega_mean * np.arange(1, fly.harmonics.shape[0] + 1)
            kept.append((bal.rows.design.copy(), bal.rows.target.copy(), 1j * w * fly.harmonics,
                         bal.free_rows[0].copy(), bal.free_rows[1].copy(), 1j * w * free_end[1]))
        return bal

    effects = {}
    if stiffness_scale != 1.0 or damping_scale_plant != 1.0:
        effects["chain_mismatch"] = {"stiffness_scale": stiffness_scale, "damping_scale": damping_scale_plant}
    cfg = config or MonitorConfig(second_wheel=True, variable_inertia="variable_inertia" not in without)
    mon.harmonic_balance = keep
    try:
        with tooth_errors_on(teeth_errors):
            sim = simulate(spec, 1500.0, load, cycles, seed, second_wheel=True, effects=effects, without=set(without))
        pipe = EnginePipeline(spec, sim.info, cfg)
        for record in sim.records:
            pipe.feed(record)
        pipe.flush()
    finally:
        mon.harmonic_balance = balance
    rows = kept[skip:]
    if not rows:
        raise SystemExit(f"no cycle with both wheels after the first {skip}")
    p = pipe.state.layout.n_params
    fly = tuple(np.array([r[i] for r in rows]) for i in range(3))
    free = tuple(np.array([r[i] for r in rows]) for i in range(3, 6))
    return wheel_error(*fly, p), wheel_error(*free, p), {"fly": fly, "free": free, "n_params": p}


@contextmanager
def tooth_errors_on(which: str):
    """While open, the simulator draws tooth-spacing errors for ``which`` wheel only ("flywheel", "free_end"; "both":
    as it always does), the other's zeroed (a diagnostic plant: core.plant.sim_run draws them)."""
    draw = sim_run.tooth_errors

    def errors(sensors, *args, **kw):  # the flywheel's are drawn with the spec's sensors (the second wheel's: its
        err = draw(sensors, *args, **kw)  # own SensorParams, second_wheel None: core.plant.sensors)
        is_fly = sensors.second_wheel is not None
        return err if which == "both" or (which == "flywheel") == is_fly else np.zeros_like(err)

    sim_run.tooth_errors = errors
    try:
        yield
    finally:
        sim_run.tooth_errors = draw


def engine(damping_scale: float, node: str | None) -> EngineSpec:
    spec = load_engine(TWO_WHEELS)
    if damping_scale != 1.0:
        spec = replace(spec, damping=spec.damping * damping_scale)
    if node is not None:
        wheel = replace(spec.sensors.second_wheel, node=spec.node_names.index(node))
        spec = replace(spec, sensors=replace(spec.sensors, second_wheel=wheel))
    return spec


def print_table(fly: WheelError, free: WheelError) -> None:
    print("order  flywheel: %harm   SE | free end: %harm   SE  |pred|/|meas|  phase[deg]")
    for j in range(fly.rel.shape[0]):
        ratio = np.abs(free.predicted[j]) / np.abs(free.measured[j])
        phase = np.degrees(np.angle(free.predicted[j] / free.measured[j]))
        print(f"{(j + 1) / 2:5.1f}  {100 * fly.rel[j]:15.2f} {fly.se[j]:5.1f} | {100 * free.rel[j]:15.2f} "
              f"{free.se[j]:5.1f}  {ratio:12.3f}  {phase:9.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=150)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--load", type=float, default=0.75)
    ap.add_argument("--skip", type=int, default=30)
    ap.add_argument("--without", default="tooth_spacing_error")
    ap.add_argument("--damping-scale", type=float, default=1.0)
    ap.add_argument("--stiffness-scale", type=float, default=1.0)
    ap.add_argument("--node", default=None)
    ap.add_argument("--teeth-errors", choices=("both", "flywheel", "free_end"), default="both")
    args = ap.parse_args()
    without = tuple(w for w in args.without.split(",") if w)
    spec = engine(args.damping_scale, args.node)
    fly, free, kept = run(spec, args.cycles, args.seed, args.load, without, args.stiffness_scale, skip=args.skip,
                          teeth_errors=args.teeth_errors)
    print(f"{kept['fly'][0].shape[0]} cycles, seed {args.seed}, load {args.load}, without {without}, damping x "
          f"{args.damping_scale}, plant stiffness x {args.stiffness_scale}, node "
          f"{spec.node_names[spec.sensors.second_wheel.node]}, tooth errors on {args.teeth_errors}")
    print_table(fly, free)


if __name__ == "__main__":
    main()
