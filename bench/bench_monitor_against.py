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
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.bench_monitor import POINTS, SEED

_PASS = """
import json, os, pickle, sys, time, types
sys.path.insert(0, os.getcwd())
import numpy as np
import bench.bench_monitor as bm
from frictionwatch.core.model.engine import load_engine
from frictionwatch.service.pipeline import run as run_records
if sys.argv[3] == "cpu":
    bm.time = types.SimpleNamespace(perf_counter=time.thread_time)  # the pass's clock: this thread's CPU time
data = pickle.load(open(sys.argv[1], "rb"))
out = {}
for name, (info, records, short_info, short_records) in data.items():
    spec = load_engine(name)
    for _ in run_records(spec, short_info, short_records):  # numba cache load and first calls
        pass
    sim = types.SimpleNamespace(info=info, records=records)
    means = []
    for _ in range(int(sys.argv[2])):
        rows = bm.pipeline_pass(spec, sim)["rows"]
        means.append(float((rows[:, 0] + rows[:, 2]).mean()))
    out[name] = means
print("@@" + json.dumps(out))
"""


def _records(cycles: int, path: Path) -> None:
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.plant.simulate import simulate

    data = {}
    for name, rpm, load in POINTS:
        spec = load_engine(name)
        sim, short = simulate(spec, rpm, load, cycles, seed=SEED), simulate(spec, rpm, load, 12, seed=SEED + 1)
        data[name] = (sim.info, list(sim.records), short.info, list(short.records))
    path.write_bytes(pickle.dumps(data))


def _one(checkout: Path, records: Path, passes: int, clock: str) -> dict:
    # one NUMBA_CACHE_DIR may serve both: numba keys its cache by each kernel's source path
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    proc = subprocess.run([str(checkout / ".venv" / "bin" / "python"), "-c", _PASS, str(records), str(passes), clock],
                          capture_output=True, text=True, env=env, cwd=checkout, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"{checkout}: {proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else 'failed'}")
    return json.loads(proc.stdout.split("@@", 1)[1])


def compare(this: Path, base: Path, repeat: int, passes: int, cycles: int) -> dict:
    out: dict = {"uptime_before": subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()}
    with tempfile.TemporaryDirectory() as tmp:
        records = Path(tmp) / "records.pkl"
        _records(cycles, records)
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
    args = ap.parse_args()
    r = compare(Path(__file__).resolve().parents[1], args.base.resolve(), args.repeat, args.passes, args.cycles)
    print(f"uptime: {r['uptime_before']} ... {r['uptime_after']}")
    for clock in ("wall", "cpu"):
        print(f"\nend to end, ms per cycle ({clock} clock): base | this | base/this median (min-max over repeats)")
        for name, e in r[clock].items():
            print(f"  {name:11s} {e['base_ms']:7.3f} ({e['base_x_real_time']:5.1f}x) | {e['this_ms']:7.3f} "
                  f"({e['this_x_real_time']:5.1f}x) | {e['base_over_this']:.2f} ({e['ratio_range'][0]:.2f}-"
                  f"{e['ratio_range'][1]:.2f})")
    if args.out:
        args.out.write_text(json.dumps(r, indent=1))


if __name__ == "__main__":
    sys.exit(main())
