"""Long simulator runs (issue 29 item 4): genset-v20 at 1500 rpm in cycles per CPU second, against another checkout
in the same run, and a run made in two segments (two processes chained by a checkpoint) against the unsplit run.

    python -m bench.bench_sim_long [--base ../base] [--cycles 60] [--repeat 3] [--split-cycles 24] [--out F]

Speed: each measurement is a fresh process of one checkout (its own .venv), alternated base/this A B A B: CPU time
(time.process_time) of a short and a long run in that process, so the marginal cost per cycle excludes start-up,
compile-cache loading and the settling (4x real time at 1500 rpm = 50 cycles per CPU second). The ratio's spread is
over the repeats; quote ``uptime`` with any absolute figure (docs/quiet-bench.md).

Segments: cycles [0, k) in one process, which writes its checkpoint; cycles [k, n) in another, which resumes from it;
their records and truth against the unsplit run in a third: identical (to the bit) or the largest differences.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

RPM, LOAD, SEED, SHORT = 1500.0, 1.0, 0, 8
CYCLES_PER_S_4X = 4 * RPM / 120.0

_SPEED = """
import json, time
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import simulate
spec = load_engine("genset-v20")
simulate(spec, {rpm}, {load}, 1, {seed})  # cache load, first-call dispatch
t = time.process_time(); simulate(spec, {rpm}, {load}, {short}, {seed}); t_short = time.process_time() - t
t = time.process_time(); simulate(spec, {rpm}, {load}, {long}, {seed}); t_long = time.process_time() - t
print(json.dumps({{"short_cpu_s": t_short, "long_cpu_s": t_long}}))
"""

_SEGMENT = """
import pickle, sys
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import start_simulation
cycles, split, chunk, path, part = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], sys.argv[5]
sim = start_simulation(load_engine("genset-v20"), {rpm}, {load}, cycles, {seed})
if part == "2":
    sim.resume(pickle.load(open(path + ".ck", "rb")))
chunks = []
for c in sim.chunks(chunk_cycles=chunk):
    chunks.append((c.records, c.cycles))
    if part == "1" and sum(len(e) for _, e in chunks) == split:
        pickle.dump(sim.checkpoint(), open(path + ".ck", "wb"))
        break
pickle.dump({{"chunks": chunks, "truth": sim.truth}}, open(path + "." + part, "wb"))
"""


def _python(checkout: Path) -> str:
    return str(checkout / ".venv" / "bin" / "python")


def _speed(checkout: Path, cycles: int) -> float:
    """Marginal genset-v20 cycles per CPU second of one fresh process of ``checkout``."""
    code = _SPEED.format(rpm=RPM, load=LOAD, seed=SEED, short=SHORT, long=SHORT + cycles)
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    if "NUMBA_CACHE_DIR" in env:  # one compile cache per checkout
        env["NUMBA_CACHE_DIR"] = f"{env['NUMBA_CACHE_DIR']}-{checkout.name}"
    out = subprocess.run([_python(checkout), "-c", code], capture_output=True, text=True, env=env, check=True,
                         cwd=checkout)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    return cycles / (r["long_cpu_s"] - r["short_cpu_s"])


def speed(this: Path, base: Path | None, cycles: int, repeat: int) -> dict:
    runs: dict[str, list[float]] = {"this": [], "base": []}
    for _ in range(repeat):
        for name, checkout in (("base", base), ("this", this)):
            if checkout is not None:
                runs[name].append(_speed(checkout, cycles))
    out = {"cycles_marginal": cycles, "repeat": repeat,
           "this_cycles_per_cpu_s": [round(x, 1) for x in runs["this"]],
           "real_time_factor_this": round(float(np.median(runs["this"])) / (RPM / 120.0), 2),
           "target_cycles_per_cpu_s": CYCLES_PER_S_4X}
    if runs["base"]:
        ratios = np.array(runs["this"]) / np.array(runs["base"])
        out.update(base_cycles_per_cpu_s=[round(x, 1) for x in runs["base"]],
                   ratio_median=round(float(np.median(ratios)), 2),
                   ratio_spread=[round(float(ratios.min()), 2), round(float(ratios.max()), 2)])
    return out


def _records_diff(a: list, b: list) -> dict:
    """Largest differences of two record lists of the same types in the same order (ticks and values)."""
    if [type(r) for r in a] != [type(r) for r in b]:
        return {"same_types": False}
    tick = value = 0.0
    for x, y in zip(a, b):
        for f in ("ticks", "t0_ticks", "values", "torque", "power"):
            if hasattr(y, f):
                d = np.abs(np.asarray(getattr(x, f), dtype=float) - np.asarray(getattr(y, f), dtype=float))
                if d.size:
                    if "tick" in f:
                        tick = max(tick, float(d.max()))
                    else:
                        value = max(value, float(d.max()))
    return {"same_types": True, "max_tick_diff": tick, "max_value_diff": value}


def segments(this: Path, cycles: int, split: int, chunk: int) -> dict:
    code = _SEGMENT.format(rpm=RPM, load=LOAD, seed=SEED)
    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "run")
        for part, n_split in (("0", 0), ("1", split), ("2", split)):  # 0: the unsplit run
            subprocess.run([_python(this), "-c", code, str(cycles), str(n_split), str(chunk), path, part],
                           check=True, cwd=this)
        whole, first, second = (pickle.load(open(f"{path}.{p}", "rb")) for p in "012")
    flat = lambda parts: [r for p in parts for c in p["chunks"] for r in c[0]]  # noqa: E731
    entries = lambda parts: [e for p in parts for c in p["chunks"] for e in c[1]]  # noqa: E731
    rec = _records_diff(flat([first, second]), flat([whole]))
    same_truth = (entries([first, second]) == entries([whole])) and second["truth"] == whole["truth"]
    return {"cycles": cycles, "segment_1_cycles": split, "chunk_cycles": chunk, "processes": 3, **rec,
            "records_identical": rec.get("max_tick_diff") == 0.0 and rec.get("max_value_diff") == 0.0,
            "truth_identical": bool(same_truth)}


def run() -> dict:
    """`make bench` (bench/run.py): this checkout alone, one repeat, and the two-segment check."""
    this = Path(__file__).resolve().parents[1]
    return {"speed": speed(this, None, 40, 1), "segments": segments(this, 16, 8, 4)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, help="another checkout with its own .venv (docs/quiet-bench.md)")
    ap.add_argument("--cycles", type=int, default=60)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--split-cycles", type=int, default=24, help="the unsplit run's cycles (cut at half)")
    ap.add_argument("--out", type=Path, help="also write the figures here (bench/results/sim_long.json is the quoted run)")
    a = ap.parse_args()
    this = Path(__file__).resolve().parents[1]
    uptime = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    out = {"uptime_before": uptime, "speed": speed(this, a.base.resolve() if a.base else None, a.cycles, a.repeat),
           "segments": segments(this, a.split_cycles, a.split_cycles // 2, 4),
           "uptime_after": subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()}
    json.dump(out, sys.stdout, indent=1)
    print()
    if a.out:
        a.out.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
