"""Two checkouts' serve at once, on one core, each with ``--engines`` genset-v20 (the demo log looped at real time):
the server CPU per cycle analysed of each over the same windows, and their ratio (issue 28 item 7; design note 158).

On this shared box the CPU a cycle of one checkout moved 5.1 -> 7.1 ms between two runs minutes apart (load 9.6 ->
11.8, bench_service_plant idle), more than any cut of serve's code outside the monitor could show. Here both servers
share the core and the minutes, so whatever the box does meets both: a window's ratio is a same-run A/B. Each
window's figures come from /proc (all threads) and each server's cycle counter, taken together; the ratio over the
whole span (``whole_B_over_A``: a window's count of cycles moves with where its ends fall in a result's ingest)
is the figure, each window's beside it.

    .venv/bin/python -m bench.bench_service_pair --against /tmp/base --against-numba-cache /tmp/nb-base --engines 4
    .venv/bin/python -m bench.bench_service_pair --against . --replay-batch-s 0.04 0.16   # one checkout, two settings

``--against``: the other checkout (its own .venv); ``NUMBA_CACHE_DIR`` of this process goes to this checkout's serve,
``--against-numba-cache`` to the other's. Both keep up at 4 engines each on one core (~2 x 0.3 of it); check
each window's ``cycles`` against ``cycles_offered_per_window_each``. The server started second read 2-3 % cheaper
in each of three A/A runs (design note 158): compare a ratio with an A/A run, or run both orders (``--b-first``) and
take the geometric mean. Minutes; not in the tests.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]


def sample(client: httpx.Client, pid: int) -> tuple[float, float]:
    """(server CPU s so far, cycles analysed so far)."""
    from bench.bench_service_load import cpu_s
    from bench.bench_service_plant import counters

    return cpu_s(pid), counters(client)["processed"]


def main() -> None:
    sys.path.insert(0, str(ROOT))
    ap = argparse.ArgumentParser()
    ap.add_argument("--against", required=True, help="the other checkout (A); this one is B")
    ap.add_argument("--against-numba-cache", help="NUMBA_CACHE_DIR for the other checkout's serve")
    ap.add_argument("--engines", type=int, default=4)
    ap.add_argument("--cpu", type=int, default=1)
    ap.add_argument("--settle", type=float, default=15.0)
    ap.add_argument("--seconds", type=float, default=20.0, help="one window")
    ap.add_argument("--windows", type=int, default=6)
    ap.add_argument("--b-first", action="store_true",
                    help="start B's server before A's (the second started read 2-3 %% cheaper in A/A runs: run both "
                         "orders and take the geometric mean of the two ratios)")
    ap.add_argument("--replay-batch-s", type=float, nargs=2, metavar=("A", "B"),
                    help="each server's paced-replay read batch instead of serve's default (LiveSession replay_batch_s)")
    args = ap.parse_args()
    from bench.bench_service_plant import wait_first_results
    from bench.bench_service_threads import start_server

    sides = {"A": (Path(args.against).resolve(), args.against_numba_cache),
             "B": (ROOT, os.environ.get("NUMBA_CACHE_DIR"))}
    procs, clients = {}, {}
    engines = [f"g{i + 1}" for i in range(args.engines)]
    try:
        for name in ("B", "A") if args.b_first else ("A", "B"):
            checkout, cache = sides[name]
            batch_s = args.replay_batch_s["AB".index(name)] if args.replay_batch_s else None
            procs[name], url = start_server(checkout, args.engines, args.cpu, batch_s, cache)
            clients[name] = httpx.Client(base_url=url, timeout=30)
        for name in sides:
            wait_first_results(clients[name], engines)
        time.sleep(args.settle)
        windows = []
        first = last = {n: sample(clients[n], procs[n].pid) for n in sides}
        for _ in range(args.windows):
            w0 = time.monotonic()
            time.sleep(args.seconds)
            now = {n: sample(clients[n], procs[n].pid) for n in sides}
            ms = {n: 1e3 * (now[n][0] - last[n][0]) / max(1.0, now[n][1] - last[n][1]) for n in sides}
            windows.append({"A_ms_per_cycle": round(ms["A"], 3), "B_ms_per_cycle": round(ms["B"], 3),
                            "B_over_A": round(ms["B"] / ms["A"], 4),
                            "cycles": {n: now[n][1] - last[n][1] for n in sides},
                            "wall_s": round(time.monotonic() - w0, 1), "load1": round(os.getloadavg()[0], 2)})
            last = now
        whole = {n: 1e3 * (last[n][0] - first[n][0]) / (last[n][1] - first[n][1]) for n in sides}
        rpm = [clients["B"].get(f"/api/v1/engines/{e}/cycles/latest").json()["rpm_mean"] for e in engines]
        offered = sum(r / 60.0 / 2.0 for r in rpm) * args.seconds
    finally:
        for p in procs.values():
            p.terminate()
        for p in procs.values():
            p.wait(60)
    print(json.dumps({"A": str(sides["A"][0]), "B": str(ROOT), "replay_batch_s": args.replay_batch_s,
                      "started_first": "B" if args.b_first else "A", "engines_each": args.engines, "cpu": args.cpu,
                      "whole_A_ms": round(whole["A"], 3), "whole_B_ms": round(whole["B"], 3),
                      "whole_B_over_A": round(whole["B"] / whole["A"], 4),
                      "median_B_over_A": statistics.median(w["B_over_A"] for w in windows),
                      "median_A_ms": statistics.median(w["A_ms_per_cycle"] for w in windows),
                      "median_B_ms": statistics.median(w["B_ms_per_cycle"] for w in windows),
                      "cycles_offered_per_window_each": round(offered, 1), "windows": windows,
                      "loadavg": os.getloadavg()}, indent=1))


if __name__ == "__main__":
    main()
