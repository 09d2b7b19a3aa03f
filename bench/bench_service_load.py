"""Load on the service (issue #17 item 7): while `frictionwatch serve` ingests genset-v20 at real time (the demo
log looped, speed=1), this second process sends ``--rate`` dashboard requests/s for ``--seconds`` s and reports:

- cycles analysed and skipped during the load, and the real-time need (the log's cycles per wall second);
- p50 / p99 API latency seen by the client (request sent -> whole response read);
- the server's histograms (deltas over the load window): record arrival -> result, result -> visible to the API;
- the server's CPU time per analysed cycle, with and without the load (/proc/PID/stat), and from it the number of
  genset-v20 engines at 1500 rpm (12.5 cycles/s) one core could follow at real time: an estimate from the measured
  cost, not a run of that many engines.

    .venv/bin/python -m bench.bench_service_load [--seconds 60] [--rate 200] [--idle 20]

Takes minutes (numba compiles the monitor in the server first); not part of `make bench` nor the tests.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import re
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np
from prometheus_client.parser import text_string_to_metric_families

ROOT = Path(__file__).resolve().parents[1]
ENGINE = "genset-v20"
ROUTES = [f"/api/v1/engines/{ENGINE}/losses"] * 4 + [f"/api/v1/engines/{ENGINE}/cycles/latest"] * 2 + [
    f"/api/v1/engines/{ENGINE}/speed", f"/api/v1/engines/{ENGINE}/friction-torque", "/api/v1/health",
    "/api/v1/engines"]
CYCLES_PER_S_1500 = 1500 / 120


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def scrape(client: httpx.Client) -> dict:
    fams = {f.name: f for f in text_string_to_metric_families(client.get("/metrics").text)}
    out = {"processed": 0.0, "skipped": {}, "hist": {}}
    for s in fams["frictionwatch_cycles_processed"].samples:
        out["processed"] = s.value
    for s in fams["frictionwatch_cycles_skipped"].samples:
        out["skipped"][s.labels["reason"]] = s.value
    for name in ("frictionwatch_cycle_latency_seconds", "frictionwatch_cycle_to_api_seconds"):
        out["hist"][name] = {float(s.labels["le"]): s.value for s in fams[name].samples if s.name.endswith("_bucket")}
    return out


def hist_quantile(before: dict, after: dict, q: float) -> float | None:
    """The upper bucket bound holding quantile q of the observations between two scrapes."""
    les = sorted(after)
    counts = np.array([after[le] - before.get(le, 0.0) for le in les])
    if counts[-1] <= 0:
        return None
    i = int(np.searchsorted(counts, q * counts[-1]))
    return les[min(i, len(les) - 1)]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=200.0)
    ap.add_argument("--idle", type=float, default=20.0, help="seconds measured without load first")
    args = ap.parse_args()
    proc = subprocess.Popen([sys.executable, "-m", "frictionwatch.service.cli", "serve", "--port", "0", "--source",
                             "mcap:replay_logs/demo.mcap?loop=1&speed=1"], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout], daemon=True).start()
    try:
        url = None
        while url is None:
            m = re.search(r"dashboard at (\S+)", lines.get(timeout=300))
            url = m[1] if m else None
        with httpx.Client(base_url=url, timeout=10) as client:
            t0 = time.monotonic()
            while client.get(f"/api/v1/engines/{ENGINE}/losses").status_code != 200:
                time.sleep(0.5)
            print(f"first result after {time.monotonic() - t0:.0f} s (numba compile included)", flush=True)
            time.sleep(10)  # past the first cycles' backlog
            s0, c0, w0 = scrape(client), cpu_s(proc.pid), time.monotonic()
            time.sleep(args.idle)
            s1, c1, w1 = scrape(client), cpu_s(proc.pid), time.monotonic()
            lat = load(url, args.rate, args.seconds)
            s2, c2, w2 = scrape(client), cpu_s(proc.pid), time.monotonic()
            passes_rate = 40 / (3.2 + 1.0)  # the demo log: 40 cycles in 3.2 s, then the loop's 1 s gap
        report(args, lat, (s0, s1, s2), (c0, c1, c2), (w0, w1, w2), passes_rate)
    finally:
        proc.terminate()
        proc.wait(30)


def load(url: str, rate: float, seconds: float, routes: list[str] = ROUTES, tag: bool = False) -> dict:
    """Open loop: request i (``routes[i % len(routes)]``) is due at start + i / rate, whatever the answers before
    it; its send and its read's end on the monotonic clock (the one bench/serve_probe.py logs in the server).
    ``tag``: each request carries the header x-bench-id: i (the probe's key for it)."""
    n = int(rate * seconds)
    out, sent, done = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    status, late = np.zeros(n, int), np.zeros(n)
    local = threading.local()
    start = time.monotonic() + 0.5

    def one(i: int) -> None:
        client = getattr(local, "client", None) or httpx.Client(base_url=url, timeout=10)
        local.client = client
        due = start + i / rate
        time.sleep(max(0.0, due - time.monotonic()))
        late[i] = time.monotonic() - due
        sent[i] = time.monotonic()
        try:
            r = client.get(routes[i % len(routes)], headers={"x-bench-id": str(i)} if tag else None)
            r.read()
            status[i] = r.status_code
        except httpx.HTTPError:
            status[i] = -1
        done[i] = time.monotonic()
        out[i] = done[i] - sent[i]

    with ThreadPoolExecutor(max_workers=32) as pool:
        list(pool.map(one, range(n)))
    return {"latency_s": out, "status": status, "send_late_s": late, "n": n, "sent": sent, "done": done}


def report(args, lat, scrapes, cpus, walls, need_rate) -> None:
    s0, s1, s2 = scrapes
    idle_cycles, load_cycles = s1["processed"] - s0["processed"], s2["processed"] - s1["processed"]
    lat_ms = lat["latency_s"] * 1e3
    ok = lat["status"] == 200
    doc = {
        "rate_req_s": args.rate, "seconds": args.seconds, "requests": lat["n"], "ok_200": int(ok.sum()),
        "other_status": {str(k): int(v) for k, v in zip(*np.unique(lat["status"][~ok], return_counts=True))},
        "api_latency_ms": {"p50": float(np.nanpercentile(lat_ms, 50)), "p99": float(np.nanpercentile(lat_ms, 99)),
                           "max": float(np.nanmax(lat_ms))},
        "client_send_late_ms_p99": float(np.percentile(lat["send_late_s"] * 1e3, 99)),
        "need_cycles_per_s": need_rate,
        "idle": {"cycles": idle_cycles, "cycles_per_s": idle_cycles / (walls[1] - walls[0]),
                 "cpu_s_per_cycle": (cpus[1] - cpus[0]) / max(idle_cycles, 1)},
        "under_load": {"cycles": load_cycles, "cycles_per_s": load_cycles / (walls[2] - walls[1]),
                       "cpu_s_per_cycle": (cpus[2] - cpus[1]) / max(load_cycles, 1),
                       "skipped": {k: v - s1["skipped"].get(k, 0) for k, v in s2["skipped"].items()
                                   if v - s1["skipped"].get(k, 0)}},
        "arrival_to_result_s": {"p50_le": hist_quantile(s1["hist"]["frictionwatch_cycle_latency_seconds"],
                                                        s2["hist"]["frictionwatch_cycle_latency_seconds"], 0.5),
                                "p99_le": hist_quantile(s1["hist"]["frictionwatch_cycle_latency_seconds"],
                                                        s2["hist"]["frictionwatch_cycle_latency_seconds"], 0.99)},
        "result_to_api_s": {"p50_le": hist_quantile(s1["hist"]["frictionwatch_cycle_to_api_seconds"],
                                                    s2["hist"]["frictionwatch_cycle_to_api_seconds"], 0.5),
                            "p99_le": hist_quantile(s1["hist"]["frictionwatch_cycle_to_api_seconds"],
                                                    s2["hist"]["frictionwatch_cycle_to_api_seconds"], 0.99)},
    }
    cost = doc["idle"]["cpu_s_per_cycle"]
    doc["genset_engines_per_core_estimate"] = 1.0 / (cost * CYCLES_PER_S_1500) if cost > 0 else None
    print(json.dumps(doc, indent=1, default=float))


if __name__ == "__main__":
    main()
