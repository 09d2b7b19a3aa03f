"""A long run's per-cycle cost per component, and the size of every container its state keeps (issue 29 item 4 /
issue 28, design note 89): a genset is served for months, so no cost and no container may grow with the cycles
served.

    nice python -m bench.long_run_cost [--engine genset-v20] [--cycles 6000] [--bin 500] [--seed 13]
                                       [--step-every 500] [--out F.json]

The product path of ``bench.ring_condition healthy --no-commission``: the simulator streamed chunk by chunk
(core.plant.sim_stream), each record through serve's ``EnginePipeline`` (the cycle assembler, then the monitor's
``CyclePipeline``), each result through the ``AlertEngine`` (every default rule). Per bin of ``--bin`` cycles it
takes the CPU time (this thread's clock, time.thread_time: the box is shared, wall time is the load's) of each
component -- the simulator's chunks, the assembler, the monitor, the alert engine, the loop's own rest -- the
process's RSS and object count, and walks the state the simulator, the pipeline and the alert engine keep: every
list, tuple, deque, dict, set's length and every array's size, by attribute path. The components are timed by
wrapping the objects' own bound methods (the calls the product makes, not copies of them).

Prints one JSON line per bin (``"bin": true``; the CPU of the process's other threads too: BLAS workers, none with
bench/__init__.py's one BLAS thread) and a summary: per component its CPU per cycle in the reference bin (the first
ending after ``--warm`` cycles: the first cycles compile or load kernels) and the last, their ratio, and the median
of the later half of the bins over the earlier half's; every container (element indices collapsed: ``by_pattern``)
whose size changed from the reference bin to the last, with every bin's size. Quote ``uptime`` beside any absolute
figure (docs/quiet-bench.md); the ratios are same-run. ``make bench`` runs ``run()``: 1,500 cycles in bins of 250.
tests/service/test_long_run_state.py holds the sizes (not the times) on a small engine.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import re
import sys
import tempfile
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import load_model
from frictionwatch.core.plant.simulate import start_simulation
from frictionwatch.service.alerts import AlertEngine
from frictionwatch.service.pipeline import EnginePipeline

from bench.ring_after_commission import LOW_LOAD, POINTS

DEMO = Path(__file__).resolve().parents[1] / "replay_logs" / "demo.mcap"  # genset-v20, with faults
COMPONENTS = ("simulator", "assembler", "monitor", "alerts", "loop")
SHORT_MAX = 64  # a sequence this long or shorter is walked element by element; a longer one by its length and arrays
INDEX = re.compile(r"\[\d+\]")
SKIP_MODULES = ("numba", "llvmlite", "logging", "threading")  # compiled dispatchers, loggers, locks: not run state


class Clock:
    """CPU seconds per component in the current bin (this thread's clock)."""

    def __init__(self) -> None:
        self.spent: Counter[str] = Counter()

    def wrap(self, name: str, fn: Callable) -> Callable:
        def timed(*args, **kwargs):
            t = time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.spent[name] += time.thread_time() - t
        return timed


def container_sizes(roots: dict[str, object], max_depth: int = 12) -> dict[str, int]:
    """Path -> size of every container reachable from ``roots`` by attributes, dict values and short sequences:
    len() of lists, tuples, deques, dicts, sets, Counters, bytes; .size of arrays. An object met twice is walked
    once (its first path)."""
    out: dict[str, int] = {}
    seen: set[int] = set()
    stack = [(name, obj, 0) for name, obj in roots.items()]
    while stack:
        path, obj, depth = stack.pop()
        if id(obj) in seen or depth > max_depth or obj is None or isinstance(obj, bool | int | float | complex | str):
            continue
        seen.add(id(obj))
        if isinstance(obj, np.ndarray):
            out[path] = int(obj.size)
            continue
        if isinstance(obj, bytes | bytearray | memoryview):
            out[path] = len(obj)
            continue
        if isinstance(obj, type) or callable(obj) and not hasattr(obj, "__dict__"):
            continue
        mod = getattr(type(obj), "__module__", "") or ""
        if mod.startswith(SKIP_MODULES) or type(obj).__name__ in ("module", "function", "method", "generator"):
            continue
        if isinstance(obj, dict):
            out[path] = len(obj)
            if len(obj) <= 4 * SHORT_MAX:
                stack += [(f"{path}[{k!r:.40}]", v, depth + 1) for k, v in obj.items()]
            continue
        if isinstance(obj, list | tuple | deque | set | frozenset):
            out[path] = len(obj)
            items = list(obj)
            if len(items) <= SHORT_MAX:
                stack += [(f"{path}[{i}]", v, depth + 1) for i, v in enumerate(items)]
            else:  # a long sequence: its arrays' total size, so a sequence of growing arrays is seen too
                out[path + "[*].size"] = sum(int(v.size) for v in items if isinstance(v, np.ndarray))
            continue
        attrs = dict(getattr(obj, "__dict__", {}))
        for slot in getattr(type(obj), "__slots__", ()):
            if hasattr(obj, slot):
                attrs[slot] = getattr(obj, slot)
        stack += [(f"{path}.{k}", v, depth + 1) for k, v in attrs.items()]
    return out


def rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def stream(engine: str, cycles: int, bin_cycles: int, seed: int, step_every: int,
           emit: Callable[[dict], None] = lambda row: None) -> tuple[list[dict], dict[int, dict[str, int]]]:
    """Stream one run (module doc): the bins' rows (each also given to ``emit`` as it closes) and the container
    sizes at the end of each bin, {cycles served: {path: size}} (``container_sizes`` of the simulator, the pipeline
    and the alert engine)."""
    rpm, load = POINTS[engine]
    t_cycle = 120.0 / rpm
    steps = [(i * step_every * t_cycle, load * (LOW_LOAD if i % 2 else 1.0))
             for i in range(1, cycles // step_every)] if step_every else []
    model = load_model(engine)
    sim = start_simulation(load_engine(engine), rpm, load, cycles, seed, load_steps=steps or None)
    pipe = EnginePipeline(model, sim.info)
    alerts = AlertEngine(model.spec, baseline=None)
    clock = Clock()
    # the product's own calls, timed where they are: the assembler's feed (read through pipe.assembler at each
    # record), the monitor's process, the alert engine's update
    pipe.assembler.feed = clock.wrap("assembler", pipe.assembler.feed)
    pipe.cycles.process = clock.wrap("monitor", pipe.cycles.process)
    update = clock.wrap("alerts", alerts.update)
    roots = {"simulator": sim, "pipeline": pipe, "alerts": alerts}
    bins, sizes, n, events = [], {}, 0, 0
    chunks = iter(sim.chunks())
    t_bin, c_bin, o_bin = time.thread_time(), time.process_time(), other_threads_cpu_s()
    while True:
        t = time.thread_time()
        chunk = next(chunks, None)
        clock.spent["simulator"] += time.thread_time() - t
        if chunk is None:
            break
        for record in chunk.records:
            for res in pipe.feed(record):
                n += 1
                events += len(update(res))
                if n % bin_cycles:
                    continue
                total, process = time.thread_time() - t_bin, time.process_time() - c_bin
                spent = dict(clock.spent)
                spent["loop"] = total - sum(spent.values())
                others = other_threads_cpu_s()
                gc.collect()
                row = {"bin": True, "cycles": n,
                       "cpu_ms_per_cycle": {k: round(1e3 * spent.get(k, 0.0) / bin_cycles, 3) for k in COMPONENTS},
                       "thread_cpu_s": round(total, 2), "process_cpu_s": round(process, 2),
                       "other_threads_cpu_s": {k: round(v - o_bin.get(k, 0.0), 2) for k, v in others.items()},
                       "rss_mb": round(rss_mb(), 1), "gc_objects": len(gc.get_objects()), "alert_events": events,
                       "load1": round(_load1(), 2)}
                bins.append(row)
                emit(row)
                sizes[n] = container_sizes(roots)
                clock.spent.clear()
                t_bin, c_bin, o_bin = time.thread_time(), time.process_time(), other_threads_cpu_s()
    return bins, sizes


def by_pattern(sizes: dict[str, int]) -> dict[str, int]:
    """The sizes with every element index collapsed (``a.b[3].c`` -> ``a.b[*].c``), the largest per pattern: the
    elements of a list are one container kind, whichever of them a bin happens to hold."""
    out: dict[str, int] = {}
    for path, size in sizes.items():
        key = INDEX.sub("[*]", path)
        out[key] = max(out.get(key, 0), size)
    return out


def summary(bins: list[dict], sizes: dict[int, dict[str, int]], warm: int) -> dict:
    """Per component the reference bin's CPU per cycle (the first bin ending after ``warm`` cycles: the first
    cycles load or compile kernels), the last bin's and their ratio, and the median of the later half of the bins
    from the reference on over the earlier half's; the container patterns (``by_pattern``) whose size changed from
    the reference bin to the last, with every bin's size."""
    ref_i = next((i for i, b in enumerate(bins) if b["cycles"] > warm), 0)
    used = bins[ref_i:]
    half = max(1, len(used) // 2)

    def ms(b: dict, k: str) -> float:
        return b["process_cpu_s"] * 1e3 / _bin_len(bins) if k == "total" else b["cpu_ms_per_cycle"][k]

    per = {}
    for k in COMPONENTS + ("total",):
        a, b = ms(used[0], k), ms(used[-1], k)
        early, late = np.median([ms(x, k) for x in used[:half]]), np.median([ms(x, k) for x in used[half:] or used])
        per[k] = {"first_ms": round(a, 3), "last_ms": round(b, 3), "last_over_first": round(b / a, 3) if a else None,
                  "late_over_early_median": round(float(late / early), 3) if early else None}
    pats = {c: by_pattern(s) for c, s in sizes.items()}
    s_ref, s_last = pats[used[0]["cycles"]], pats[used[-1]["cycles"]]
    changed = {p: [pats[c].get(p) for c in sorted(pats)] for p in sorted(set(s_ref) | set(s_last))
               if s_ref.get(p) != s_last.get(p)}
    return {"reference_bin_cycles": used[0]["cycles"], "last_bin_cycles": used[-1]["cycles"], "per_component": per,
            "rss_mb": [used[0]["rss_mb"], used[-1]["rss_mb"]],
            "gc_objects": [used[0]["gc_objects"], used[-1]["gc_objects"]],
            "containers_changed": changed, "containers_walked": len(sizes[used[-1]["cycles"]])}


def _bin_len(bins: list[dict]) -> int:
    return bins[1]["cycles"] - bins[0]["cycles"] if len(bins) > 1 else bins[0]["cycles"]


def other_threads_cpu_s() -> dict[str, float]:
    """CPU seconds (user + system, since each started) of this process's threads other than the calling one, by
    thread name: BLAS or numba workers spend CPU the component clocks (this thread's) do not see."""
    me, tick = threading.get_native_id(), os.sysconf("SC_CLK_TCK")
    out: Counter[str] = Counter()
    for task in os.listdir("/proc/self/task"):
        if int(task) == me:
            continue
        try:
            with open(f"/proc/self/task/{task}/stat") as fh:
                stat = fh.read()
        except OSError:  # the thread ended
            continue
        name, rest = stat[stat.index("(") + 1:stat.rindex(")")], stat[stat.rindex(")") + 2:].split()
        out[name] += (int(rest[11]) + int(rest[12])) / tick  # utime, stime (fields 14, 15)
    return dict(out)


def _load1() -> float:
    with open("/proc/loadavg") as fh:
        return float(fh.read().split()[0])


def serve_sizes(cycles: int, history_cycles: int, **options) -> tuple[dict[str, int], dict]:
    """serve's per-engine stack in this process, as ``serve --data-dir`` wires it: a DataDir store (SQLite in a
    temporary folder, its StoreListener on the fan-out), an EngineService on the demo log looped as fast as it reads
    (``?loop=1``), the AlertEngine; stopped once ``cycles`` results are in (a few more may come), then walked whole
    (``container_sizes`` of the service and the data dir, ``by_pattern``). Also: the cycles served, RSS [MB].
    ``options``: the EngineService's (e.g. recent_s)."""
    from frictionwatch.drivers.source import open_source
    from frictionwatch.drivers.timebase import Clocks
    from frictionwatch.service.data_dir import DataDir
    from frictionwatch.service.engine_service import EngineService
    from frictionwatch.service.pipeline import resolve_model

    url = f"mcap:{DEMO}?loop=1"
    with tempfile.TemporaryDirectory(prefix="long-run-") as tmp:
        data = DataDir(Path(tmp))
        src = open_source(url, Clocks())
        model = resolve_model(src.engine_toml, None, "demo", src.info)
        svc = EngineService("demo", model, src.info, {"log": src}, urls=[url], history_cycles=history_cycles,
                            **options, alerts=data.with_baseline(lambda _id, spec, baseline=None: AlertEngine(spec, baseline=baseline)))
        data.attach(svc)
        svc.start()
        came = svc.session.wait_results(cycles, timeout=3600.0)
        svc.stop()
        if not came:
            raise RuntimeError(f"serve's stack gave {svc.cycles_ok} results of {cycles} in an hour")
        data.close()
        return by_pattern(container_sizes({"service": svc, "data_dir": data})), {"cycles": svc.cycles_ok,
                                                                                  "rss_mb": round(rss_mb(), 1)}


def run(engine: str = "genset-v20", cycles: int = 1500, bin_cycles: int = 250, seed: int = 13,
        step_every: int = 250, warm: int = 250) -> dict:
    """``make bench``'s entry (bench/run.py): a shorter run than the command's (~1 min of CPU), its summary."""
    bins, sizes = stream(engine, cycles, bin_cycles, seed, step_every)
    return {"engine": engine, "cycles": cycles, "bin_cycles": bin_cycles, **summary(bins, sizes, warm)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench.long_run_cost", description=__doc__.split("\n\n")[0])
    ap.add_argument("--engine", choices=sorted(POINTS), default="genset-v20")
    ap.add_argument("--cycles", type=int, default=6000)
    ap.add_argument("--bin", type=int, default=500, help="cycles per bin")
    ap.add_argument("--seed", type=int, default=13)
    ap.add_argument("--step-every", type=int, default=500, help="a load step every N cycles (0: none)")
    ap.add_argument("--warm", type=int, default=500, help="bins ending at or before this cycle are not the reference")
    ap.add_argument("--out", default="", help="write the bins and the summary here (JSON)")
    ap.add_argument("--serve", type=int, default=0, help="instead: serve's stack on the looped demo log (serve_sizes) "
                    "to N and to 2 N cycles; the containers larger at 2 N")
    ap.add_argument("--history", type=int, default=200, help="--serve: the results the service holds (history_cycles)")
    args = ap.parse_args(argv)
    if args.serve:
        (a, at_a), (b, at_b) = serve_sizes(args.serve, args.history), serve_sizes(2 * args.serve, args.history)
        print(json.dumps({"serve": True, "first": at_a, "second": at_b, "patterns": len(b),
                          "larger": {p: [a.get(p), v] for p, v in sorted(b.items()) if v > a.get(p, 0)}}), flush=True)
        return 0
    bins, sizes = stream(args.engine, args.cycles, args.bin, args.seed, args.step_every,
                         lambda row: print(json.dumps(row), flush=True))
    out = {"argv": vars(args), **summary(bins, sizes, args.warm)}
    print(json.dumps(out), flush=True)
    if args.out:
        with open(args.out, "w") as fh:
            json.dump({**out, "bins": bins}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
