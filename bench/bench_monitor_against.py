"""The monitor bench's timed pass against another checkout, side by side in one run (docs: quiet-bench.md).

    python -m bench.bench_monitor_against --base ../base [--repeat 6] [--passes 3] [--cycles 120] [--out F]

The records of bench.bench_monitor's points (deutz-1cyl 3000 rpm, k9k-4cyl 4000 rpm, genset-v20 1500 rpm, full load,
seed 1; a 12-cycle warm-up stream, seed 2) are simulated once here and given to both checkouts. Each measurement is
a fresh process of one checkout (its own .venv and numba cache, run from its own directory), alternated base/this
A B B A ...: it warms on the short stream, then runs bench.bench_monitor.pipeline_pass (the product path,
EnginePipeline.outcomes per record: assembly, the model's view, the monitor, the running watches) ``passes`` times
per engine, timed by wall clock (the bench's own figure) and, in another process, by the thread's CPU time (what a
shared box's descheduling does not move). Reported: the median of every pass's mean end-to-end ms per cycle, its
real-time factor, and the median (min-max) over the repeats of base / this. Quote ``uptime`` with any absolute
figure; the ratio is what a shared box can say.

Before any timing, the same records go once through each checkout's one pipeline (service.pipeline.run) and every
cycle's outcome is compared: skipped or not and why, the flags (equal), and every number of the result, nested
estimates, sensor health and ring indicators included (float arrays within rtol ``RTOL``, NaN where NaN; ints and
strings equal). A difference is listed by cycle and field and the run stops (exit 1): a speed-up is only claimed
for code that gives the same figures. ``--check-only`` stops after the check. Each side fills a fresh numba cache
(a compile of its own, ~1 min each) and is compared on a run loading from it: a run that compiled its kernels and
one that loaded them give the same code's figures other last digits (see ``same_outcomes``).
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from bench.bench_monitor import POINTS, SEED, warm_up

RTOL = 1e-12  # what "the same figures" means between two checkouts (issue 26 item 7: rtol 1e-12 or bit-identical)

_PASS = """
import json, os, pickle, sys, time, types
sys.path.insert(0, os.getcwd())
import numpy as np
import bench.bench_monitor as bm
from frictionwatch.core.model.engine import load_engine
from frictionwatch.service.pipeline import EnginePipeline
if sys.argv[3] == "cpu":
    bm.time = types.SimpleNamespace(perf_counter=time.thread_time)  # the pass's clock: this thread's CPU time
data = pickle.load(open(sys.argv[1], "rb"))
out = {}
for name, (info, records, short_info, short_records) in data.items():
    spec = load_engine(name)
    warm_up(spec, types.SimpleNamespace(info=short_info, records=short_records))  # numba cache, first calls
    sim = types.SimpleNamespace(info=info, records=records)
    means = []
    for _ in range(int(sys.argv[2])):
        rows = bm.pipeline_pass(spec, sim)["rows"]
        means.append(float((rows[:, 0] + rows[:, 2]).mean()))
    out[name] = means
print("@@" + json.dumps(out))
"""


_OUTCOMES = """
import dataclasses, pickle, sys
import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.service.pipeline import run
data = pickle.load(open(sys.argv[1], "rb"))
out = {name: [plain(o) for o in run(load_engine(name), info, records)] for name, (info, records, _, _) in data.items()}
pickle.dump(out, open(sys.argv[2], "wb"))
"""  # run by each checkout's python with ``plain`` (below) put in front: the base need not have it


def plain(obj):
    """``obj`` (an outcome, a result and what it holds) as builtins and numpy arrays only: dataclasses and named
    tuples as dicts of their fields (a cached property not yet asked for is not a field), so two checkouts' results
    compare without importing either's classes."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {"<type>": type(obj).__name__, **{f.name: plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}}
    if isinstance(obj, tuple) and hasattr(obj, "_fields"):
        return {"<type>": type(obj).__name__, **{k: plain(v) for k, v in zip(obj._fields, obj, strict=True)}}
    if isinstance(obj, (list, tuple)):
        return [plain(v) for v in obj]
    if isinstance(obj, dict):
        return {k: plain(v) for k, v in obj.items()}
    if isinstance(obj, np.ndarray | np.generic) or obj is None or isinstance(obj, (bool, int, float, complex, str)):
        return obj
    if hasattr(obj, "__dict__") and not isinstance(obj, type) and not callable(obj) and not hasattr(obj, "_value_"):
        return {"<type>": type(obj).__name__, **{k: plain(v) for k, v in vars(obj).items()}}
    return repr(obj)  # a class, a function, an enum member: compared by what it prints


