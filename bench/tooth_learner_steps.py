"""The tooth learner's correction against the wheel's true tooth errors, cycle by cycle, on a log (design note 60).

    python -m bench.tooth_learner_steps --engine deutz-1cyl --point 1 --seed 2 [--one-point] [--speed-step F]

The log: bench.discrepancy_cases' two-point log at the engine's matrix point ``point`` (its blocks and speed
steps), or with --one-point that point alone (160 cycles either way). Only the monitor's tooth step runs
(core.monitor.teeth.tooth_fit.fit_cycle_teeth with MonitorConfig's learner settings; --speed-step overrides
tooth_speed_step, ``inf`` turns the gate off). Printed per cycle: the window's mean rpm, its change from the cycle
before, whether the learner folded it in, the fit's residual rms, and the rms of (learnt - true) above the fitted
band (wheel orders above n_harmonics // 2 per revolution, where the learner is the only estimate) [urad].
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.monitor.monitor import initial_state
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.monitor.teeth.tooth_fit import fit_cycle_teeth
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles

from bench.discrepancy_cases import ENGINES, TWO_POINT_CYCLES, two_point_steps


def out_of_band(spec, x: np.ndarray, orders: int) -> np.ndarray:
    """x (present teeth,) [rad] with wheel orders 0..``orders`` removed (least squares on the present teeth)."""
    ang = np.radians(spec.sensors.first_tooth_deg + np.arange(x.size) * 360.0 / spec.sensors.wheel_teeth)
    basis = np.column_stack([np.ones(x.size)] + [f(k * ang) for k in range(1, orders + 1) for f in (np.cos, np.sin)])
    return x - basis @ np.linalg.lstsq(basis, x, rcond=None)[0]


def trace(engine: str, point: int, seed: int, two_points: bool, cfg: MonitorConfig) -> list[dict]:
    spec = load_engine(engine)
    rpm, load = ENGINES[engine]["points"][point]
    steps = two_point_steps(engine, point) if two_points else None
    sim = simulate(spec, rpm, load, TWO_POINT_CYCLES, seed, load_steps=steps)
    model = EngineModel.from_spec(spec)
    cycles = assembled_cycles(model, sim.info, sim.records)[0]
    truth = np.radians(sim.diagnostics["tooth_errors_deg"])
    state = initial_state(model, cfg)
    m, teeth, cache = state.n_harmonics, state.teeth, state.tooth_patterns
    rows, last = [], None
    for cycle in cycles:
        count = teeth.count
        fly, teeth, _, cache = fit_cycle_teeth(cycle, spec.sensors.wheel_teeth, m, state.n_nuisance, teeth, cache,
                                               cfg.drift_nuisance, m, cfg.fit_drift, cfg.tooth_learning)
        err = out_of_band(spec, teeth.correction[:truth.size] - truth, m // 2)
        rpm_c = fly.omega_mean * 30.0 / np.pi
        rows.append({"cycle": cycle.index, "rpm": rpm_c, "change": np.nan if last is None else rpm_c / last - 1.0,
                     "learnt": teeth.count > count, "residual_urad": 1e6 * fly.residual_rms,
                     "error_urad": 1e6 * float(np.sqrt(np.mean(err**2)))})
        last = rpm_c
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engine", choices=sorted(ENGINES), default="deutz-1cyl")
    ap.add_argument("--point", type=int, choices=(0, 1), default=1)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--one-point", action="store_true")
    ap.add_argument("--speed-step", type=float, help="MonitorConfig.tooth_speed_step (inf: no gate)")
    args = ap.parse_args()
    cfg = MonitorConfig() if args.speed_step is None else dataclasses.replace(MonitorConfig(),
                                                                              tooth_speed_step=args.speed_step)
    rows = trace(args.engine, args.point, args.seed, not args.one_point, cfg)
    for r in rows:
        print(f"{r['cycle']:4d} {r['rpm']:8.1f} rpm {100 * r['change']:+7.2f} % {'learnt ' if r['learnt'] else 'skipped'}"
              f" residual {r['residual_urad']:7.1f} error {r['error_urad']:6.2f} urad")
    err = np.array([r["error_urad"] for r in rows])
    print(f"learnt from {sum(r['learnt'] for r in rows)} of {len(rows)} cycles; error above the band (urad): "
          f"last {err[-1]:.2f}, median {np.median(err):.2f}, max after cycle 10 {err[10:].max():.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
