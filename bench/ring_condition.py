"""The ring-condition figure (issue 29 item 3) through the product's path: an accuracy run, not a test; the figures go
into the work's report.

    python -m bench.ring_condition ring --engine genset-v20 --cylinder 10 --onset 1000        # after commissioning
    python -m bench.ring_condition ring --engine genset-v20 --cylinder 1 --onset 1000 --second-wheel   # two wheels
    python -m bench.ring_condition ring --engine maruti-3cyl --cylinder 2 --onset 0 --no-commission   # from the start
    python -m bench.ring_condition ring --engine k9k-4cyl --fault blow_by --cylinder 3 --onset 0 --no-commission
    python -m bench.ring_condition healthy --engine k9k-4cyl --cycles 3000 --step-every 500
    python -m bench.ring_condition healthy --engine k9k-4cyl --mismatch gain --no-commission

Every run streams the simulator (core.plant.sim_stream) through ``EnginePipeline`` and the ``AlertEngine`` serve makes
(default AlertConfig, every rule, RingConditionRule among them). With commissioning (the default), healthy logs of
the same seed are commissioned first as bench/ring_after_commission.py does (``frictionwatch commission``: TDC,
gains, the alert baseline per load band; with ``--onset 0`` the fault is in the commissioning logs too: the engine
was commissioned with it), and the run starts with that model and baseline; ``--no-commission``
starts from the engine preset with no baseline (the alerts learn theirs from the run's first healthy cycles: a fault
present from the first cycle is in it).

ring: a ``ring_wear`` (F1-F3 x ``--gain``, a ``--mass-loss`` leak) or ``blow_by`` fault in ``--cylinder`` from
output cycle ``--onset`` (0: from the first cycle) with a linear ``--ramp``; stops ``--after`` cycles after the
first ring alert naming that cylinder or ``--max-delay`` cycles after the onset. healthy: no fault (or a
``--mismatch``: a 3 % pressure gain error, a 0.5 deg TDC offset, a Stribeck ring-friction law, on cylinder 2 where it
is per cylinder; a shaft line 15 % softer or stiffer than the model's) with combustion variability and a load
step every ``--step-every`` cycles between the point's load and ``--low-load`` (60 %) of it; every ring alert is false (a sensor_fault on the mismatched cylinder is right).
Prints one JSON line (``--progress N``: a line with "progress": true every N cycles before it): the first ring alert
per rule, wrong-cylinder and early ring alerts, and the ring-condition figures (largest since / against siblings z per
cylinder over the run, the faulty cylinder's at the end); ``--trace F.npz`` keeps the per-cycle figures.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import load_model
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.plant.simulate import start_simulation
from frictionwatch.service.alert_baseline import Baseline
from frictionwatch.service.alert_ring_rule import RingConditionRule
from frictionwatch.service.alerts import RING_KINDS, AlertEngine

from bench.accuracy_v20_long import ENGINE
from bench.accuracy_v20_wheels import TWO_WHEELS
from bench.ring_after_commission import LOW_LOAD, POINTS, commission

MISMATCH = {"gain": ["pressure_gain:cylinder=2,gain=1.03"], "tdc": ["tdc_offset:cylinder=2,deg=0.5"],
            "friction_law": ["stribeck_ring:fraction=1.0"], "none": [],
            # the shaft line 15 % softer / stiffer than the monitor's model: the throws' twist it reads each cylinder
            # at is off (core.monitor.checks.ring_pressure.ThrowMotion)
            "chain_soft": ["chain_mismatch:stiffness_scale=0.85"], "chain_stiff": ["chain_mismatch:stiffness_scale=1.15"]}


def run(args: argparse.Namespace, cycles: int, effects: list[str], step_every: int, stop=None,
        commission_effects: tuple[str, ...] = ()) -> dict:
    """Stream one run; the events, the rule's per-cycle figures and counts. ``commission_effects``: simulator
    effects in the commissioning logs too (a fault there from the first cycle)."""
    rpm, load = POINTS[args.engine]
    if args.second_wheel and args.engine != ENGINE:
        raise SystemExit(f"--second-wheel: only {ENGINE} has an engine file with a free-end wheel ({TWO_WHEELS.name})")
    with tempfile.TemporaryDirectory(prefix="ring-cond-") as tmp:
        if args.no_commission:
            model, baseline = load_model(args.engine), None
        else:
            path = commission(Path(tmp), args.engine, args.seed, args.commission_cycles,
                              [float(f) for f in args.commission_loads.split(",")], args.cov, commission_effects)
            model = load_model(str(path))
            baseline = (Baseline.from_dict(json.loads(model.calibration.baseline))
                        if model.calibration.baseline else None)
    steps = []
    if step_every:
        t_cycle = 120.0 / rpm
        steps = [(i * step_every * t_cycle, load * (args.low_load if i % 2 else 1.0))
                 for i in range(1, cycles // step_every)]
    spec = load_engine(args.engine)
    if args.second_wheel:  # the same engine with its free-end wheel (the commissioning logs and model have one wheel)
        spec = load_engine(TWO_WHEELS)
        model = replace(model, spec=replace(model.spec, sensors=spec.sensors))
    sim = start_simulation(spec, rpm, load, cycles, args.seed,
                           effects=[parse_effect(e) for e in effects], cov_imep=args.cov, load_steps=steps or None,
                           second_wheel=args.second_wheel)
    from frictionwatch.service.pipeline import EnginePipeline
    pipe = EnginePipeline(model, sim.info, MonitorConfig(second_wheel=True) if args.second_wheel else None)
    alerts = AlertEngine(model.spec, baseline=baseline)
    rule = next(r for stage in alerts.rules for r in stage if isinstance(r, RingConditionRule))
    events, trace = [], {"cycle": [], "since": [], "since_sigma": [], "siblings": [], "siblings_sigma": []}
    kept = []  # --save: every cycle's result, for bench.alert_autocorrelation's replays
    t0, c0, n = time.perf_counter(), time.process_time(), 0
    for chunk in sim.chunks():
        for record in chunk.records:
            for res in pipe.feed(record):
                n += 1
                if args.save:
                    kept.append(res)
                events += [(int(res.index), e.kind, e.alert) for e in alerts.update(res)]
                if args.progress and n % args.progress == 0:  # a long run's partial figures, should it be cut
                    raised = [r for r in _raised(events) if r["kind"] in RING_KINDS]
                    print(json.dumps({"progress": True, "cycles": n, "ring_alerts": raised[:10],
                                      "cpu_s": round(time.process_time() - c0, 1),
                                      "wall_s": round(time.perf_counter() - t0, 1)}), flush=True)
                rc = rule.last
                if rc is not None:
                    trace["cycle"].append(int(res.index))
                    for key in ("since", "since_sigma", "siblings", "siblings_sigma"):
                        trace[key].append(getattr(rc, key).copy())
        if stop is not None and stop(events, n):
            break
    arr = {k: np.array(v) for k, v in trace.items()}
    if args.save:  # the run's results and the baseline it started from: the alerts replay on them alone
        with open(args.save, "wb") as fh:
            pickle.dump({"argv": vars(args), "spec": model.spec, "baseline": baseline, "results": kept,
                         "effects": effects}, fh)
    return {"events": events, "trace": arr, "cycles": n, "wall_s": round(time.perf_counter() - t0, 1),
            "cpu_s": round(time.process_time() - c0, 1),
            "load_steps": len(steps), "commissioned": not args.no_commission,
            "second_wheel": pipe.config.second_wheel,  # the joint fit ran (not only asked for)
            "bands_at_end": [round(b.imep_pa / 1e5, 2) for b in (alerts.baseline.bands if alerts.baseline else ())]}


def _raised(events: list) -> list[dict]:
    return [{"cycle": i, "kind": a.kind, "cylinder": a.cylinder, "rule": a.rule, "severity": a.severity,
             "message": a.message[:150]} for i, k, a in events if k == "raised"]


def _z_summary(trace: dict) -> dict:
    """Per cylinder: the largest since / against-siblings figure over sigma over the run (NaN-free), 3 decimals."""
    out = {}
    with np.errstate(invalid="ignore", divide="ignore"):
        for key in ("since", "siblings"):
            zz = trace[key] / trace[key + "_sigma"]
            mx = np.nanmax(np.where(np.isfinite(zz), zz, -np.inf), axis=0) if zz.size else np.array([])
            out[f"max_z_{key}"] = [round(float(v), 2) if np.isfinite(v) else None for v in mx]
            fig = np.nanmax(np.where(np.isfinite(trace[key]), trace[key], -np.inf), axis=0) if zz.size else []
            out[f"max_{key}"] = [round(float(v), 2) if np.isfinite(v) else None for v in fig]
    return out


def ring(args: argparse.Namespace) -> dict:
    params = f"cylinder={args.cylinder},from_cycle={args.onset},ramp_cycles={args.ramp},mass_loss={args.mass_loss}"
    effect = f"ring_wear:{params},gain={args.gain}" if args.fault == "ring_wear" else f"blow_by:{params}"

    def first(events: list) -> int | None:
        return next((i for i, k, a in events if k == "raised" and a.kind in RING_KINDS
                     and a.cylinder == args.cylinder), None)

    def stop(events: list, n: int) -> bool:
        f = first(events)
        return f is not None and n >= f + args.after

    # from the first cycle the fault is there when the engine is commissioned, too (without a ramp there)
    at_commission = (f"{effect.split(':')[0]}:" + params.replace(f"ramp_cycles={args.ramp}", "ramp_cycles=0")
                     + (f",gain={args.gain}" if args.fault == "ring_wear" else ""),) if args.onset == 0 else ()
    out = run(args, args.onset + args.max_delay, [effect], args.step_every, stop, at_commission)
    raised = _raised(out["events"])
    firsts = {}
    for r in raised:
        if r["kind"] in RING_KINDS and r["cylinder"] == args.cylinder:
            firsts.setdefault(r["rule"], r["cycle"] - args.onset)
    _save(args, out["trace"])
    tr = out["trace"]
    k = args.cylinder - 1
    end = {}
    if tr["since"].size:
        end = {key: (round(float(tr[key][-1, k]), 3) if np.isfinite(tr[key][-1, k]) else None)
               for key in ("since", "since_sigma", "siblings", "siblings_sigma")}
    return {"mode": "ring", "engine": args.engine, "seed": args.seed, "effect": effect, "onset": args.onset,
            "commissioned": out["commissioned"], "commissioned_with": list(at_commission) if out["commissioned"] else [],
            "second_wheel": out["second_wheel"],
            "step_every": args.step_every, "delay_cycles": None if first(out["events"]) is None else first(out["events"]) - args.onset,
            "first_by_rule": firsts,
            "wrong_cylinder": [r for r in raised if r["kind"] in RING_KINDS and r["cylinder"] != args.cylinder],
            "before_onset": [r for r in raised if r["cycle"] < args.onset and r["kind"] in RING_KINDS],
            "other": [r for r in raised if r["kind"] not in RING_KINDS][:8], "faulty_at_end": end,
            **_z_summary(tr), "cycles": out["cycles"], "wall_s": out["wall_s"], "cpu_s": out["cpu_s"],
            "bands_at_end": out["bands_at_end"]}


def healthy(args: argparse.Namespace) -> dict:
    out = run(args, args.cycles, MISMATCH[args.mismatch], args.step_every)
    raised = _raised(out["events"])
    _save(args, out["trace"])
    return {"mode": "healthy", "engine": args.engine, "seed": args.seed, "mismatch": MISMATCH[args.mismatch],
            "commissioned": out["commissioned"], "step_every": args.step_every, "load_steps": out["load_steps"],
            "second_wheel": out["second_wheel"],
            "ring_alerts": [r for r in raised if r["kind"] in RING_KINDS],
            "other": [r for r in raised if r["kind"] not in RING_KINDS][:12], **_z_summary(out["trace"]),
            "cycles": out["cycles"], "wall_s": out["wall_s"], "cpu_s": out["cpu_s"], "bands_at_end": out["bands_at_end"]}


def _save(args: argparse.Namespace, trace: dict) -> None:
    if args.trace:
        np.savez_compressed(args.trace, **trace)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench.ring_condition", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="mode", required=True)
    for name in ("ring", "healthy"):
        p = sub.add_parser(name)
        p.add_argument("--engine", choices=sorted(POINTS), default="k9k-4cyl")
        p.add_argument("--seed", type=int, default=7, help="the engine (commissioning and run alike)")
        p.add_argument("--cov", type=float, default=0.03, help="COV of IMEP (combustion variability)")
        p.add_argument("--no-commission", action="store_true", help="no commissioning: the preset, no baseline")
        p.add_argument("--second-wheel", action="store_true", help="log the free-end wheel too (accuracy_v20_wheels.TWO_WHEELS) and "
                       "fit both wheels (MonitorConfig.second_wheel; the commissioning logs stay one-wheel)")
        p.add_argument("--commission-cycles", type=int, default=300)
        p.add_argument("--commission-loads", default=f"1.0,{LOW_LOAD}")
        p.add_argument("--trace", default="", help="keep the per-cycle figures in this .npz")
        p.add_argument("--save", default="", help="pickle the run's results and starting baseline here "
                       "(bench.alert_autocorrelation replays the alerts on them)")
        p.add_argument("--step-every", type=int, default=0 if name == "ring" else 500)
        p.add_argument("--progress", type=int, default=0, help="a progress line every N cycles (0: none)")
        p.add_argument("--low-load", type=float, default=LOW_LOAD, help="the steps' other load, a fraction of the point's")
        if name == "ring":
            p.add_argument("--fault", choices=("ring_wear", "blow_by"), default="ring_wear")
            p.add_argument("--cylinder", type=int, default=2)
            p.add_argument("--onset", type=int, default=1000)
            p.add_argument("--gain", type=float, default=1.3, help="ring group friction factor")
            p.add_argument("--mass-loss", type=float, default=0.03, help="trapped mass lost IVC->EVO (the leak)")
            p.add_argument("--ramp", type=int, default=100)
            p.add_argument("--max-delay", type=int, default=2000)
            p.add_argument("--after", type=int, default=0, help="cycles run on after the first alert")
        else:
            p.add_argument("--cycles", type=int, default=3000)
            p.add_argument("--mismatch", choices=sorted(MISMATCH), default="none")
    args = ap.parse_args(argv)
    out = (ring if args.mode == "ring" else healthy)(args)
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