def differences(a, b, where: str = "", rtol: float = RTOL) -> tuple[list[str], int]:
    """(each place where ``a`` and ``b`` (``plain`` trees) differ, the count of numbers compared): numbers within
    ``rtol`` (NaN equal to NaN; atol 0: a zero stays a zero), everything else equal."""
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            return [f"{where}: fields {sorted(set(a) ^ set(b))} in one only"], 0
        out, n = [], 0
        for k in a:
            d, m = differences(a[k], b[k], f"{where}.{k}", rtol)
            out += d
            n += m
        return out, n
    if isinstance(a, list) and isinstance(b, list) and not _numeric(a):
        if len(a) != len(b):
            return [f"{where}: {len(a)} against {len(b)} items"], 0
        out, n = [], 0
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            d, m = differences(x, y, f"{where}[{i}]", rtol)
            out += d
            n += m
        return out, n
    if _numeric(a) and _numeric(b):
        x, y = np.asarray(a), np.asarray(b)
        if x.shape != y.shape or x.dtype.kind != y.dtype.kind:
            return [f"{where}: shape/kind {x.shape} {x.dtype} against {y.shape} {y.dtype}"], 0
        if x.dtype.kind in "fc":
            try:
                np.testing.assert_allclose(y, x, rtol=rtol, atol=0.0, equal_nan=True)
            except AssertionError:
                nan_x, nan_y = np.isnan(x), np.isnan(y)
                if np.any(nan_x != nan_y):
                    return [f"{where}: NaN in one only at {int(np.sum(nan_x != nan_y))} of {x.size}"], x.size
                both = ~nan_x
                with np.errstate(divide="ignore", invalid="ignore"):
                    rel = float(np.max(np.abs(y[both] - x[both]) / np.abs(x[both])))
                return [f"{where}: max relative difference {rel:.3g}"], x.size
            return [], x.size
        return ([] if np.array_equal(x, y) else [f"{where}: {x!r} against {y!r}"]), x.size
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):  # an array against something else (None, a list)
        return [f"{where}: {type(a).__name__} against {type(b).__name__}"], 0
    return ([] if a == b else [f"{where}: {a!r} against {b!r}"]), 0


def _numeric(v) -> bool:
    if isinstance(v, np.ndarray | np.generic) or (isinstance(v, (int, float, complex)) and not isinstance(v, bool)):
        return True
    return isinstance(v, list) and len(v) > 0 and all(
        isinstance(e, (int, float, complex)) and not isinstance(e, bool) for e in v)


def same_outcomes(this: Path, base: Path, records: Path) -> dict:
    """Every cycle's outcome from both checkouts on the same records, compared (module doc): per engine the cycles,
    the numbers compared and the differences (empty: the same figures)."""
    trees = {}
    for label, checkout in (("base", base), ("this", this)):
        out = records.with_name(f"outcomes_{label}.pkl")
        # a fresh numba cache each, filled by a first run, then the run compared loading from it (as a served engine
        # does): a run that compiled its kernels in-process gives other last digits than one that loaded the same
        # kernels from the cache (up to ~6e-10 relative, e.g. friction_torque_balance, chi2_reduced), while two
        # compiling runs agree exactly and so do two loading ones; a shared or older cache would show differences
        # the code does not make
        env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
                   NUMBA_CACHE_DIR=str(records.with_name(f"numba_cache_{label}")))
        script = _OUTCOMES.replace("\nfrom frictionwatch", "\n" + inspect.getsource(plain) + "\nfrom frictionwatch", 1)
        for _ in range(2):  # fill the cache, then load from it
            proc = subprocess.run([str(checkout / ".venv" / "bin" / "python"), "-c", script, str(records), str(out)],
                                  capture_output=True, text=True, env=env, cwd=checkout, check=False)
            if proc.returncode != 0:
                raise RuntimeError(f"{checkout}: {proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else 'failed'}")
        trees[label] = pickle.loads(out.read_bytes())
    report = {}
    for name in trees["base"]:
        diffs, n = differences(trees["base"][name], trees["this"][name], name)
        report[name] = {"cycles": len(trees["base"][name]), "numbers": n, "differences": diffs}
    return report


def _records(cycles: int, path: Path) -> None:
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.plant.simulate import simulate

    data = {}
    for name, rpm, load in POINTS:
        spec = load_engine(name)
        sim, short = simulate(spec, rpm, load, cycles, seed=SEED), simulate(spec, rpm, load, 12, seed=SEED + 1)
        data[name] = (sim.info, list(sim.records), short.info, list(short.records))
    path.write_bytes(pickle.dumps(data))


