"""Where serve's CPU goes, component by component (issue 28 item 7; design notes 47): ``frictionwatch serve`` of one
checkout with ``--engines`` genset-v20 (the demo log looped at real time, one engine per --source) pinned to one
core, with CPU timers (``time.thread_time``, each exclusive of the timed calls inside it) around the monitor
(core's ``CyclePipeline.process``), the assembler, the alert engine, the fan-out, the listeners, the record merge,
the queue and the replay reader; what a thread spends outside them is its ``rest``; the cyclic garbage collector's
pauses by generation (``gc genN``, thread CPU, already inside the component or rest they fell in). After the first
results and ``--settle`` s, the totals over ``--seconds`` s per cycle analysed, with each thread's CPU from /proc
(named by ``py-spy dump``; one a dump did not name is ``python``) and each thread's context switches (voluntary,
involuntary) per cycle analysed (design note 107: serve's threads preempting one another).

    .venv/bin/python -m bench.bench_service_components --engines 8 --py-spy /tmp/spyenv/bin/py-spy
    .venv/bin/python -m bench.bench_service_components --checkout ../base --engines 8 ...  # another checkout's serve
    taskset -c 1 .venv/bin/python -m bench.bench_service_components --engines 8 --one-thread 300  # no serve (below)
    .venv/bin/python -m bench.bench_service_components --engines 8 --gc-freeze-after 60   # serve's heap frozen at 60 s

The timers cost ~1 us a timed call (~35 calls a genset-v20 cycle, most of them per record: the assembler's and
the pipeline's): compare checkouts with this bench, not its figures with bench_service_plant's. A checkout that
lacks a timed function (renamed, removed) is told in one line and timed without it. Minutes; not in the tests.
"""

from __future__ import annotations

import argparse
import functools
import gc
import json
import os
import sys
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path

ROOT_LOG = Path(__file__).resolve().parents[1] / "replay_logs" / "demo.mcap"
TIMED = (  # (module, class, method, component); the thread's prefix ("ingest", "reader", ...) names where it runs
    ("frictionwatch.service.ingest_queue", "IngestQueue", "get", "ingest: queue get"),
    ("frictionwatch.service.record_merge", "RecordMerge", "push", "ingest: merge"),
    ("frictionwatch.service.record_merge", "RecordMerge", "set_quiet", "ingest: merge"),
    ("frictionwatch.service.engine_service", "RecentRecords", "append", "ingest: recent records"),
    ("frictionwatch.service.engine_service", "RecentRecords", "extend", "ingest: recent records"),
    ("frictionwatch.service.pipeline", "EnginePipeline", "feed", "ingest: pipeline glue"),
    ("frictionwatch.drivers.assembly.cycles", "CycleAssembler", "feed", "ingest: assembler"),
    ("frictionwatch.core.monitor.pipeline", "CyclePipeline", "process", "ingest: monitor"),
    ("frictionwatch.service.alerts", "AlertEngine", "update", "ingest: alert engine"),
    ("frictionwatch.service.listeners", "Fanout", "publish", "ingest: fan-out publish"),
    ("frictionwatch.service.pipeline", "ResultHistory", "append", "ingest: result history"),
    ("frictionwatch.service.engine_service", "EngineService", "_on_result", "ingest: on_result glue"),
    ("frictionwatch.drivers.logs.mcap_replay", "McapSource", "_read_internal", "reader: mcap read+decode"),
    ("frictionwatch.service.ingest_queue", "IngestQueue", "put", "reader: queue put"),
    ("frictionwatch.service.listeners", "LatestState", "on_message_received", "listener: api state"),
    ("frictionwatch.service.metrics", "MetricsListener", "on_message_received", "listener: metrics"),
    ("frictionwatch.service.metrics", "CycleObserver", "__call__", "listener: metrics"),  # on the API state's thread
    ("frictionwatch.service.listeners", "SseBroadcaster", "on_message_received", "listener: sse"),
)


