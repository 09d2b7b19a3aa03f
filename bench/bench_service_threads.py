"""Where serve's CPU goes, thread by thread (issue 28 item 7; design notes 34): ``frictionwatch serve`` of one
checkout with ``--engines`` genset-v20 (the demo log looped at real time, one engine per --source) pinned to one
core; after the first results and ``--settle`` s, each thread's CPU over ``--seconds`` s from
/proc/<pid>/task/<tid>/stat, named by ``py-spy dump`` (Python 3.11 gives its threads no OS names; the engine in a
name is folded, so ``live-read-*`` is every engine's reader together), per cycle analysed.

    .venv/bin/python -m bench.bench_service_threads --engines 4 --py-spy /tmp/spyenv/bin/py-spy
    .venv/bin/python -m bench.bench_service_threads --checkout ../base --engines 4 ...   # another checkout's serve
    ... --replay-batch-s 0.02      # serve with another paced-replay read batch (LiveSession replay_batch_s)

Two checkouts: alternate them (A B A B) in one run and quote each thread's ratio with ``uptime`` (quiet-bench.md).
Thread CPU is what the other jobs' descheduling does not move; a server that falls behind (cycles analysed well
under those offered) reads records it then drops, which a per-cycle figure charges to the cycles it did analyse:
compare runs that keep up. Without py-spy every thread is ``python``. Minutes of wall time; not in the tests.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import time
from collections import Counter
from pathlib import Path

import httpx

from bench.bench_service_plant import CYCLE_REVS, launched

ROOT = Path(__file__).resolve().parents[1]


def thread_cpu(pid: int) -> dict[str, float]:
    """CPU seconds of each live thread of ``pid``, by tid."""
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            fields = Path(f"/proc/{pid}/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended meanwhile
            continue
        out[tid] = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return out


def thread_switches(pid: int) -> dict[str, tuple[int, int]]:
    """(voluntary, involuntary) context switches of each live thread of ``pid`` so far, by tid: a thread that
    blocks (a lock, the GIL held by another) switches voluntarily; one preempted (another woke) involuntarily."""
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            text = Path(f"/proc/{pid}/task/{tid}/status").read_text()
        except OSError:  # the thread ended meanwhile
            continue
        vol = re.search(r"^voluntary_ctxt_switches:\s+(\d+)", text, re.M)
        inv = re.search(r"^nonvoluntary_ctxt_switches:\s+(\d+)", text, re.M)
        if vol and inv:
            out[tid] = (int(vol[1]), int(inv[1]))
    return out


def thread_names(pid: int, py_spy: str | None) -> dict[str, str]:
    """tid -> Python thread name (the engine folded to ``*``), from ``py-spy dump``; {} without py-spy."""
    if not py_spy:
        return {}
    text = subprocess.run([py_spy, "dump", "-p", str(pid)], capture_output=True, text=True, check=False).stdout
    return {m[1]: re.sub(r"mcap\d+|g\d+", "*", m[2]) for m in re.finditer(r'Thread (\d+) \(\w+\): "([^"]+)"', text)}


def start_server(checkout: Path, n: int, cpu: int, batch_s: float | None, numba_cache: str | None = None
                 ) -> tuple[subprocess.Popen, str]:
    """``checkout``'s serve of ``n`` looped demo gensets on core ``cpu`` (``numba_cache``: its NUMBA_CACHE_DIR)."""
    python = checkout / ".venv" / "bin" / "python"
    launch = ["-m", "frictionwatch.service.cli"]
    if batch_s is not None:  # LiveSession's default read batch replaced before serve builds its sessions
        launch = ["-c", "import sys; import frictionwatch.service.live as L; L.LiveSession.__init__.__kwdefaults__"
                        f"['replay_batch_s'] = {batch_s!r}; from frictionwatch.service.cli import main; "
                        "sys.exit(main(sys.argv[1:]))"]
    cmd = ["taskset", "-c", str(cpu), str(python), *launch, "serve", "--port", "0", "--history-cycles", "5000"]
    for i in range(n):
        cmd += ["--source", f"mcap:replay_logs/demo.mcap?loop=1&speed=1#g{i + 1}"]
    if numba_cache:  # each checkout its own compiled kernels
        cmd = ["env", f"NUMBA_CACHE_DIR={numba_cache}", *cmd]
    return launched(cmd, checkout, timeout_s=900)


def processed(client: httpx.Client) -> float:
    return sum(float(line.split()[-1]) for line in client.get("/metrics").text.splitlines()
               if line.startswith("frictionwatch_cycles_processed_total"))


def ready(client: httpx.Client, engines: list[str]) -> bool:
    try:
        return all(client.get(f"/api/v1/engines/{e}/cycles/latest").status_code == 200 for e in engines)
    except httpx.HTTPError:  # a server busy compiling may drop a connection
        return False


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--checkout", type=Path, default=ROOT, help="the checkout whose serve runs (its own .venv)")
    ap.add_argument("--engines", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=40.0)
    ap.add_argument("--settle", type=float, default=10.0)
    ap.add_argument("--cpu", type=int, default=1, help="the core the server is pinned to")
    ap.add_argument("--py-spy", help="py-spy's path, to name the threads")
    ap.add_argument("--replay-batch-s", type=float, help="serve's paced-replay read batch instead of its default")
    args = ap.parse_args()
    engines = [f"g{i + 1}" for i in range(args.engines)]
    proc, url = start_server(args.checkout.resolve(), args.engines, args.cpu, args.replay_batch_s)
    try:
        with httpx.Client(base_url=url, timeout=10) as client:
            while not ready(client, engines):
                time.sleep(1.0)
            time.sleep(args.settle)
            cpu0, n0, w0 = thread_cpu(proc.pid), processed(client), time.monotonic()
            time.sleep(args.seconds)
            cpu1, n1, w1 = thread_cpu(proc.pid), processed(client), time.monotonic()
            rpm = [client.get(f"/api/v1/engines/{e}/cycles/latest").json()["rpm_mean"] for e in engines]
        names = thread_names(proc.pid, args.py_spy)
        by_name: Counter[str] = Counter()
        for tid, s in cpu1.items():
            by_name[names.get(tid, "python")] += s - cpu0.get(tid, 0.0)
        cycles = n1 - n0
        total = sum(by_name.values())
        per_s = float(sum(rpm)) / len(rpm) / 60.0 / CYCLE_REVS
        print(json.dumps({
            "checkout": str(args.checkout.resolve()), "engines": args.engines, "wall_s": w1 - w0,
            "replay_batch_s": args.replay_batch_s, "cycles_analysed": cycles,
            "cycles_offered": per_s * len(engines) * (w1 - w0), "cpu_ms_per_cycle": 1e3 * total / cycles,
            "gensets_per_core": 1.0 / (total / cycles * per_s),
            "by_thread_ms_per_cycle": {k: round(1e3 * v / cycles, 3) for k, v in by_name.most_common()},
            "loadavg": os.getloadavg()}, indent=1))
    finally:
        proc.terminate()
        try:
            proc.wait(90)
        except subprocess.TimeoutExpired:
            proc.kill()


if __name__ == "__main__":
    main()
