"""Drift after commissioning (issue 25 check: "TDC +0.5 deg or gain -4 % from cycle 300 of 900: flagged within 200
cycles on the right cylinder, the figure corrected or withheld"): an accuracy run, not a test.

    python -m bench.sensor_drift [--engine k9k-4cyl ...] [--cases tdc,gain,wheel]

Per engine: ``frictionwatch commission`` on a healthy log (seed 61, ``COMMISSION`` point, 300 cycles), then
``analyze`` (service.pipeline.analyze_log, the TDC and gain watches inside EnginePipeline) with the model written on
900-cycle logs of another seed (62) at another point (``RUN``) with the fault from output cycle 300 (the simulator's
``from_cycle``): a cylinder's TDC +0.5 deg (cylinder 2), the wheel's +0.5 deg, a gain of 0.96 on cylinder 2; and the
same log healthy (``--cylinder`` another than 2). Per case one row: the first cycle with any sensor flag and the first with the right one, the
flags in force at the end, whether cylinder 2's friction is withheld at the end (figure status) and which other
cylinders are, and any sensor flag before the onset. Prints a table and one JSON line per row.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
import time
from pathlib import Path

from frictionwatch.core.monitor.report.figure_status import friction_status
from frictionwatch.service.cli import main as cli
from frictionwatch.service.pipeline import analyze_log

COMMISSION = {"k9k-4cyl": (2200.0, 0.7), "maruti-3cyl": (2500.0, 0.6), "genset-v20": (1500.0, 0.75)}
RUN = {"k9k-4cyl": (2000.0, 0.8), "maruti-3cyl": (2800.0, 0.7), "genset-v20": (1500.0, 0.6)}
ONSET, CYCLES, CYLINDER = 300, 900, 2
CASES = {"tdc": ("tdc_offset:deg=0.5,cylinder={cyl},from_cycle={onset}", "sensor_tdc_offset_cyl{cyl}"),
         "wheel": ("tdc_offset:deg=0.5,cylinder=0,from_cycle={onset}", "sensor_tdc_offset"),
         "gain": ("pressure_gain:cylinder={cyl},gain=0.96,from_cycle={onset}", "sensor_pressure_gain_cyl{cyl}"),
         "healthy": (None, None)}


def _quiet(args: list[str]) -> None:
    with contextlib.redirect_stdout(sys.stderr):
        assert cli(args) == 0


def simulate(path: Path, engine: str, point: tuple[float, float], seed: int, cycles: int, effect: str | None) -> Path:
    rpm, load = point
    _quiet(["simulate", "--engine", engine, "--rpm", str(rpm), "--load", str(load), "--cycles", str(cycles),
            "--seed", str(seed), "-o", str(path)] + (["--effect", effect] if effect else []))
    return path


def row(folder: Path, engine: str, model: Path, case: str, onset: int = ONSET, cylinder: int = CYLINDER) -> dict:
    effect, expected = (None if v is None else v.format(cyl=cylinder, onset=onset) for v in CASES[case])
    t0 = time.perf_counter()
    log = simulate(folder / f"{engine}-{case}.mcap", engine, RUN[engine], 62, CYCLES, effect)
    analysis = analyze_log(log, engine=str(model))
    first_any = first_right = None
    early: set[str] = set()
    other: set[str] = set()  # sensor flags other than the expected one after the onset (a wrong cylinder)
    for r in analysis.results:
        sensor = [f for f in r.flags if f.startswith("sensor_")]
        if sensor and r.index < onset:
            early.update(sensor)
        elif sensor:
            other.update(f for f in sensor if f != expected)
        if sensor and first_any is None and r.index >= onset:
            first_any = int(r.index)
        if expected in r.flags and first_right is None and r.index >= onset:
            first_right = int(r.index)
    last = analysis.results[-1]
    status = friction_status(last.smoothed, last.flags)
    withheld = [k + 1 for k, c in enumerate(status.cylinders) if c.status == "withheld"]
    return {"engine": engine, "case": case, "effect": effect, "onset": onset, "cycles": analysis.cycles_ok,
            "first_sensor_flag": first_any, "first_right_flag": first_right,
            "delay": None if first_right is None else first_right - onset,
            "flags_at_end": sorted(f for f in last.flags if f.startswith("sensor_")),
            "cylinder_withheld_at_end": cylinder in withheld, "withheld_at_end": withheld,
            "engine_status_at_end": status.engine.status if hasattr(status, "engine") else None,
            "flags_before_onset": sorted(early), "other_flags_after_onset": sorted(other), "wall_s": round(time.perf_counter() - t0, 1)}


def _cyls(cyls: list[int]) -> str:
    return "all" if len(cyls) > 4 and cyls == list(range(1, len(cyls) + 1)) else ",".join(map(str, cyls)) or "-"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench.sensor_drift", description=__doc__.split("\n\n")[0])
    ap.add_argument("--engine", choices=sorted(COMMISSION), action="append")
    ap.add_argument("--cases", default="tdc,gain,wheel,healthy")
    ap.add_argument("--onset", type=int, default=ONSET, help="first output cycle of the fault (of 900)")
    ap.add_argument("--cylinder", type=int, default=CYLINDER, help="the faulty cylinder of the tdc and gain cases")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="sensor-drift-") as tmp:
        folder = Path(tmp)
        for engine in args.engine or list(COMMISSION):
            healthy = simulate(folder / f"{engine}-commission.mcap", engine, COMMISSION[engine], 61, 300, None)
            model = folder / f"{engine}-model.toml"
            _quiet(["commission", str(healthy), "-o", str(model)])
            for case in args.cases.split(","):
                rows.append(row(folder, engine, model, case, args.onset, args.cylinder))
                print(json.dumps(rows[-1]), flush=True)
    print(f"\n{'engine':12} {'case':8} {'first flag':>10} {'right flag':>10} {'delay':>6}  {'withheld cyl':>12}  "
          f"{'flags at end':28} {'before onset':14} other flags after onset")
    for r in rows:
        print(f"{r['engine']:12} {r['case']:8} {str(r['first_sensor_flag']):>10} {str(r['first_right_flag']):>10} "
              f"{str(r['delay']):>6}  {_cyls(r['withheld_at_end']):>12}  {','.join(r['flags_at_end']) or '-':28} "
              f"{','.join(r['flags_before_onset']) or '-':14} {','.join(r['other_flags_after_onset']) or '-'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