def serve_timed(argv: list[str], out: str, freeze_after_s: float | None = None) -> None:
    """Run serve (``argv``) with the TIMED functions wrapped; cumulative totals written to ``out`` every second.
    ``freeze_after_s``: that long after the start (past the warm-up), one full collection and ``gc.freeze()``, so
    that later collections leave what serve made until then (its modules, numba's objects) out of their pass."""
    import importlib

    total: defaultdict[str, float] = defaultdict(float)
    calls: defaultdict[str, int] = defaultdict(int)
    local = threading.local()

    def wrap(cls, meth: str, comp: str) -> None:
        f = getattr(cls, meth)

        @functools.wraps(f)
        def timed(*a, **k):
            stack = getattr(local, "stack", None)
            if stack is None:
                stack = local.stack = []
            t0 = time.thread_time()
            stack.append(0.0)
            try:
                return f(*a, **k)
            finally:
                el = time.thread_time() - t0
                total[comp] += el - stack.pop()  # exclusive of the timed calls inside
                calls[comp] += 1
                if stack:
                    stack[-1] += el
        setattr(cls, meth, timed)

    for mod, cls, meth, comp in TIMED:
        owner = getattr(importlib.import_module(mod), cls, None)
        if owner is None or meth not in vars(owner):
            print(f"bench_service_components: {mod}.{cls}.{meth} not in this checkout, not timed", file=sys.stderr)
            continue
        wrap(owner, meth, comp)

    def dump() -> None:
        while True:
            time.sleep(1.0)
            with open(out + ".tmp", "w") as fh:
                json.dump({"total": dict(total), "calls": dict(calls)}, fh)
            os.replace(out + ".tmp", out)

    collecting = {}  # thread id -> (generation, thread CPU at the collection's start)

    def on_gc(phase: str, info: dict) -> None:  # the cyclic collector's pauses, by generation (inside the above)
        if phase == "start":
            collecting[threading.get_ident()] = time.thread_time()
            return
        t0 = collecting.pop(threading.get_ident(), None)
        if t0 is not None:
            total[f"gc gen{info['generation']} (inside the above)"] += time.thread_time() - t0
            calls[f"gc gen{info['generation']} (inside the above)"] += 1

    gc.callbacks.append(on_gc)
    threading.Thread(target=dump, name="bench-dump", daemon=True).start()
    if freeze_after_s is not None:
        def freeze() -> None:
            time.sleep(freeze_after_s)
            gc.collect()
            gc.freeze()
            print(f"bench_service_components: {gc.get_freeze_count()} objects frozen", file=sys.stderr)

        threading.Thread(target=freeze, name="bench-freeze", daemon=True).start()
    from frictionwatch.service.cli import main
    sys.exit(main(argv))


def measure(args) -> dict:
    import tempfile

    import httpx

    from bench.bench_service_plant import CYCLE_REVS, launched
    from bench.bench_service_threads import processed, ready, thread_cpu, thread_names, thread_switches

    checkout = Path(args.checkout).resolve()
    live = tempfile.mktemp(prefix="fw-components-", suffix=".json")
    cmd = ["taskset", "-c", str(args.cpu), str(checkout / ".venv" / "bin" / "python"), str(Path(__file__).resolve()),
           "--serve-timed", live, *(["--gc-freeze-after", str(args.gc_freeze_after)] if args.gc_freeze_after else []),
           "serve", "--port", "0", "--history-cycles", "5000"]
    for i in range(args.engines):
        cmd += ["--source", f"mcap:replay_logs/demo.mcap?loop=1&speed=1#g{i + 1}"]
    proc, url = launched(cmd, checkout, timeout_s=900)
    engines = [f"g{i + 1}" for i in range(args.engines)]
    try:
        with httpx.Client(base_url=url, timeout=10) as client:
            while not ready(client, engines):
                time.sleep(1.0)
            time.sleep(args.settle)
            s0, cpu0, n0, w0 = json.loads(Path(live).read_text()), thread_cpu(proc.pid), processed(client), time.monotonic()
            sw0 = thread_switches(proc.pid)
            time.sleep(args.seconds)
            s1, cpu1, n1, w1 = json.loads(Path(live).read_text()), thread_cpu(proc.pid), processed(client), time.monotonic()
            sw1 = thread_switches(proc.pid)
            rpm = [client.get(f"/api/v1/engines/{e}/cycles/latest").json()["rpm_mean"] for e in engines]
        names = thread_names(proc.pid, args.py_spy)
    finally:
        proc.terminate()
        proc.wait(90)
        Path(live).unlink(missing_ok=True)
    by_thread: Counter[str] = Counter()
    for tid, s in cpu1.items():
        by_thread[names.get(tid, "python")] += s - cpu0.get(tid, 0.0)
    cycles = n1 - n0
    switches: defaultdict[str, list[float]] = defaultdict(lambda: [0.0, 0.0])  # (voluntary, involuntary) a cycle
    for tid, (v, i) in sw1.items():
        v0, i0 = sw0.get(tid, (0, 0))
        switches[names.get(tid, "python")][0] += (v - v0) / cycles
        switches[names.get(tid, "python")][1] += (i - i0) / cycles
    ms = {k: 1e3 * (v - s0["total"].get(k, 0.0)) / cycles for k, v in s1["total"].items()}
    threads = {k: 1e3 * v / cycles for k, v in by_thread.items()}
    inline = sum(v for k, v in ms.items() if k.startswith("listener")) if "listener-api-state" not in threads else 0.0
    ingest = threads.get("live-ingest", 0.0) + threads.get("python", 0.0)  # an unnamed thread: an engine's ingest
    rest = {"ingest: rest (loop, deliver, locks)": ingest - inline - sum(v for k, v in ms.items() if k.startswith("ingest")),
            "reader: rest (loop, stamps)": threads.get("live-read-*", 0.0) - sum(v for k, v in ms.items()
                                                                                 if k.startswith("reader"))}
    total = sum(by_thread.values())
    per_s = sum(rpm) / len(rpm) / 60.0 / CYCLE_REVS
    return {"checkout": str(checkout), "engines": args.engines, "cycles_analysed": cycles,
            "cycles_offered": per_s * args.engines * (w1 - w0), "cpu_ms_per_cycle": 1e3 * total / cycles,
            "listeners_inline": "listener-api-state" not in threads,
            "threads_ms_per_cycle": {k: round(v, 3) for k, v in sorted(threads.items(), key=lambda kv: -kv[1])},
            "components_ms_per_cycle": {k: round(v, 3) for k, v in sorted({**ms, **rest}.items())},
            "switches_per_cycle": {k: [round(v, 2), round(i, 2)] for k, (v, i) in sorted(switches.items())},
            "timed_calls_per_cycle": {k: round((v - s0["calls"].get(k, 0)) / cycles, 2)
                                      for k, v in sorted(s1["calls"].items())},
            "loadavg": os.getloadavg()}


