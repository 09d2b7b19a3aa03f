"""Tune MonitorConfig.r_squared_floor apart from the logs that validate it (issue 26 item 5).

    python -m bench.calibrate_r_squared_floor [--cycles 24] [--write]

A cycle whose speed fit explains less of the in-band speed ripple than the floor is flagged ``speed_fit_poor``. The
floor must sit below every healthy simulated cycle's R^2 and above a real run whose speed ripple the model does not
explain. Tuning logs: every preset but k9k-4cyl (held out: tests/core/test_monitor.py validates its R^2) at one
operating point, seeds 51 and 52, which no test simulates; the real TU/e group14 E0NOLOAD1 (no load, its ripple
near the encoder's noise), which no test reads. The floor is the geometric mean of E0NOLOAD1's largest per-cycle
R^2 and the smallest healthy simulated one, to one significant figure; if the two overlap it refuses to write.
Validated by tests/realdata/test_tue_regimes.py (E0NOLOAD2-4 flagged on every cycle) and the other group14 files.

With --write the number and its provenance go into core/monitor/tuned.json (core.tuned).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import sys
import tempfile
from datetime import date
from pathlib import Path

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.core.tuned import MONITOR_RECORD, Case, Tuned, write_tuned
from frictionwatch.service.cli import main as cli
from frictionwatch.service.pipeline import analyze_log, run

POINTS = {"maruti-3cyl": (2500.0, 0.6), "deutz-1cyl": (2200.0, 0.7), "genset-v20": (1500.0, 0.6),
          "polito-4cyl": (1600.0, 0.6), "auth-4cyl": (1200.0, 0.6), "tue-4gb10": (1500.0, 0.5)}
SEEDS = (51, 52)
REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "tue-4gb10-si-encoder-pressure"
REAL_LOG = "E0NOLOAD1"
REAL_IMPORT = ["--engine", "tue-4gb10", "--tdc-deg", "244.5", "--gain-bar-per-v", "12.4"]  # tests/realdata's
TUNED_BY = "python -m bench.calibrate_r_squared_floor --write"


def healthy_r_squared(engine: str, rpm: float, load: float, seed: int, cycles: int) -> np.ndarray:
    """Per-cycle R^2 of a healthy simulated log through the one pipeline (cycles it could not fit: left out)."""
    spec = load_engine(engine)
    sim = simulate(spec, rpm, load, cycles, seed)
    r2 = [o.result.r_squared for o in run(spec, sim.info, sim.records, MonitorConfig()) if o.ok]
    return np.array([x for x in r2 if math.isfinite(x)])


def real_r_squared(folder: Path) -> np.ndarray:
    """Per-cycle R^2 of the real log, imported as tests/realdata imports it."""
    src = REAL / f"group14_{REAL_LOG}.txt.gz"
    if not src.is_file():
        raise SystemExit(f"the real log {src} is absent: the floor cannot be tuned without it")
    log = folder / f"{REAL_LOG}.mcap"
    with contextlib.redirect_stdout(io.StringIO()):
        if cli(["import-daq", str(src), *REAL_IMPORT, "-o", str(log)]) != 0:
            raise SystemExit(f"import-daq of {src.name} failed")
    r2 = [r.r_squared for r in analyze_log(log).results]
    return np.array([x for x in r2 if math.isfinite(x)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=24)
    ap.add_argument("--write", action="store_true", help="write it and its provenance into core/monitor/tuned.json")
    args = ap.parse_args()
    cases, lowest = [], []
    for engine, (rpm, load) in POINTS.items():
        for seed in SEEDS:
            r2 = healthy_r_squared(engine, rpm, load, seed, args.cycles)
            cases.append(Case(engine, rpm, load, seed))
            lowest.append((float(r2.min()), str(cases[-1])))
            print(f"{cases[-1]}: {r2.size} cycles, R^2 {r2.min():.3f}-{r2.max():.3f}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        real = real_r_squared(Path(tmp))
    print(f"log {REAL_LOG}: {real.size} cycles, R^2 {real.min():.3f}-{real.max():.3f}", flush=True)
    low, where = min(lowest)
    high = float(real.max())
    if high >= low:
        print(f"the real run's largest R^2 {high:.3f} is not below the healthy smallest {low:.3f} ({where}): "
              "no floor separates them; nothing written", file=sys.stderr)
        raise SystemExit(1)
    floor = float(f"{math.sqrt(high * low):.1g}")
    if not high < floor < low:
        floor = math.sqrt(high * low)  # one figure would cross a side: keep the geometric mean whole
    print(f"floor {floor:g}: between {REAL_LOG}'s largest {high:.3f} and the healthy smallest {low:.3f} ({where})")
    if args.write:
        on = tuple(str(c) for c in cases) + (f"log {REAL_LOG}",)
        figure = (f"the geometric mean of {REAL_LOG}'s largest per-cycle R^2 {high:.4f} ({real.size} cycles) and the "
                  f"smallest healthy simulated one {low:.4f} ({where}; {args.cycles} cycles each), to one figure")
        write_tuned({"R_SQUARED_FLOOR": Tuned(floor, f"{TUNED_BY} --cycles {args.cycles}", on, figure,
                                              date.today().isoformat())}, MONITOR_RECORD)
        print(f"wrote {MONITOR_RECORD}")


if __name__ == "__main__":
    main()
