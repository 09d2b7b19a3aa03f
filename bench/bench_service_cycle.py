"""The service's own work per cycle, outside the monitor (issue 28 item 7): what ``serve`` does with each result of
one genset-v20 — the alert engine's update, the API state's window row, the metrics' histograms (on the API state's
thread since design note 92: then in ``api_state_ms``, and ``metrics_ms`` is 0) — timed on the demo
log's results looped (the replay's own loop: cycle numbers and times go on), so the alert engine learns its
baseline and runs every rule as in a served plant. Thread CPU time (``time.thread_time``) per cycle, median of
``--repeat`` passes; the events are printed as a digest so that two checkouts can be compared on the same results.

    .venv/bin/python -m bench.bench_service_cycle --cycles 600
    ../base/.venv/bin/python bench/bench_service_cycle.py --cycles 600     # another checkout's code, same script

Two checkouts side by side: run each alternately (A B A B) and quote the ratio, with ``uptime`` (quiet-bench.md).

``--answers FILE`` also writes what the API answers at fixed cycles (every ``ANSWER_EVERY``-th: /losses now and
over windows of 50 and 400 cycles, the cycle summary, each cylinder's stored losses) and the friction status with
its words (engine and cylinders, the smoothed and the cycle's estimate), made from the API state and the alert
engine as serve holds them; ``--against FILE`` compares this run's with another checkout's: words, integers and
None exactly, numbers to ``ANSWER_RTOL`` (design note 100).
Target (issue 28 item 7: 25 genset-v20 per core needs <= 3.2 ms a cycle all in, the monitor ~1.4 ms of it): these
three together well under 1 ms a cycle.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_MS = 1.0  # the three per-cycle costs together (module doc)
ANSWER_EVERY = 25  # cycles between two answers taken (--answers)
# numbers: the same arithmetic, but a kernel compiled in the run and one loaded from the cache differ by up to
# ~4e-12 relative (design notes 11, 94; a core source changed is a new cache folder, so a fresh compile)
ANSWER_RTOL = 1e-9


def looped_results(n: int, faults: bool = True) -> list:
    """``n`` results of the demo log played in a loop (index and start time going on, as a looped replay's); with
    ``faults`` some made up so that every kind of alert event happens (the digest then covers raise, update and
    clear): cylinder 3 misfires in cycles 100-139, cylinder 2's TDC sensor is flagged in 150-179, the speed fit
    misfits in 200-229, and from cycle 320 cylinder 5's pressure bends like a leak (its compression exponent
    -0.004, expansion +0.006 against the siblings), growing to twice that from 450."""
    import numpy as np
    from frictionwatch.service.pipeline import analyze_log

    base = analyze_log(ROOT / "replay_logs" / "demo.mcap").results
    span = base[-1].t_start - base[0].t_start + (base[-1].t_start - base[-2].t_start)
    out = []
    for i in range(n):
        r = base[i % len(base)]
        r = replace(r, index=i, t_start=r.t_start + (i // len(base)) * span)
        if faults:
            flags = (*r.flags, *(("misfire_cyl3",) if 100 <= i < 140 else ()),
                     *(("sensor_tdc_offset_cyl2",) if 150 <= i < 180 else ()),
                     *(("model_misfit",) if 200 <= i < 230 else ()))
            ring = r.ring
            if ring is not None and i >= 320:
                step = np.zeros(ring.n_compression_dev.shape[0])
                step[4] = 1.0 if i < 450 else 2.0
                ring = replace(ring, n_compression_dev=ring.n_compression_dev - 0.004 * step,
                               n_expansion_dev=ring.n_expansion_dev + 0.006 * step)
            r = replace(r, flags=flags, ring=ring)
        out.append(r)
    return out


def timed_pass(results: list) -> tuple[dict, str]:
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.service import metrics as m
    from frictionwatch.service.alerts import AlertEngine
    from frictionwatch.service.listeners import LatestState, ServiceEvent

    spec = load_engine("genset-v20")
    alerts = AlertEngine(spec)
    state = LatestState()
    service_metrics = m.ServiceMetrics(lambda: [], lambda: 0)
    if hasattr(m, "CycleObserver"):  # the histograms observed on the API state's thread (design note 92)
        state.on_visible = service_metrics.observer("g1")
        metrics = None
    else:  # a checkout before it: the metrics listener of its own (and the API state's to_api histogram)
        metrics = m.MetricsListener(service_metrics, "g1")
        state.on_visible = service_metrics.to_api.labels("g1").observe
    t_alert = t_state = t_metrics = 0.0
    digest = hashlib.sha256()
    for r in results:
        t0 = time.thread_time()
        events = alerts.update(r)
        docs = [e.alert.to_dict() for e in events]  # what serve sends on (engine_service._alert_dict)
        t1 = time.thread_time()
        ev = ServiceEvent("g1", r, time.monotonic(), None, tuple(docs))
        state.on_message_received(ev)
        t2 = time.thread_time()
        if metrics is not None:
            metrics.on_message_received(ev)
        t3 = time.thread_time()
        t_alert, t_state, t_metrics = t_alert + t1 - t0, t_state + t2 - t1, t_metrics + t3 - t2
        for e, d in zip(events, docs, strict=True):
            digest.update(json.dumps([e.kind, {k: v for k, v in d.items() if k != "raised_at_s"}], sort_keys=True,
                                     default=repr).encode())
    n = len(results)
    alerts_final = [a.to_dict() for a in alerts.history()]
    digest.update(json.dumps(alerts_final, sort_keys=True, default=repr).encode())
    return {"alerts_ms": 1e3 * t_alert / n, "api_state_ms": 1e3 * t_state / n, "metrics_ms": 1e3 * t_metrics / n,
            "events": len(alerts_final)}, digest.hexdigest()[:16]


def answers(results: list) -> list:
    """What the API answers and the status words at every ANSWER_EVERY-th cycle (module doc), one pass."""
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.monitor.report.figure_status import friction_status
    from frictionwatch.service import api_views as v
    from frictionwatch.service.alerts import AlertEngine
    from frictionwatch.service.listeners import LatestState, ServiceEvent

    alerts, state, names = AlertEngine(load_engine("genset-v20")), LatestState(), ("a", "b", "c")
    out = []
    for r in results:
        docs = tuple(e.alert.to_dict() for e in alerts.update(r))
        state.on_message_received(ServiceEvent("g1", r, time.monotonic(), None, docs))
        if r.index % ANSWER_EVERY:
            continue
        newest, held = state.snapshot()
        words = {which: [[f.status, f.reason, f.data_weight] for f in (st.engine, *st.cylinders)]
                 for which, st in (("smoothed", friction_status(r.smoothed, r.flags)),
                                   ("cycle", friction_status(r.cycle, r.flags)))}
        windows = {}
        for n in (50, 400):
            last, win = state.window(n)
            windows[n] = v.losses_window("g1", last, win, names) if win is not None else None
        out.append({"cycle": int(r.index), "now": v.losses_now("g1", held, names),
                    "summary": v.cycle_summary("g1", newest), "stored": v.cylinder_losses(newest, names),
                    "windows": windows, "status": words,
                    "alerts": [{k: a for k, a in d.items() if k != "raised_at_s"} for d in
                               (x.to_dict() for x in alerts.active())]})
    return json.loads(json.dumps(out, default=repr))  # as a client reads them (tuples as lists, keys as strings)


def same_answers(a, b, where: str = "") -> list[str]:
    """Where two answers differ: words, integers, booleans and None exactly, numbers to ANSWER_RTOL."""
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            return [f"{where}: keys {sorted(a.keys() ^ b.keys())}"]
        return [d for k in a for d in same_answers(a[k], b[k], f"{where}.{k}")]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{where}: {len(a)} against {len(b)} items"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in same_answers(x, y, f"{where}[{i}]")]
    if isinstance(a, float) and isinstance(b, float):
        import math

        ok = (math.isnan(a) and math.isnan(b)) or math.isclose(a, b, rel_tol=ANSWER_RTOL, abs_tol=0.0)
        return [] if ok else [f"{where}: {a!r} against {b!r}"]
    return [] if type(a) is type(b) and a == b else [f"{where}: {a!r} against {b!r}"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=600)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-faults", action="store_true", help="the demo's healthy results only")
    ap.add_argument("--answers", help="write the API's answers and the status words at fixed cycles here")
    ap.add_argument("--against", help="compare them with another checkout's --answers file")
    args = ap.parse_args()
    results = looped_results(args.cycles, not args.no_faults)
    if args.answers or args.against:
        mine = answers(results)
        if args.answers:
            Path(args.answers).write_text(json.dumps(mine))
        if args.against:
            diff = same_answers(json.loads(Path(args.against).read_text()), mine)
            print(json.dumps({"answers_compared": len(mine), "differences": len(diff), "first": diff[:10]}))
    timed_pass(results[:50])  # warm: imports, first calls
    passes = [timed_pass(results) for _ in range(args.repeat)]
    digests = {d for _, d in passes}
    med = {k: statistics.median(p[k] for p, _ in passes) for k in ("alerts_ms", "api_state_ms", "metrics_ms")}
    total = sum(med.values())
    import frictionwatch.service

    print(json.dumps({"checkout": str(Path(frictionwatch.service.__file__).resolve().parents[1]), "cycles": args.cycles,
                      "median_ms_per_cycle": {k: round(v, 4) for k, v in med.items()}, "total_ms": round(total, 4),
                      "target_ms": TARGET_MS, "within_target": total <= TARGET_MS,
                      "passes": [{k: round(v, 4) for k, v in p.items()} for p, _ in passes],
                      "events_digest": sorted(digests), "loadavg": os.getloadavg()}, indent=1))


if __name__ == "__main__":
    main()
