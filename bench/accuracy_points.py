"""Accuracy figures of the monitor on the simulator at the points the accuracy tests use (before/after a change).

    python -m bench.accuracy_points [--v20] > figures.json

Per engine and point: total FMEP error and its sigma (relative), per-cylinder mean friction errors (%), and for the
single-cylinder deutz the mean NRMSE of the instantaneous friction torque. Same simulations as
tests/core/test_monitor_accuracy.py (seed 1, default effects), through the same one pipeline (service.pipeline.run:
assembler, monitor, running calibration watches); figures, not pass/fail.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import run

POINTS = {
    "k9k-4cyl": ([(1100.0, 0.28), (1400.0, 0.5), (1700.0, 0.69)], 200),
    "maruti-3cyl": ([(2000.0, 0.5), (3000.0, 0.8), (5400.0, 0.8)], 200),
    "deutz-1cyl": ([(1570.0, 0.0), (2000.0, 0.5), (2600.0, 0.8)], 150),
}
WARMUP = 50


def point(name: str, rpm: float, load: float, cycles: int) -> dict:
    spec = load_engine(name)
    sim = simulate(spec, rpm, load, cycles, seed=1)
    outcomes = list(run(spec, sim.info, sim.records))
    results = [o.result for o in outcomes if o.ok]
    est = results[-1].smoothed
    truth_fmep = sim.truth["fmep_bar"] * 1e5
    truth_cyl = np.array([c["friction_torque_mean_nm"] for c in sim.truth["cylinders"]])
    out = {"rpm": rpm, "load": load, "cycles": len(results), "lost": len(outcomes) - len(results),
           "total_err_pct": round(100 * (est.total_fmep / truth_fmep - 1), 2),
           "total_sigma_pct": round(100 * est.total_fmep_sigma / truth_fmep, 2),
           "cyl_err_pct": [round(float(v), 2) for v in 100 * (est.friction_torque_mean / truth_cyl - 1)],
           "cyl_sigma_pct": [round(float(v), 2) for v in 100 * est.friction_torque_mean_sigma / truth_cyl],
           "resolved": int(np.sum(est.resolved))}
    if spec.n_cyl == 1:
        nrmse = [np.sqrt(np.mean((r.friction_torque - np.asarray(sim.truth["cycles"][r.index]["friction_torque_grid_nm"]))
                                 ** 2) / np.mean(np.asarray(sim.truth["cycles"][r.index]["friction_torque_grid_nm"]) ** 2))
                 for r in results[WARMUP:]]
        out["nrmse_pct"] = round(100 * float(np.mean(nrmse)), 2)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--v20", action="store_true", help="also genset-v20, 1500 rpm, full load, 1000 cycles (slow)")
    args = ap.parse_args()
    points = dict(POINTS)
    if args.v20:
        points["genset-v20"] = ([(1500.0, 1.0)], 1000)
    figures = {name: [point(name, rpm, load, n) for rpm, load in pts] for name, (pts, n) in points.items()}
    print(json.dumps(figures, indent=1))


if __name__ == "__main__":
    main()
