"""The drive train identified from both wheels (core.monitor.calibration.drive_train) on plants that differ from the
monitor's chain: does the identified scale hold the truth within 2 sigma, and does the fit say when it cannot?

    nice .venv/bin/python -m bench.drive_train_identification [--cycles 150] [--seeds 7,11] [--load 0.75]
        [--cases stiffness_0.85,...]

genset-v20 with its free-end wheel (bench/genset-v20-two-wheels.toml) at one load, every default effect on (tooth
errors on both wheels). Cases (the monitor always runs the engine file's chain):
  stiffness_0.85 / stiffness_1.15   chain_mismatch: every section's stiffness x 0.85 / 1.15 (representable)
  damping_2                         chain_mismatch: every section's damping x 2 (representable)
  none                              the plant is the engine file's chain (scales 1 expected)
  one_section_0.6                   the plant's crank section throw5-throw6 alone x 0.6 (not representable)
  damper_ring_1.5                   the plant's damper-ring inertia x 1.5 (not representable)
Per case and seed: the identified scales with sigma, their distance from the truth in sigmas (representable cases),
chi2/dof and the poor-fit verdict, the modes, and the free end's and flywheel's residual per half order in % of the
harmonic before (the engine file's chain) and after (the identified one). Written to
bench/results/drive_train_identification.json. Nothing in the identification was tuned on these runs: its poor-fit line is
the chi2 distribution's 0.1 % tail and its noise model the monitor's own (tooth_error_deg, model_rel_error).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.calibration.drive_train import identify_iteratively
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import EnginePipeline

from bench.accuracy_v20_wheels import TWO_WHEELS

OUT_JSON = Path(__file__).parent / "results" / "drive_train_identification.json"
CASES = {  # name: (chain_mismatch values or None, plant spec change or None, true scales or None)
    "none": (None, None, (1.0, 1.0)),
    "stiffness_0.85": ({"stiffness_scale": 0.85, "damping_scale": 1.0}, None, (0.85, 1.0)),
    "stiffness_1.15": ({"stiffness_scale": 1.15, "damping_scale": 1.0}, None, (1.15, 1.0)),
    "damping_2": ({"stiffness_scale": 1.0, "damping_scale": 2.0}, None, (1.0, 2.0)),
    "one_section_0.6": (None, ("stiffness", "throw5", 0.6), None),
    "damper_ring_1.5": (None, ("node_inertia", "damper_ring", 1.5), None),
}


def plant_spec(spec, change):
    """``spec`` with one section's stiffness (named by its front node) or one node's inertia scaled."""
    if change is None:
        return spec
    field, node, factor = change
    values = getattr(spec, field).astype(np.float64).copy()
    values[spec.node_names.index(node)] *= factor
    return replace(spec, **{field: values})


def run_case(spec, name: str, cycles: int, seed: int, load: float) -> dict:
    mismatch, change, truth = CASES[name]
    effects = {"chain_mismatch": mismatch} if mismatch else {}
    sim = simulate(plant_spec(spec, change), 1500.0, load, cycles, seed, second_wheel=True, effects=effects)
    cfg = MonitorConfig(drive_train_inputs=True)

    def results_for(chain):
        pipe = EnginePipeline(chain, sim.info, cfg)
        return [r for rec in sim.records for r in pipe.feed(rec)] + pipe.flush()

    t0 = time.process_time()
    fit = identify_iteratively(spec, results_for, cfg.tooth_error_deg, cfg.model_rel_error, skip=30)
    out = {"case": name, "seed": seed, "cycles_simulated": cycles, "cpu_s": time.process_time() - t0, **fit.to_dict()}
    if truth is not None:
        out["truth"] = {"stiffness_scale": truth[0], "damping_scale": truth[1]}
        out["stiffness_off_sigmas"] = (fit.stiffness_scale - truth[0]) / fit.stiffness_sigma
        out["damping_off_sigmas"] = (fit.damping_scale - truth[1]) / fit.damping_sigma
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=150)
    ap.add_argument("--seeds", default="7,11")
    ap.add_argument("--load", type=float, default=0.75)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--json", default=str(OUT_JSON))
    args = ap.parse_args()
    spec = load_engine(TWO_WHEELS)
    runs = []
    for seed in (int(s) for s in args.seeds.split(",")):
        for name in args.cases.split(","):
            r = run_case(spec, name, args.cycles, seed, args.load)
            runs.append(r)
            off = (f"; truth within {abs(r['stiffness_off_sigmas']):.1f} / {abs(r['damping_off_sigmas']):.1f} sigma"
                   if "truth" in r else "")
            print(f"seed {seed} {name}: {r['words']}{off}")
            print("   free end % before:", np.round(r["residual_pct_before"]["free_end"], 2).tolist())
            print("   free end % after: ", np.round(r["residual_pct_after"]["free_end"], 2).tolist())
            print("   flywheel % before:", np.round(r["residual_pct_before"]["flywheel"], 2).tolist())
            print("   flywheel % after: ", np.round(r["residual_pct_after"]["flywheel"], 2).tolist())
            print("   free end sigmas before / after:", np.round(r["residual_sigmas_before"]["free_end"], 1).tolist(),
                  np.round(r["residual_sigmas_after"]["free_end"], 1).tolist())
    Path(args.json).write_text(json.dumps({"command": "python -m bench.drive_train_identification " + " ".join(
        f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items() if k != "json"), "runs": runs}, indent=1) + "\n")


if __name__ == "__main__":
    main()