def one_thread(engines: int, cycles: int, warm: int = 100) -> dict:
    """The monitor (``CyclePipeline.process``, thread CPU a call) of ``engines`` demo logs looped as fast as they are
    read (McapSource loop=1, each engine its own source and EnginePipeline), the engines' reads taken in turn on
    this one thread: serve's data and work without its threads, GIL or listeners (design note 141), so that the
    monitor's cost a cycle can be told apart by what it depends on (engines interleaved or not, threads or not).
    The cyclic collector's pauses are counted beside (thread CPU, inside the figures)."""
    import statistics

    from frictionwatch.core.monitor.pipeline import CyclePipeline
    from frictionwatch.drivers.logs.mcap_replay import McapSource
    from frictionwatch.service.pipeline import EnginePipeline, resolve_model

    log = ROOT_LOG
    spent: list[float] = []
    paused = [0.0, 0.0]  # collector CPU so far, thread CPU at the current pause's start

    def on_gc(phase: str, info: dict) -> None:
        if phase == "start":
            paused[1] = time.thread_time()
        else:
            paused[0] += time.thread_time() - paused[1]

    process = CyclePipeline.process

    def timed(self, cycle):
        t0 = time.thread_time()
        try:
            return process(self, cycle)
        finally:
            spent.append(time.thread_time() - t0)

    sources = [McapSource(log, loop=True, max_records=64) for _ in range(engines)]
    model = resolve_model(sources[0].engine_toml, None, log.name, sources[0].info)
    pipes = [EnginePipeline(model, sources[0].info) for _ in range(engines)]
    CyclePipeline.process = timed
    gc.callbacks.append(on_gc)
    try:
        start = None
        while len(spent) < (warm + cycles) * engines:
            if start is None and len(spent) >= warm * engines:
                start, first, paused[0] = time.thread_time(), len(spent), 0.0
            for source, pipe in zip(sources, pipes, strict=True):
                for record in source.read(1.0):
                    pipe.feed(record)
        ms = [1e3 * s for s in spent[first:]]
        wall = time.thread_time() - start
    finally:
        CyclePipeline.process = process
        gc.callbacks.remove(on_gc)
        for source in sources:
            source.close()
    return {"engines": engines, "cycles": len(ms), "monitor_mean_ms": round(statistics.mean(ms), 3),
            "monitor_median_ms": round(statistics.median(ms), 3),
            "read_assemble_monitor_ms_per_cycle": round(1e3 * wall / len(ms), 3),
            "gc_ms_per_cycle": round(1e3 * paused[0] / len(ms), 3), "loadavg": os.getloadavg()}


def main() -> None:
    if len(sys.argv) > 2 and sys.argv[1] == "--serve-timed":  # the server process itself
        if sys.argv[3] == "--gc-freeze-after":
            serve_timed(sys.argv[5:], sys.argv[2], float(sys.argv[4]))
        else:
            serve_timed(sys.argv[3:], sys.argv[2])
        return
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench.* when run as a script
    ap = argparse.ArgumentParser()
    ap.add_argument("--checkout", default=str(Path(__file__).resolve().parents[1]))
    ap.add_argument("--engines", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=40.0)
    ap.add_argument("--settle", type=float, default=10.0)
    ap.add_argument("--cpu", type=int, default=1)
    ap.add_argument("--py-spy", help="py-spy's path, to name the threads")
    ap.add_argument("--one-thread", type=int, metavar="CYCLES",
                    help="no serve: the monitor of --engines looped demo logs on this thread, CYCLES each after a warm "
                         "stretch (pin it with taskset)")
    ap.add_argument("--gc-freeze-after", type=float, metavar="S",
                    help="S s after serve's start (past its warm-up): a full collection, then gc.freeze()")
    args = ap.parse_args()
    print(json.dumps(one_thread(args.engines, args.one_thread) if args.one_thread else measure(args), indent=1))


if __name__ == "__main__":
    main()