def _one(checkout: Path, records: Path, passes: int, clock: str, env_extra: dict | None = None) -> dict:
    # this bench's warm-up (bench_monitor.warm_up) in both checkouts: the base's bench may warm up otherwise
    script = _PASS.replace("\nif sys.argv[3]", "\n" + inspect.getsource(warm_up) + "\nif sys.argv[3]", 1)
    # one NUMBA_CACHE_DIR may serve both: numba keys its cache by each kernel's source path (env_extra: other
    # variables, bench/compile_opt.py's NUMBA_OPT and its own cache folder for each setting)
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
               **(env_extra or {}))
    proc = subprocess.run([str(checkout / ".venv" / "bin" / "python"), "-c", script, str(records), str(passes), clock],
                          capture_output=True, text=True, env=env, cwd=checkout, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"{checkout}: {proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else 'failed'}")
    return json.loads(proc.stdout.split("@@", 1)[1])


def compare(this: Path, base: Path, repeat: int, passes: int, cycles: int, check_only: bool = False,
            differ_ok: bool = False) -> dict:
    out: dict = {"uptime_before": subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()}
    with tempfile.TemporaryDirectory() as tmp:
        records = Path(tmp) / "records.pkl"
        _records(cycles, records)
        out["same"] = same_outcomes(this, base, records)
        if check_only or (any(e["differences"] for e in out["same"].values()) and not differ_ok):
            return out
        for clock in ("wall", "cpu"):
            runs: dict[str, list[dict]] = {"base": [], "this": []}
            for i in range(repeat):
                order = (("base", base), ("this", this)) if i % 2 == 0 else (("this", this), ("base", base))
                for label, checkout in order:
                    runs[label].append(_one(checkout, records, passes, clock))
            table = {}
            for name, rpm, _ in POINTS:
                cycle_ms = 120.0 / rpm * 1e3
                med = {k: statistics.median(v for r in runs[k] for v in r[name]) for k in runs}
                ratios = [statistics.median(b[name]) / statistics.median(t[name])
                          for b, t in zip(runs["base"], runs["this"], strict=True)]
                table[name] = {"base_ms": round(med["base"], 4), "this_ms": round(med["this"], 4),
                               "base_x_real_time": round(cycle_ms / med["base"], 1),
                               "this_x_real_time": round(cycle_ms / med["this"], 1),
                               "base_over_this": round(statistics.median(ratios), 3),
                               "ratio_range": [round(min(ratios), 3), round(max(ratios), 3)],
                               "pass_means_ms": {k: [round(v, 4) for r in runs[k] for v in r[name]] for k in runs}}
            out[clock] = table
    out["uptime_after"] = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True, help="the other checkout (with its own .venv)")
    ap.add_argument("--repeat", type=int, default=6)
    ap.add_argument("--passes", type=int, default=3)
    ap.add_argument("--cycles", type=int, default=120)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--check-only", action="store_true", help="compare the figures, no timing")
    ap.add_argument("--differ-ok", action="store_true",
                    help="the two are meant to differ (a change of behaviour, not only of speed): print the timing "
                         "anyway, after the differences")
    args = ap.parse_args()
    r = compare(Path(__file__).resolve().parents[1], args.base.resolve(), args.repeat, args.passes, args.cycles,
                args.check_only, args.differ_ok)
    if args.out:
        args.out.write_text(json.dumps(r, indent=1))
    for name, e in r["same"].items():
        print(f"same figures, {name}: {e['cycles']} cycles, {e['numbers']} numbers compared (rtol {RTOL:g}): "
              + ("equal" if not e["differences"] else f"{len(e['differences'])} DIFFER, e.g. "
                 + "; ".join(e["differences"][:5])))
    if any(e["differences"] for e in r["same"].values()) and not args.differ_ok:
        return 1
    if args.check_only:
        return 0
    print(f"uptime: {r['uptime_before']} ... {r['uptime_after']}")
    for clock in ("wall", "cpu"):
        print(f"\nend to end, ms per cycle ({clock} clock): base | this | base/this median (min-max over repeats)")
        for name, e in r[clock].items():
            print(f"  {name:11s} {e['base_ms']:7.3f} ({e['base_x_real_time']:5.1f}x) | {e['this_ms']:7.3f} "
                  f"({e['this_x_real_time']:5.1f}x) | {e['base_over_this']:.2f} ({e['ratio_range'][0]:.2f}-"
                  f"{e['ratio_range'][1]:.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
