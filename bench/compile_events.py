"""Where the monitor's numba cold compile goes: numba's compile events, per kernel and per specialisation.

The product path (service.pipeline.run, bench_monitor's short warm-up streams) runs in a fresh process with an empty
numba cache, with a listener on numba's "numba:compile" event registered before the first import. Each event is one
specialisation (a dispatcher and its argument types) compiled; a kernel that calls another compiles the callee inside
its own event, so each event's *exclusive* seconds (its time less the events nested in it) are what that
specialisation cost itself, its callees' linked code optimised again inside it included (numba links a callee's LLVM
module into the caller's and optimises the whole). The sum of the exclusive seconds is the compile time the events
see; ``bench_monitor.cold_compile`` (first pass minus warm pass) also counts what is not an event (typing of the
Python-side calls, writing the cache), so the two differ by a few seconds.

Printed: the summed exclusive seconds by phase (import, then each engine's first run) and how much of them is LLVM
(numba's own timer of its LLVM lock) and Python's garbage collector (gc.callbacks), the largest kernels, the kernels
compiled for more than one signature (a literal and the plain type, C and A layouts, int32 and int64 ...: one
specialisation could serve them all), and with ``--json`` every event. Less load-sensitive than the cold compile's
wall clock (the events time only the compiler), but still CPU time on a shared box: compare same-run pairs.

    python -m bench.compile_events [--engines k9k-4cyl ...] [--top 40] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

_CHILD = """
import gc, json, pickle, sys, time
from numba.core import event, types

class Events(event.Listener):
    # each compile event: its dispatcher, argument types, phase, inclusive and exclusive seconds (less nested events)
    def __init__(self):
        self.stack, self.rows, self.results, self.phase = [], [], [], "import"
        self.gc_s, self.gc_t0 = 0.0, 0.0  # the garbage collector's seconds so far (gc.callbacks)
    def on_gc(self, phase, info):
        if phase == "start":
            self.gc_t0 = time.perf_counter()
        else:
            self.gc_s += time.perf_counter() - self.gc_t0
    def on_start(self, ev):
        f = getattr(ev.data.get("dispatcher"), "py_func", None)
        self.stack.append([time.perf_counter(), 0.0, getattr(f, "__qualname__", "?"), self.gc_s, 0.0])
    def on_end(self, ev):
        t0, nested, _, gc0, gc_nested = self.stack.pop()
        dt, gc_in = time.perf_counter() - t0, self.gc_s - gc0
        if self.stack:
            self.stack[-1][1] += dt
            self.stack[-1][4] += gc_in
        d = ev.data.get("dispatcher")
        f = getattr(d, "py_func", None)
        args = ev.data.get("args") or ()
        self.rows.append({"phase": self.phase, "module": getattr(f, "__module__", "?"),
                          "name": getattr(f, "__qualname__", repr(d)), "args": [str(a) for a in args],
                          "literal": any(isinstance(a, types.Literal) for a in args),
                          "caller": self.stack[-1][2] if self.stack else "",
                          "depth": len(self.stack), "incl_s": dt, "excl_s": dt - nested,
                          "gc_excl_s": gc_in - gc_nested})
        # numba times its LLVM lock per compile result after this event ends: read at the end of the run
        self.results.append(getattr(d, "overloads", {}).get(tuple(args)))

ev = Events()
event.register("numba:compile", ev)
gc.callbacks.append(ev.on_gc)
t0 = time.perf_counter()
from frictionwatch.core.model.engine import load_engine
from frictionwatch.service.pipeline import run
t_import = time.perf_counter() - t0
wall = {"import": t_import}
for name, info, records in pickle.load(open(sys.argv[1], "rb")):
    ev.phase = name
    spec = load_engine(name)
    t = time.perf_counter()
    for _ in run(spec, info, records):
        pass
    wall[name] = time.perf_counter() - t
below = {}  # depth -> the LLVM seconds of the events ended at that depth since their parent's (children end first)
for row, cres in zip(ev.rows, ev.results):
    llvm = ((getattr(cres, "metadata", None) or {}).get("timers") or {}).get("llvm_lock") or 0.0
    row["llvm_excl_s"] = llvm - below.pop(row["depth"] + 1, 0.0)
    below[row["depth"]] = below.get(row["depth"], 0.0) + llvm
