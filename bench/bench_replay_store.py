"""A replay read as fast as it can be into a slow store, and a real-time replay's latency, on two checkouts
(issue 28, design note 57). Each run is a child process of the checkout measured (its own .venv: its frictionwatch),
this file and tests/service/slow_store.py from this checkout; the checkouts alternate, A B B A.

- ``slow``: the demo log played ``--passes`` times over and then ended (not real time) into a store (SQLite in a
  temporary folder, DataDir as serve joins it) whose every cycle is a commit of its own slowed by ``--write-ms``;
  the fan-out's default queue (256). Reports the cycles analysed (offered to the store), stored once the stop has
  returned, dropped and left (counted), and the wall times until every source had ended (the replay), until the
  store's queue was empty (the store done: serve would go on running) and until the stop returned.
- ``latency``: the demo log looped at ``--speed`` (real time: a replay with a speed never waits), a store as serve
  has it (not slowed); after the monitor's warm-up (WARM_RESULTS cycles) ``--seconds`` of cycles, each cycle's
  latency from the read of the record that completed it (``ServiceEvent.arrived_s``) to a listener holding its
  event. Reports the median and p90 (ms) and the cycles analysed.

    .venv/bin/python -m bench.bench_replay_store slow --against ../h-store-base --repeat 2
    .venv/bin/python -m bench.bench_replay_store latency --against ../h-store-base --repeat 2

Not part of `make bench` nor the tests. On a shared box quote `uptime` beside the figures; compare same-run ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WARM_RESULTS = 150  # service/live.py's: the cycles after which the monitor is warm


def slow_run(passes: int, write_s: float) -> dict:
    from tests.service.serve_helpers import wait_until
    from tests.service.slow_store import DemoPasses, slow_store_engine, stored

    with tempfile.TemporaryDirectory() as tmp:
        data, svc = slow_store_engine(Path(tmp) / "data", DemoPasses(passes), write_s)
        t0 = time.monotonic()
        svc.start()
        try:
            wait_until(lambda: svc.sources_ended, timeout=1800, every=0.02)
            ended = time.monotonic() - t0
            wait_until(lambda: svc.fanout.queued["store"] == 0, timeout=1800, every=0.02)  # as serve would go on
            drained = time.monotonic() - t0
            svc.stop()
            stopped = time.monotonic() - t0
            kept = stored(data)
        finally:
            svc.stop()
            data.close()
        return {"analysed": svc.cycles_ok, "stored": len(kept), "stored_distinct": len(set(kept)),
                "dropped": svc.fanout.drops.get("store", 0), "left": getattr(svc.fanout, "left", {}).get("store"),
                "ended_s": round(ended, 2), "drained_s": round(drained, 2), "stopped_s": round(stopped, 2)}


def latency_run(speed: float, seconds: float) -> dict:
    import numpy as np
    from frictionwatch.service.data_dir import DataDir

    from tests.service.serve_helpers import DEMO, demo_service, wait_until

    lat: list[float] = []

    def listener(event) -> None:
        if event.result is not None and event.arrived_s is not None:
            lat.append(time.monotonic() - event.arrived_s)

    with tempfile.TemporaryDirectory() as tmp:
        data = DataDir(Path(tmp) / "data")
        svc = demo_service("genset-v20", f"mcap:{DEMO}?loop=1&speed={speed:g}")
        svc.add_listener(listener)
        data.attach(svc)
        svc.start()
        try:
            wait_until(lambda: svc.cycles_ok >= WARM_RESULTS, timeout=600)
            first, n0 = len(lat), svc.cycles_ok
            time.sleep(seconds)
            kept, n1 = lat[first:], svc.cycles_ok
        finally:
            svc.stop()
            data.close()
    ms = np.asarray(kept) * 1e3
    return {"cycles": n1 - n0, "events": len(ms), "median_ms": round(float(np.median(ms)), 2),
            "p90_ms": round(float(np.percentile(ms, 90)), 2), "realtime": svc.session.realtime,
            "dropped": sum(svc.fanout.drops.values())}


def child(args: argparse.Namespace) -> None:
    out = slow_run(args.passes, args.write_ms / 1e3) if args.mode == "slow" else latency_run(args.speed, args.seconds)
    print(json.dumps(out))


def run_in(checkout: Path, args: argparse.Namespace) -> dict:
    cmd = [str(checkout / ".venv" / "bin" / "python"), "-m", "bench.bench_replay_store", args.mode, "--child",
           "--passes", str(args.passes), "--write-ms", str(args.write_ms), "--speed", str(args.speed),
           "--seconds", str(args.seconds)]
    env = {**os.environ, "NUMBA_CACHE_DIR": os.environ.get("NUMBA_CACHE_DIR", f"/tmp/nb-{checkout.name}")}
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=3600)
    if done.returncode != 0:
        raise RuntimeError(f"{checkout}: {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mode", choices=("slow", "latency"))
    ap.add_argument("--against", help="the other checkout (its own .venv); without it only this one runs")
    ap.add_argument("--repeat", type=int, default=2, help="runs of each checkout, alternated")
    ap.add_argument("--passes", type=int, default=10, help="slow: passes of the demo log (~40 cycles each)")
    ap.add_argument("--write-ms", type=float, default=20.0, help="slow: what each cycle's commit is slowed by")
    ap.add_argument("--speed", type=float, default=4.0, help="latency: the replay's speed (1 = real time)")
    ap.add_argument("--seconds", type=float, default=15.0, help="latency: wall seconds measured after warm-up")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args)
        return
    checkouts = [("this", ROOT)] + ([("against", Path(args.against).resolve())] if args.against else [])
    runs = []
    for i in range(args.repeat):
        for name, checkout in checkouts if i % 2 == 0 else checkouts[::-1]:
            runs.append({"checkout": name, **run_in(checkout, args), "loadavg": os.getloadavg()})
            print(json.dumps(runs[-1]), file=sys.stderr, flush=True)
    print(json.dumps({"mode": args.mode, "args": vars(args), "runs": runs}, indent=1))


if __name__ == "__main__":
    main()
