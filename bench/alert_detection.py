"""Alert accuracy on simulator logs the monitor is not told about (issue 17 item 4, issue 19 item 4): an accuracy
run, not a test; the figures go into the work's report.

    python -m bench.alert_detection detect --engine k9k-4cyl --fault ring_wear --cylinder 2 --onset 300 --ramp 100
    python -m bench.alert_detection healthy --engine k9k-4cyl --cycles 20000
    python -m bench.alert_detection mismatch --engine k9k-4cyl --case gain --cycles 600

detect: ring_wear (x1.3 ring group, ``--mass-loss`` leak, default 3 %) or blow_by starting in one cylinder at
``--onset`` with a linear ``--ramp``; the delay is the cycles from the onset to the first ring_wear or blow_by alert
naming that cylinder (alerts on other cylinders are counted as wrong). healthy: combustion variability (``--cov``)
and a load step every ``--step-every`` cycles between the preset's load and 60 % of it; every alert is a false
alarm (the load bands the baseline learnt are listed: service.alert_baseline). mismatch: a pressure gain error of
3 % on cylinder 2 (``gain``), a TDC offset of 0.5 deg on cylinder 2
(``tdc``), a friction law of another shape (``friction_law``: the ring boundary friction on a Stribeck curve instead of the mixed window
, core.model.effects.mismatch); the sensor errors from the start (the commissioning baseline learns them) and,
with ``--given-baseline``, against a baseline learnt on the same engine without them (a sensor changed after
commissioning). A ring alert there is wrong; a sensor_fault or nothing is right.

Every run streams the simulator chunk by chunk (core.plant.sim_stream) through the one pipeline
(service.pipeline.EnginePipeline: the assembler, the monitor with its default configuration, the running calibration
watches) and the AlertEngine with its default AlertConfig; prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import start_simulation
from frictionwatch.service.alert_baseline import Baseline
from frictionwatch.service.alerts import RING_KINDS, AlertEngine
from frictionwatch.service.pipeline import EnginePipeline

POINTS = {"k9k-4cyl": (1700.0, 0.69), "maruti-3cyl": (3000.0, 0.8), "deutz-1cyl": (2400.0, 0.8),
          "genset-v20": (1500.0, 0.75)}
MISMATCH = {"gain": ["pressure_gain:cylinder=2,gain=1.03"], "tdc": ["tdc_offset:cylinder=2,deg=0.5"],
            "friction_law": ["stribeck_ring:fraction=1.0"], "none": []}


def run(engine: str, cycles: int, effects: list[str], seed: int, cov: float, step_every: int = 0,
        baseline: Baseline | None = None, stop_when=None, progress: int = 0) -> tuple[list, AlertEngine, dict]:
    """Stream a simulated log through the monitor and the alerts: (all events, the engine, counts)."""
    spec = load_engine(engine)
    rpm, load = POINTS[engine]
    steps = []
    if step_every:
        t_cycle = 120.0 / rpm
        steps = [(i * step_every * t_cycle, load * (0.6 if i % 2 else 1.0)) for i in range(1, cycles // step_every)]
    sim = start_simulation(spec, rpm, load, cycles, seed, effects=[parse_effect(e) for e in effects],
                           cov_imep=cov, load_steps=steps or None)
    pipe, alerts, events = EnginePipeline(spec, sim.info), AlertEngine(spec, baseline=baseline), []
    counts = {"cycles": 0, "rejected": 0, "lost_in_assembly": 0, "load_steps": len(steps)}
    t0, done_reports = time.perf_counter(), 0
    for chunk in sim.chunks():
        for outcome in (o for r in chunk.records for o in pipe.outcomes(r)):
            if not outcome.ok:
                counts["rejected" if outcome.stage == "monitor" else "lost_in_assembly"] += 1
                continue
            res = outcome.result
            counts["cycles"] += 1
            events += [(res.index, e.kind, e.alert) for e in alerts.update(res)]
        if stop_when is not None and stop_when(events):
            break
        if progress and counts["cycles"] // progress > done_reports:  # a partial figure survives a cut-off run
            done_reports = counts["cycles"] // progress
            print(json.dumps({"progress": True, "cycles": counts["cycles"], "raised": _raised(events)[:20],
                              "wall_s": round(time.perf_counter() - t0, 1)}), flush=True)
    counts["wall_s"] = round(time.perf_counter() - t0, 1)
    counts["baseline_learnt_at"] = alerts.baseline.last_cycle if alerts.baseline is not None else None
    counts["load_bands"] = [{"imep_bar": round(b.imep_pa / 1e5, 2), "cycles": [b.first_cycle, b.last_cycle]}
                            for b in (alerts.baseline.bands if alerts.baseline is not None else ())]
    return events, alerts, counts


def _raised(events: list) -> list[dict]:
    return [{"cycle": int(i), "kind": a.kind, "cylinder": a.cylinder, "severity": a.severity, "message": a.message[:140]}
            for i, k, a in events if k == "raised"]


def detect(args: argparse.Namespace) -> dict:
    params = f"cylinder={args.cylinder},from_cycle={args.onset},ramp_cycles={args.ramp},mass_loss={args.mass_loss}"
    effect = f"ring_wear:{params},gain=1.3" if args.fault == "ring_wear" else f"blow_by:{params}"

    def named(events: list) -> bool:
        return any(k == "raised" and a.kind in RING_KINDS and a.cylinder == args.cylinder for _, k, a in events)

    events, alerts, counts = run(args.engine, args.onset + args.max_delay, [effect], args.seed, args.cov,
                                 stop_when=named, progress=100)
    first = next((i for i, k, a in events if k == "raised" and a.kind in RING_KINDS and a.cylinder == args.cylinder),
                 None)
    wrong = [r for r in _raised(events) if r["kind"] in RING_KINDS and r["cylinder"] != args.cylinder]
    early = [r for r in _raised(events) if r["cycle"] < args.onset]
    return {"mode": "detect", "engine": args.engine, "effect": effect, "onset": args.onset, "ramp": args.ramp,
            "delay_cycles": None if first is None else first - args.onset, "wrong_cylinder": wrong,
            "before_onset": early, "raised": _raised(events)[:10], **counts}


def healthy(args: argparse.Namespace) -> dict:
    events, alerts, counts = run(args.engine, args.cycles, [], args.seed, args.cov, step_every=args.step_every,
                                 progress=args.progress)
    raised = _raised(events)
    return {"mode": "healthy", "engine": args.engine, "cov_imep": args.cov, "step_every": args.step_every,
            "false_alarms": len(raised), "raised": raised[:20], **counts}


def mismatch(args: argparse.Namespace) -> dict:
    base = None
    if args.given_baseline:  # learnt on the same engine (same seed) without the error
        _, clean, _ = run(args.engine, args.baseline_cycles, [], args.seed, args.cov)
        base = clean.baseline
    events, alerts, counts = run(args.engine, args.cycles, MISMATCH[args.case], args.seed, args.cov, baseline=base)
    raised = _raised(events)
    return {"mode": "mismatch", "engine": args.engine, "case": args.case, "effects": MISMATCH[args.case],
            "given_baseline": bool(args.given_baseline), "raised": raised[:20],
            "ring_alerts": sum(r["kind"] in RING_KINDS for r in raised), **counts}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench.alert_detection", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="mode", required=True)
    for name in ("detect", "healthy", "mismatch"):
        p = sub.add_parser(name)
        p.add_argument("--engine", choices=sorted(POINTS), default="k9k-4cyl")
        p.add_argument("--seed", type=int, default=7)
        p.add_argument("--cov", type=float, default=0.03, help="COV of IMEP (combustion variability)")
        if name == "detect":
            p.add_argument("--fault", choices=("ring_wear", "blow_by"), default="ring_wear")
            p.add_argument("--cylinder", type=int, default=2)
            p.add_argument("--onset", type=int, default=300)
            p.add_argument("--ramp", type=int, default=100)
            p.add_argument("--mass-loss", type=float, default=0.03)
            p.add_argument("--max-delay", type=int, default=400, help="cycles after the onset simulated at most")
        if name == "healthy":
            p.add_argument("--cycles", type=int, default=20000)
            p.add_argument("--step-every", type=int, default=1000)
            p.add_argument("--progress", type=int, default=500, help="print the alerts so far every N cycles")
        if name == "mismatch":
            p.add_argument("--case", choices=sorted(MISMATCH), required=True)
            p.add_argument("--cycles", type=int, default=600)
            p.add_argument("--given-baseline", action="store_true")
            p.add_argument("--baseline-cycles", type=int, default=260)
    args = ap.parse_args(argv)
    out = {"detect": detect, "healthy": healthy, "mismatch": mismatch}[args.mode](args)
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