json.dump({"wall_s": wall, "gc_s": ev.gc_s, "events": ev.rows}, open(sys.argv[2], "w"))
"""


def short_runs(engines: list[str]) -> list:
    """bench_monitor's cold-compile streams: 12 cycles a point, its seed + 1 (the same records it times)."""
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.plant.simulate import simulate

    from bench.bench_monitor import POINTS, SEED
    out = []
    for name, rpm, load in POINTS:
        if name in engines:
            sim = simulate(load_engine(name), rpm, load, 12, seed=SEED + 1)
            out.append((name, sim.info, sim.records))
    return out


def measure(engines: list[str]) -> dict:
    """The events of one fresh process with an empty numba cache over the engines' short streams."""
    with tempfile.TemporaryDirectory() as tmp:
        runs, out = Path(tmp) / "runs.pkl", Path(tmp) / "events.json"
        runs.write_bytes(pickle.dumps(short_runs(engines)))
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "cache"))
        proc = subprocess.run([sys.executable, "-c", _CHILD, str(runs), str(out)], env=env, cwd=Path.cwd(),
                              capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise RuntimeError(f"the compile run failed: {proc.stderr.strip()[-2000:]}")
        return json.loads(out.read_text())


def summary(r: dict, top: int) -> str:
    ev = r["events"]
    lines = ["phase: wall s (exclusive compile-event s, events)"]
    for phase, wall in r["wall_s"].items():
        rows = [e for e in ev if e["phase"] == phase]
        lines.append(f"  {phase:12s} {wall:7.2f} ({sum(e['excl_s'] for e in rows):6.2f}, {len(rows)})")
    lines.append(f"  {'all':12s} {sum(r['wall_s'].values()):7.2f} ({sum(e['excl_s'] for e in ev):6.2f}, {len(ev)})")
    lines.append(f"of the events' exclusive seconds, under numba's LLVM lock (optimisation, code generation): "
                 f"{sum(e['llvm_excl_s'] for e in ev):.2f}; Python's garbage collector: "
                 f"{sum(e['gc_excl_s'] for e in ev):.2f} (in the whole run {r['gc_s']:.2f})")
    by = defaultdict(list)
    for e in ev:
        by[(e["module"].removeprefix("frictionwatch."), e["name"])].append(e)
    lines.append(f"\nlargest {top} kernels by exclusive s (of it LLVM s; specialisations; phase of the first):")
    for (mod, name), rows in sorted(by.items(), key=lambda kv: -sum(e["excl_s"] for e in kv[1]))[:top]:
        lines.append(f"  {sum(e['excl_s'] for e in rows):6.2f} {sum(e['llvm_excl_s'] for e in rows):6.2f} "
                     f"{len(rows):3d}  {mod}.{name}  [{rows[0]['phase']}]")
    lines.append("\nour kernels compiled for more than one signature (exclusive s each; L: a literal argument):")
    for (mod, name), rows in sorted(by.items(), key=lambda kv: -sum(e["excl_s"] for e in kv[1])):
        if len(rows) > 1 and not mod.startswith(("numba", "numpy")) and "frictionwatch" in rows[0]["module"]:
            lines.append(f"  {mod}.{name}:")
            for e in rows:
                lines.append(f"    {e['excl_s']:5.2f} {'L' if e['literal'] else ' '} [{e['phase']}] "
                             f"({', '.join(e['args'])})"[:200])
    same = defaultdict(list)  # one overload, the same argument types, compiled again: another caller's flags
    for e in ev:
        if not e["module"].startswith("frictionwatch."):
            same[(e["name"], tuple(e["args"]))].append(e)
    again = [rows for rows in same.values() if len(rows) > 1]
    lines.append(f"\nnumba's own overloads compiled again for the same types (a caller with other flags: fastmath, "
                 f"_nrt, error_model): {sum(len(r) - 1 for r in again)} events, "
                 f"{sum(e['excl_s'] for r in again for e in r[1:]):.2f} s beyond the first of each")
    return "\n".join(lines)


def main() -> None:
    from bench.bench_monitor import POINTS
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engines", nargs="*", default=[p[0] for p in POINTS])
    ap.add_argument("--top", type=int, default=40)
    ap.add_argument("--json", type=Path, default=None, help="also write every event here")
    a = ap.parse_args()
    r = measure(a.engines)
    print(summary(r, a.top))
    if a.json:
        a.json.write_text(json.dumps(r, indent=1))


if __name__ == "__main__":
    main()
