"""False sensor flags on healthy engines: how often the running watches (the TDC watch,
core/monitor/calibration/tdc_watch.py, and the gain and pegging watch, gain_watch.py) flag a healthy engine run with
its bare preset (uncalibrated), on the product's path (simulator -> service.pipeline.EnginePipeline). Not run by the
test suite (issue 25's check: no sensor flag in >= 99 % of healthy cycles).

    python -m bench.sensor_flags                      # the table: 4 engines x 2 loads x 300 cycles, seed 7
    python -m bench.sensor_flags --cycles 150 --json out.json
    python -m bench.sensor_flags --faults             # detection: faulted channels, bare and after commissioning

Printed per case: the fraction of analysed cycles with any ``sensor_`` flag, with a TDC-watch flag, with a
gain-watch flag, and the gain watch's closest call: the largest |gain - 1| / limit and |offset| / limit over its
windows and channels (1 would flag). deutz-1cyl has one cylinder: no sibling to compare with, so the gain watch does
not run there (and the TDC watch judges its wheel only).

``--faults``: on k9k, maruti and the genset (cylinder 2, 200 cycles, seed 8), bare: gain 0.94 / 1.06, pegging
+0.3 bar; commissioned on a healthy 120-cycle log at the first point (seed 9), then a log at the second point with
gain 0.96 / 1.04 (the drift after commissioning). Printed: the first cycle with a gain-watch flag, the flags at the
end, and what the watch's last window read on the faulted channel against its limit (gain_watch.gain_limits).
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from frictionwatch.core.model.calibration import Calibration  # noqa: E402
from frictionwatch.core.model.engine import load_engine  # noqa: E402
from frictionwatch.core.model.engine_model import EngineModel, load_model  # noqa: E402
from frictionwatch.core.monitor.calibration.gain_watch import gain_limits  # noqa: E402
from frictionwatch.core.plant.simulate import simulate  # noqa: E402
from frictionwatch.service.cli import main as cli  # noqa: E402
from frictionwatch.service.pipeline import EnginePipeline, analyze_log  # noqa: E402

# two loads each, the points of bench/tdc_from_pressure.py (none is a point tests/core/test_gain_watch.py uses)
POINTS = {
    "k9k-4cyl": ((1700.0, 1.0), (2500.0, 0.5)),
    "maruti-3cyl": ((3000.0, 0.8), (2000.0, 0.4)),
    "deutz-1cyl": ((2600.0, 1.0), (1800.0, 0.5)),
    "genset-v20": ((1500.0, 1.0), (1500.0, 0.5)),
}


def run_case(engine: str, rpm: float, load: float, cycles: int, seed: int) -> dict:
    spec = load_engine(engine)
    t0 = time.perf_counter()
    sim = simulate(spec, rpm, load, cycles, seed)
    t_sim = time.perf_counter() - t0
    model = EngineModel.from_spec(spec)
    pipe = EnginePipeline(model, sim.info)
    results, windows, seen = [], [], None
    t0 = time.perf_counter()
    for record in list(sim.records) + [None]:
        out = pipe.feed(record) if record is not None else pipe.flush()
        for r in out:
            results.append(r)
            stats = pipe.gain_watch.last
            if stats is not None and stats is not seen:
                seen = stats
                lim_g, lim_o = gain_limits(model.calibration, stats)
                windows.append((float(np.max(np.abs(stats.mean[0]) / lim_g)),
                                float(np.max(np.abs(stats.mean[1]) / lim_o))))
    t_an = time.perf_counter() - t0
    n = len(results)
    tdc = sum(any(f.startswith("sensor_tdc") for f in r.flags) for r in results)
    gain = sum(any(f.startswith("sensor_pressure") for f in r.flags) for r in results)
    anyf = sum(any(f.startswith("sensor_") for f in r.flags) for r in results)
    kinds = sorted({f for r in results for f in r.flags if f.startswith("sensor_")})
    return {"engine": engine, "rpm": rpm, "load": load, "seed": seed, "cycles": n,
            "any_sensor_fraction": anyf / n if n else None, "tdc_fraction": tdc / n if n else None,
            "gain_fraction": gain / n if n else None, "flags": kinds, "gain_windows": len(windows),
            "gain_ratio_max": max((w[0] for w in windows), default=None),
            "offset_ratio_max": max((w[1] for w in windows), default=None),
            "simulate_s": round(t_sim, 1), "analyze_s": round(t_an, 1)}


BARE_FAULTS = ("pressure_gain:cylinder=2,gain=0.94", "pressure_gain:cylinder=2,gain=1.06",
               "pressure_offset:cylinder=2,pa=30000")
DRIFTS = ("pressure_gain:cylinder=2,gain=0.96", "pressure_gain:cylinder=2,gain=1.04")


def _sim(path: Path, engine: str, rpm: float, load: float, cycles: int, seed: int, effect: str | None) -> None:
    args = ["simulate", "--engine", engine, "--rpm", str(rpm), "--load", str(load), "--cycles", str(cycles),
            "--seed", str(seed), "-o", str(path)]
    if cli(args + (["--effect", effect] if effect else [])) != 0:
        raise SystemExit(f"simulate failed: {args}")


def _detection(log: Path, engine: str | None) -> dict:
    a = analyze_log(log, engine=engine)
    first = next((r.index for r in a.results if any(f.startswith("sensor_pressure") for f in r.flags)), None)
    s = a.gain_watch.last
    lim = None if s is None else gain_limits(load_model(engine).calibration if engine else Calibration(), s)
    return {"first_flag_cycle": first, "flags": sorted(f for f in a.results[-1].flags if f.startswith("sensor_")),
            "gain_cyl2": None if s is None else 1.0 + float(s.mean[0, 1]),
            "offset_cyl2_bar": None if s is None else float(s.mean[1, 1]) / 1e5,
            "gain_limit_cyl2": None if lim is None else float(lim[0][1]),
            "offset_limit_cyl2_bar": None if lim is None else float(lim[1][1]) / 1e5}


def faults() -> list[dict]:
    rows = []
    print(f"{'engine':<12} {'model':<13} {'rpm':>5} {'load':>4} {'effect':<38} {'first':>5} {'read / limit':>20}  flags at end")
    with tempfile.TemporaryDirectory() as tmp:
        for engine in ("k9k-4cyl", "maruti-3cyl", "genset-v20"):
            (rpm1, load1), (rpm2, load2) = POINTS[engine]
            cases = [("bare", rpm1, load1, e) for e in BARE_FAULTS]
            model = Path(tmp) / f"{engine}-model.toml"
            _sim(Path(tmp) / "comm.mcap", engine, rpm1, load1, 120, 9, None)
            if cli(["commission", str(Path(tmp) / "comm.mcap"), "-o", str(model), "--json"]) != 0:
                raise SystemExit("commission failed")
            cases += [("commissioned", rpm2, load2, e) for e in DRIFTS]
            for kind, rpm, load, effect in cases:
                log = Path(tmp) / "case.mcap"
                _sim(log, engine, rpm, load, 200, 8, effect)
                r = {"engine": engine, "model": kind, "rpm": rpm, "load": load, "effect": effect,
                     **_detection(log, str(model) if kind == "commissioned" else None)}
                rows.append(r)
                read = (f"{r['gain_cyl2'] - 1:+.2%} / {r['gain_limit_cyl2']:.2%}" if "gain" in effect else
                        f"{r['offset_cyl2_bar']:+.3f} / {r['offset_limit_cyl2_bar']:.3f} bar") \
                    if r["gain_cyl2"] is not None else "-"
                first = "-" if r["first_flag_cycle"] is None else str(r["first_flag_cycle"])
                print(f"{engine:<12} {kind:<13} {rpm:5.0f} {load:4.2f} {effect:<38} {first:>5} {read:>20}  "
                      f"{','.join(r['flags']) or '-'}", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=300)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--engine", choices=sorted(POINTS), action="append")
    ap.add_argument("--json", help="also write the rows to this file")
    ap.add_argument("--faults", action="store_true", help="the detection table instead (module doc)")
    args = ap.parse_args()
    if args.faults:
        rows = faults()
        if args.json:
            with open(args.json, "w", encoding="utf-8") as fh:
                json.dump(rows, fh, indent=1)
        return
    rows = []
    print(f"{'engine':<12} {'rpm':>5} {'load':>4} {'cycles':>6} {'any sensor_':>11} {'TDC watch':>9} "
          f"{'gain watch':>10} {'gain/lim':>8} {'offs/lim':>8}  flags")
    for engine in args.engine or list(POINTS):
        for rpm, load in POINTS[engine]:
            r = run_case(engine, rpm, load, args.cycles, args.seed)
            rows.append(r)
            g = "—" if r["gain_ratio_max"] is None else f"{r['gain_ratio_max']:.2f}"
            o = "—" if r["offset_ratio_max"] is None else f"{r['offset_ratio_max']:.2f}"
            print(f"{engine:<12} {rpm:5.0f} {load:4.2f} {r['cycles']:6d} {100 * r['any_sensor_fraction']:10.1f}% "
                  f"{100 * r['tdc_fraction']:8.1f}% {100 * r['gain_fraction']:9.1f}% {g:>8} {o:>8}  "
                  f"{','.join(r['flags']) or '-'}", flush=True)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
