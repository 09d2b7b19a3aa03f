"""Ring wear appearing after commissioning (issue 25 check): an accuracy run, not a test; the figures go into the
work's report.

    python -m bench.ring_after_commission ring --engine k9k-4cyl            # wear from --onset, cycles to the alert
    python -m bench.ring_after_commission healthy --engine k9k-4cyl --cycles 5000 --step-every 500

Both commission first, as a user does: healthy logs of the engine (``frictionwatch simulate``, the same seed: one
seed is one engine, its cylinders' fuel spread and its wheel's tooth errors; tests/service/test_commissioned_baseline.py)
at the point's load and, with ``--commission-loads``, at other fractions of it, then ``frictionwatch commission`` on
them, which writes the model with its calibration and the alert baseline per load band. The run is then streamed
from the simulator chunk by chunk (core.plant.sim_stream) through the product's path: ``EnginePipeline`` with the
commissioned model (its TDC and gain corrections, the TDC and gain watches) and the ``AlertEngine`` serve makes
(service.serve._alerts_factory: default AlertConfig), its baseline seeded from the model's calibration as
service.engine_service.EngineService does when no stored baseline exists.

ring: ``ring_wear`` (ring group x ``--gain``, a ``--mass-loss`` leak, linear ``--ramp``) in ``--cylinder`` from output
cycle ``--onset`` (after the commissioning cycles the same seed's log starts with); stops at the first ring alert
(ring_wear or blow_by) naming that cylinder or ``--max-delay`` cycles after the onset. Prints the delay, the kind of the
first alert, ring alerts on other cylinders and any alert before the onset.
healthy: no fault, combustion variability and a load step every ``--step-every`` cycles between the point's load and
60 % of it; every ring alert is a false alarm; sensor alerts and flags are counted too.

Prints one JSON line (progress lines with "progress": true before it).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
import time
from pathlib import Path

from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import load_model
from frictionwatch.core.plant.simulate import start_simulation
from frictionwatch.service.alert_baseline import Baseline
from frictionwatch.service.alerts import RING_KINDS
from frictionwatch.service.cli import main as cli
from frictionwatch.service.pipeline import EnginePipeline
from frictionwatch.service.serve import _alerts_factory

# operating points (rpm, load): bench/alert_detection.py's, where the alert thresholds were set (service/alerts.py)
POINTS = {"k9k-4cyl": (1700.0, 0.69), "maruti-3cyl": (3000.0, 0.8), "genset-v20": (1500.0, 0.75)}
LOW_LOAD = 0.6  # the healthy run's load steps: between the point's load and this fraction of it


def commission(folder: Path, engine: str, seed: int, cycles: int, fractions: list[float], cov: float,
               effects: tuple[str, ...] = ()) -> Path:
    """MODEL.toml from logs of ``engine`` (seed ``seed``) at each fraction of the point's load: healthy, or with
    ``effects`` (simulator effects, e.g. a worn ring there from the first cycle: the engine as commissioned)."""
    rpm, load = POINTS[engine]
    logs = []
    for f in fractions:
        log = folder / f"commission_{f:g}.mcap"
        extra = [a for e in effects for a in ("--effect", e)]
        with contextlib.redirect_stdout(sys.stderr):
            assert cli(["simulate", "--engine", engine, "--rpm", str(rpm), "--load", str(load * f), "--cycles",
                        str(cycles), "--seed", str(seed), "--cov-imep", str(cov), *extra, "-o", str(log)]) == 0
        logs.append(str(log))
    model = folder / "model.toml"
    with contextlib.redirect_stdout(sys.stderr):  # the commissioning report is not this bench's line
        assert cli(["commission", *logs, "-o", str(model)]) == 0
    return model


def stream(model_path: Path, cycles: int, seed: int, cov: float, effects: list[str], step_every: int = 0,
           stop_when=None, progress: int = 0) -> tuple[list, dict]:
    """The run through the pipeline and the serve alert engine: ([(cycle, event kind, alert)], counts)."""
    model = load_model(str(model_path))
    rpm, load = POINTS[model.spec.name]
    steps = []
    if step_every:
        t_cycle = 120.0 / rpm  # the tick time base: one cycle at the requested speed
        steps = [(i * step_every * t_cycle, load * (LOW_LOAD if i % 2 else 1.0)) for i in range(1, cycles // step_every)]
    sim = start_simulation(load_engine(model.spec.name), rpm, load, cycles, seed,
                           effects=[parse_effect(e) for e in effects], cov_imep=cov, load_steps=steps or None)
    pipe = EnginePipeline(model, sim.info)
    alerts = _alerts_factory()(model.spec.name, model.spec)
    if alerts.baseline is None and model.calibration.baseline:  # as service.engine_service.EngineService
        alerts.baseline = Baseline.from_dict(json.loads(model.calibration.baseline))
    bands = len(alerts.baseline.bands) if alerts.baseline is not None else 0
    events, counts = [], {"cycles": 0, "load_steps": len(steps), "commissioned_bands": bands,
                          "sensor_flag_cycles": 0, "sensor_flags": {}}
    t0, reported = time.perf_counter(), 0
    for chunk in sim.chunks():
        for record in chunk.records:
            for res in pipe.feed(record):
                counts["cycles"] += 1
                sensor = [f for f in res.flags if f.startswith("sensor_")]
                if sensor:
                    counts["sensor_flag_cycles"] += 1
                    for f in sensor:
                        counts["sensor_flags"][f] = counts["sensor_flags"].get(f, 0) + 1
                events += [(int(res.index), e.kind, e.alert) for e in alerts.update(res)]
        if stop_when is not None and stop_when(events):
            break
        if progress and counts["cycles"] // progress > reported:
            reported = counts["cycles"] // progress
            print(json.dumps({"progress": True, "cycles": counts["cycles"], "raised": _raised(events)[:10],
                              "wall_s": round(time.perf_counter() - t0, 1)}), flush=True)
    counts["skipped"] = dict(pipe.skipped)
    counts["wall_s"] = round(time.perf_counter() - t0, 1)
    counts["bands_at_end"] = [{"imep_bar": round(b.imep_pa / 1e5, 2), "cycles": [b.first_cycle, b.last_cycle]}
                              for b in (alerts.baseline.bands if alerts.baseline is not None else ())]
    return events, counts


def _raised(events: list) -> list[dict]:
    return [{"cycle": i, "kind": a.kind, "cylinder": a.cylinder, "severity": a.severity, "message": a.message[:120]}
            for i, k, a in events if k == "raised"]


def ring(args: argparse.Namespace, model: Path) -> dict:
    effect = (f"ring_wear:cylinder={args.cylinder},gain={args.gain},mass_loss={args.mass_loss},"
              f"from_cycle={args.onset},ramp_cycles={args.ramp}")

    def first_named(events: list) -> tuple[int, str] | None:
        return next(((i, a.kind) for i, k, a in events
                     if k == "raised" and a.kind in RING_KINDS and a.cylinder == args.cylinder), None)

    events, counts = stream(model, args.onset + args.max_delay, args.seed, args.cov, [effect],
                            stop_when=lambda ev: first_named(ev) is not None, progress=args.progress)
    hit = first_named(events)
    raised = _raised(events)
    return {"mode": "ring", "engine": args.engine, "point": POINTS[args.engine], "seed": args.seed, "effect": effect,
            "onset": args.onset, "delay_cycles": None if hit is None else hit[0] - args.onset,
            "first_kind": None if hit is None else hit[1],
            "wrong_cylinder": [r for r in raised if r["kind"] in RING_KINDS and r["cylinder"] != args.cylinder],
            "before_onset": [r for r in raised if r["cycle"] < args.onset], "raised": raised[:10], **counts}


def healthy(args: argparse.Namespace, model: Path) -> dict:
    events, counts = stream(model, args.cycles, args.seed, args.cov, [], step_every=args.step_every,
                            progress=args.progress)
    raised = _raised(events)
    return {"mode": "healthy", "engine": args.engine, "point": POINTS[args.engine], "seed": args.seed,
            "step_every": args.step_every, "ring_alerts": [r for r in raised if r["kind"] in RING_KINDS],
            "other_alerts": [r for r in raised if r["kind"] not in RING_KINDS][:20], **counts}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench.ring_after_commission", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="mode", required=True)
    for name in ("ring", "healthy"):
        p = sub.add_parser(name)
        p.add_argument("--engine", choices=sorted(POINTS), default="k9k-4cyl")
        p.add_argument("--seed", type=int, default=7, help="the engine (commissioning and run alike)")
        p.add_argument("--cov", type=float, default=0.03, help="COV of IMEP (combustion variability)")
        p.add_argument("--commission-cycles", type=int, default=300)
        p.add_argument("--commission-loads", default="1.0" if name == "ring" else f"1.0,{LOW_LOAD}",
                       help="fractions of the point's load, one commissioning log each")
        p.add_argument("--progress", type=int, default=250, help="a progress line every N cycles")
        if name == "ring":
            p.add_argument("--cylinder", type=int, default=2)
            p.add_argument("--onset", type=int, default=300)
            p.add_argument("--gain", type=float, default=1.3, help="ring group friction factor")
            p.add_argument("--mass-loss", type=float, default=0.03, help="trapped mass lost IVC->EVO (the leak)")
            p.add_argument("--ramp", type=int, default=100)
            p.add_argument("--max-delay", type=int, default=500)
        else:
            p.add_argument("--cycles", type=int, default=5000)
            p.add_argument("--step-every", type=int, default=500)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="ring-bench-") as tmp:
        model = commission(Path(tmp), args.engine, args.seed, args.commission_cycles,
                           [float(f) for f in args.commission_loads.split(",")], args.cov)
        out = (ring if args.mode == "ring" else healthy)(args, model)
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
