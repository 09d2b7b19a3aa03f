"""The service's own work per cycle, outside the monitor (issue 28 item 7): what ``serve`` does with each result of
one genset-v20 — the alert engine's update, the API state's window row, the metrics' histograms (on the API state's
thread since design note 92: then in ``api_state_ms``, and ``metrics_ms`` is 0) — timed on the demo
log's results looped (the replay's own loop: cycle numbers and times go on), so the alert engine learns its
baseline and runs every rule as in a served plant. Thread CPU time (``time.thread_time``) per cycle, median of
``--repeat`` passes; the events are printed as a digest so that two checkouts can be compared on the same results.

    .venv/bin/python -m bench.bench_service_cycle --cycles 600
    ../base/.venv/bin/python bench/bench_service_cycle.py --cycles 600     # another checkout's code, same script

Two checkouts side by side: run each alternately (A B A B) and quote the ratio, with ``uptime`` (quiet-bench.md).
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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=600)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-faults", action="store_true", help="the demo's healthy results only")
    args = ap.parse_args()
    results = looped_results(args.cycles, not args.no_faults)
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
