"""Full genset-v20 accuracy run: 3 loads x 2000 cycles through simulate -> the one pipeline (assembler, monitor, watches).

    .venv/bin/python -m bench.accuracy_v20 [--cycles 2000] [--loads 0.5 0.75 1.0] [--seed 1]

Too slow for the test suite (about 80 s of simulation per load); tests/core/test_monitor_accuracy.py runs one load
for 1000 cycles. Prints, per load, the total FMEP error and sigma and, per cylinder, the error, sigma, data weight and
whether the data resolve it (design.md §5 target: within 10 % after at most 2000 cycles); writes
bench/results/accuracy_v20.json. The cycles are assembled by the pipeline's assembler (service.pipeline.assembled_cycles) and
run through core.monitor.pipeline.CyclePipeline, the path analyze and serve run: ``pipeline_ms_per_cycle`` is the
monitor with the running calibration watches (before the one pipeline: ``monitor_ms_per_cycle``, the monitor alone).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.pipeline import CyclePipeline
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles

OUT = Path(__file__).parent / "results" / "accuracy_v20.json"


def run_load(load: float, cycles: int, seed: int) -> dict:
    spec = load_engine("genset-v20")
    t0 = time.perf_counter()
    sim = simulate(spec, 1500.0, load, cycles, seed=seed)
    t_sim = time.perf_counter() - t0
    cycs, skipped = assembled_cycles(spec, sim.info, sim.records)
    pipe = CyclePipeline(spec)
    t0 = time.perf_counter()
    outcomes = [pipe.process(c) for c in cycs]
    t_mon = time.perf_counter() - t0
    res = [o.result for o in outcomes if o.ok][-1]
    skipped.update(o.skipped for o in outcomes if not o.ok)
    est = res.smoothed
    truth = np.array([c["friction_torque_mean_nm"] for c in sim.truth["cylinders"]])
    total_truth = sim.truth["fmep_bar"] * 1e5
    posterior_rel = est.friction_torque_mean / truth - 1.0
    return {
        "load": load, "cycles": len(cycs), "skipped": dict(skipped),
        "simulate_s": round(t_sim, 1), "pipeline_ms_per_cycle": round(1e3 * t_mon / max(len(cycs), 1), 2),
        "total_fmep_error_pct": round(100 * (est.total_fmep / total_truth - 1.0), 3),
        "total_fmep_sigma_pct": round(100 * est.total_fmep_sigma / total_truth, 3),
        "coupling_loss_nm": [round(res.coupling_loss, 3), round(sim.truth["damper_coupling_loss_nm"], 3)],
        "cylinders": [{"cylinder": k + 1, "truth_nm": round(float(truth[k]), 3),
                       "error_pct": None if not est.resolved[k] else round(100 * float(posterior_rel[k]), 2),
                       "sigma_pct": round(100 * float(est.friction_torque_mean_sigma[k] / truth[k]), 2),
                       "data_weight": round(float(est.data_gain[k]), 2), "resolved": bool(est.resolved[k])}
                      for k in range(spec.n_cyl)],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=2000)
    ap.add_argument("--loads", type=float, nargs="+", default=[0.5, 0.75, 1.0])
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    out = []
    for load in args.loads:
        r = run_load(load, args.cycles, args.seed)
        out.append(r)
        res = [c for c in r["cylinders"] if c["resolved"]]
        worst = max((abs(c["error_pct"]) for c in res), default=float("nan"))
        print(f"load {load:.2f}: total FMEP {r['total_fmep_error_pct']:+.2f} % (sigma {r['total_fmep_sigma_pct']:.2f} %),"
              f" {len(res)}/20 cylinders resolved, worst resolved error {worst:.1f} %, "
              f"pipeline {r['pipeline_ms_per_cycle']} ms/cycle, simulate {r['simulate_s']} s", flush=True)
        for c in r["cylinders"]:
            err = "unresolved" if c["error_pct"] is None else f"{c['error_pct']:+6.2f} %"
            print(f"   cyl {c['cylinder']:2d}: {err:>11s}  sigma {c['sigma_pct']:5.2f} %  data weight {c['data_weight']:.2f}")
    OUT.write_text(json.dumps(out, indent=1))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
