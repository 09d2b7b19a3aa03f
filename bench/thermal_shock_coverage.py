"""A thermal-shocked pressure sensor the monitor is not told of (the thermal_shock effect, design note 156), analysed
through the product's path (simulate -> analyze_records, the records of the log analyze reads) as
bench/calibration_coverage.py does, with the bare preset (uncalibrated: its sigmas assume a 3 % gain per channel)
and with a commissioned calibration (bench/mismatch_coverage.py's: gain 0.5 % per channel, 1 % common; what
commissioning concludes of a shocked sensor, whose compression stroke is right): per engine, two loads,
two sizes, one cylinder or all: the engine friction's error in sigmas, its error in %, the IMEP the monitor reads
against the truth's (the shocked cylinder's, or the engine mean with all or none), the sensor-health estimates of cylinder 1
(gain, pegging, TDC against the siblings), and every flag any cycle raised beyond those of the healthy run.

    python -m bench.thermal_shock_coverage [--cycles 60] [--engines k9k-4cyl,maruti-3cyl,genset-v20] [--json F]

Not a test: minutes per engine (genset-v20 simulates ~4 cycles per second of CPU).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import as_model
from frictionwatch.core.monitor.pipeline import STAGES
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import EnginePipeline

from bench.mismatch_coverage import COMMISSIONED

POINTS = {  # two loads each, as bench/calibration_coverage.py
    "k9k-4cyl": [(1700.0, 1.0), (2500.0, 0.5)],
    "maruti-3cyl": [(3000.0, 0.8), (2000.0, 0.4)],
    "deutz-1cyl": [(1500.0, 0.8), (1200.0, 0.4)],
    "genset-v20": [(1500.0, 0.75), (1500.0, 0.45)],
}
# 0.2 and 0.5 bar peak at full load (the literature's 0.1-0.5 bar), the default 4 ms, in cylinder 1 or in all
EFFECTS = [None] + [f"thermal_shock:cylinder={c},pa={pa:g}" for c in (1, 0) for pa in (2e4, 5e4)]


# the watches judge every WINDOW cycles here, not the product's 100: a 60-cycle log gets one verdict (at cycle 50;
# the flags hold after it). Their statistics are then over 50 cycles: a larger standard error, fewer flags
WINDOW = 50
STAGES_HERE = tuple(dataclasses.replace(s, window=WINDOW) if hasattr(s, "window") else s for s in STAGES)


def _analyse(model, sim) -> tuple[list, object]:
    """(the results, the thermal-shock watch's newest window reading or None)."""
    pipe = EnginePipeline(model, sim.info, None, stages=STAGES_HERE)
    results = [o.result for r in [*sim.records, None] for o in pipe.outcomes(r) if o.ok]
    return results, pipe.cycles.stages["thermal_shock_watch"].last


def run_case(engine: str, rpm: float, load: float, effect: str | None, cycles: int, seed: int) -> list[dict]:
    """The case's log analysed bare and commissioned: a row each."""
    spec = load_engine(engine)
    sim = simulate(spec, rpm, load, cycles, seed, effects=[parse_effect(effect)] if effect else [])
    rows = []
    for name, cal in (("bare", None), ("commissioned", COMMISSIONED)):
        model = spec if cal is None else dataclasses.replace(as_model(spec), calibration=cal)
        results, bend = _analyse(model, sim)
        rows.append({"calibration": name, **_row(sim.truth, results, engine, rpm, load, effect),
                     "bend_dev": None if bend is None else bend.dev.tolist(),
                     "bend_limit": None if bend is None else bend.limit.tolist()})
    return rows


def _row(truth: dict, results: list, engine: str, rpm: float, load: float, effect: str | None) -> dict:
    last = results[-1]
    est = last.smoothed
    flags = sorted({f for r in results for f in r.flags})
    t, s, true = est.total_friction_torque, est.total_friction_torque_sigma, truth["friction_torque_mean_nm"]
    imep_true = np.array([c["imep_bar"] for c in truth["cylinders"]])
    imep_read = np.nanmean(np.array([r.imep for r in results[len(results) // 4:]]), axis=0) / 1e5
    cyl = parse_effect(effect)["cylinder"] if effect else 0  # 0: every cylinder (or healthy: the engine mean)
    sh = last.sensor_health
    return {"engine": engine, "rpm": rpm, "load": load, "effect": effect or "healthy", "truth_nm": true,
            "friction_nm": t, "sigma_nm": s, "error_pct": 100.0 * (t - true) / true,
            "z": (t - true) / s if s > 0 else float("nan"),
            "imep_error_pct": float(100.0 * (np.mean(imep_read) / np.mean(imep_true) - 1.0) if cyl == 0
                                    else 100.0 * (imep_read[cyl - 1] / imep_true[cyl - 1] - 1.0)),
            "imep_true_bar": imep_true.tolist(), "imep_read_bar": imep_read.tolist(),
            "gain_cyl1": None if sh is None else float(sh.pressure_gain[0]),
            "offset_cyl1_pa": None if sh is None else float(sh.pressure_offset[0]),
            "tdc_cyl1_deg": None if sh is None else float(np.degrees(sh.tdc_offset[0])),
            "flags": flags, "shock_flags": [f for f in flags if f.startswith("sensor_thermal_shock")],
            "cycles_flagged": sum(1 for r in results if r.flags), "cycles": len(results)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=60)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--engines", default="k9k-4cyl,maruti-3cyl,genset-v20")
    ap.add_argument("--effects", default="", help="';'-separated effects instead of the table's (healthy: none)")
    ap.add_argument("--json", type=Path, help="write the rows here")
    a = ap.parse_args(argv)
    effects = EFFECTS if not a.effects else [None if e == "none" else e for e in a.effects.split(";")]
    rows = []
    print(f"{'engine':<12} {'rpm':>6} {'load':>5} {'effect':<36} {'cal':<5} {'truth':>7} {'read':>7} {'±1σ':>6} "
          f"{'err %':>7} {'z':>6} {'imep %':>7}  flags beyond the healthy run's")
    for engine in a.engines.split(","):
        for rpm, load in POINTS[engine]:
            healthy_flags: dict[str, set[str]] = {}
            for eff in effects:
                t0 = time.perf_counter()
                for r in run_case(engine, rpm, load, eff, a.cycles, a.seed):
                    if eff is None:
                        healthy_flags[r["calibration"]] = set(r["flags"])
                    r["new_flags"] = sorted(set(r["flags"]) - healthy_flags.get(r["calibration"], set()))
                    rows.append(r)
                    print(f"{engine:<12} {rpm:6.0f} {load:5.2f} {r['effect']:<36} {r['calibration'][:5]:<5} "
                          f"{r['truth_nm']:7.2f} {r['friction_nm']:7.2f} {r['sigma_nm']:6.2f} {r['error_pct']:+7.1f} "
                          f"{r['z']:+6.2f} {r['imep_error_pct']:+7.2f}  {','.join(r['new_flags']) or '-'} "
                          f"({time.perf_counter() - t0:.0f} s)", flush=True)
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
