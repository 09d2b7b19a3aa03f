"""The running calibration watches alone (core.monitor.pipeline.STAGES after the monitor: the TDC watch, the gain watch), per cycle,
against another checkout, and the same states from both (issue 26 item 7; design note 51).

    python -m bench.bench_watches [--base ../base] [--repeat 6] [--replays 5] [--cycles 220] [--profile]

For k9k-4cyl (4000 rpm) and genset-v20 (1500 rpm) at full load (bench.bench_monitor's points, seed 1) the records
are simulated and run through this checkout's one pipeline (CyclePipeline) once, each such stage's input kept
(StageInput: the spec, the calibration, the cycle as the monitor got it, the static twist). Each measurement is a
fresh process of one checkout (its own .venv and numba cache, its own frictionwatch; this file's code for the loop)
that replays every stage's ``update`` over those same inputs from its initial state ``replays`` times, each call
timed by the thread's CPU clock, the minimum per cycle kept. Reported per stage: us per cycle on the cycles that
close no window (the per-cycle path), the window closes (us each), and the sum per cycle at one close a
``WINDOW_CYCLES`` (100); base and this alternated A B B A ..., base / this the median (min-max) over the repeats.

Before any timing, both sides' stage states after every window close, at the end and after ``close`` (the open
window read) are compared (numbers within rtol 1e-12, bench.bench_monitor_against.differences; each side on a
fresh numba cache it filled in a first run): a speed-up is only claimed for the same readings. ``--profile`` adds a
cProfile of this checkout's replay (own and cumulative us per cycle of the top functions).
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # one core, as bench_monitor

import argparse  # noqa: E402
import inspect  # noqa: E402
import pickle  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
POINTS = (("k9k-4cyl", 4000.0, 1.0), ("genset-v20", 1500.0, 1.0))
SEED = 1
CYCLES = 220  # two TDC windows (100 cycles each) after the first pair


def captured_inputs(name: str, info, records) -> tuple[list, object]:
    """(each analysed cycle's StageInput, the pipeline) of the one pipeline over ``records`` (this process's
    frictionwatch)."""
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.monitor.pipeline import AFTER_MONITOR, CyclePipeline
    from frictionwatch.service.pipeline import assembled_cycles

    spec = load_engine(name)
    cycles, _ = assembled_cycles(spec, info, records)
    pipe = CyclePipeline(spec)
    inputs = []
    stages = pipe.stage_order

    class Tap:  # the pipeline's stages after the monitor, each input kept
        def __init__(self, stage):
            self.stage, self.name, self.place = stage, stage.name, stage.place

        def initial(self, spec):
            return self.stage.initial(spec)

        def update(self, state, inp):
            if not inputs or inputs[-1] is not inp:
                inputs.append(inp)
            return self.stage.update(state, inp)

    pipe.stage_order = tuple(Tap(s) if s.place == AFTER_MONITOR else s for s in stages)
    for c in cycles:
        pipe.process(c)
    pipe.stage_order = stages
    return inputs, pipe


def replay(stage, inputs: list, clock=time.thread_time) -> tuple[list, np.ndarray, list]:
    """(states after each window close and the last, seconds per call, the closing calls' positions) of ``stage``
    over ``inputs`` from its initial state."""
    # a checkout before design note 148: ``initial()`` without the spec, ``update`` giving the state itself
    old = len(inspect.signature(stage.initial).parameters) == 0
    state = stage.initial() if old else stage.initial(inputs[0].spec)
    kept, closes = [], []
    dt = np.empty(len(inputs))
    for i, inp in enumerate(inputs):
        before = state
        t0 = clock()
        state = stage.update(state, inp) if old else stage.update(state, inp).state
        dt[i] = clock() - t0
        if getattr(state, "last", None) is not getattr(before, "last", None):
            kept.append(state)
            closes.append(i)
    return kept + [state], dt, closes


def worker(inputs_path: Path, replays: int, out: Path, check: bool, profile: bool) -> None:
    """One checkout's measurement (module doc) on the stage inputs in ``inputs_path``, written to ``out``."""
    from frictionwatch.core.monitor.pipeline import STAGES, StageInput

    # the stages after the monitor (a checkout before design note 148 has no ``place``: its STAGES are only those)
    watches = tuple(s for s in STAGES if getattr(s, "place", "after_monitor") == "after_monitor")

    data = pickle.loads(inputs_path.read_bytes())
    result: dict = {}
    for name, rows in data.items():
        inputs = [StageInput(spec, cal, cycle, None, twist) for spec, cal, cycle, twist in rows]
        row: dict = {"cycles": len(inputs)}
        for stage in watches:
            best, closes = None, []
            for _ in range(replays):
                states, dt, closes = replay(stage, inputs)
                best = dt if best is None else np.minimum(best, dt)
            per = np.delete(best, closes)
            row[stage.name] = {"per_cycle_us": 1e6 * float(per.mean()), "per_cycle_median_us": 1e6 * float(
                np.median(per)), "closes_us": [1e6 * float(best[i]) for i in closes]}
            if check:
                from bench.bench_monitor_against import plain

                close = getattr(stage, "close", None)
                end = close(states[-1], inputs[-1].spec, inputs[-1].calibration) if close is not None else None
                row[stage.name]["states"] = plain(states + [end])
        if profile:
            import cProfile
            import pstats

            prof = cProfile.Profile()
            for stage in watches:
                prof.enable()
                replay(stage, inputs)
                prof.disable()
            top = sorted(pstats.Stats(prof).stats.items(), key=lambda kv: kv[1][2], reverse=True)[:25]
            row["profile"] = [(f"{Path(p).name}:{ln}({fn})", round(1e6 * tt / len(inputs), 2),
                               round(1e6 * ct / len(inputs), 2), round(nc / len(inputs), 2))
                              for (p, ln, fn), (_, nc, tt, ct, _) in top]
        result[name] = row
    out.write_bytes(pickle.dumps(result))


def _run(checkout: Path, records: Path, replays: int, check: bool, profile: bool, tmp: Path,
         cache: Path | None = None) -> dict:
    out = tmp / f"out_{checkout.name}.pkl"
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
               PYTHONPATH=str(ROOT))  # this file's bench package; frictionwatch is the checkout's own (its venv)
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = str(cache)
    cmd = [str(checkout / ".venv" / "bin" / "python"), "-m", "bench.bench_watches", "--worker", str(records), str(out),
           "--replays", str(replays)] + (["--check"] if check else []) + (["--profile"] if profile else [])
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"{checkout}: {proc.stderr.strip()[-2000:]}")
    return pickle.loads(out.read_bytes())


def _summary(row: dict) -> dict:
    out = {}
    for k, v in row.items():
        if isinstance(v, dict) and "per_cycle_us" in v:
            close = float(np.mean(v["closes_us"])) if v["closes_us"] else 0.0
            out[k] = {"per_cycle_us": v["per_cycle_us"], "close_us": close,
                      "amortised_us": v["per_cycle_us"] + close / 100.0}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, default=None)
    ap.add_argument("--repeat", type=int, default=6)
    ap.add_argument("--replays", type=int, default=5)
    ap.add_argument("--cycles", type=int, default=CYCLES)
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--check", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--worker", nargs=2, type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker is not None:
        sys.path.insert(0, str(ROOT))
        worker(args.worker[0], args.replays, args.worker[1], args.check, args.profile)
        return 0
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.plant.simulate import simulate

    from bench.bench_monitor_against import differences

    up = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    print(f"uptime: {up}")
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        records = tmp / "inputs.pkl"
        data = {}
        for name, rpm, load in POINTS:
            sim = simulate(load_engine(name), rpm, load, args.cycles, seed=SEED)
            inputs, _ = captured_inputs(name, sim.info, list(sim.records))
            data[name] = [(i.spec, i.calibration, i.cycle, i.twist) for i in inputs]
        records.write_bytes(pickle.dumps(data))  # this checkout's monitor's inputs, the same for both sides' watches
        sides = [("this", ROOT)] + ([("base", args.base.resolve())] if args.base else [])
        if args.base:
            # a fresh numba cache each, filled by a first run, then the run compared loading from it (as
            # bench_monitor_against: a compiling run and a loading one may differ in the last digits)
            checked = {}
            for label, path in sides:
                for _ in range(2):
                    checked[label] = _run(path, records, 1, True, False, tmp, tmp / f"cache_{label}")
            for name in checked["this"]:
                a, b = checked["base"][name], checked["this"][name]
                diffs, n = [], 0
                for key in ("tdc_watch", "gain_watch"):
                    d, m = differences(a[key]["states"], b[key]["states"], f"{name}.{key}")
                    diffs, n = diffs + d, n + m
                print(f"same states, {name}: {a['cycles']} cycles, {n} numbers compared (rtol 1e-12): "
                      + ("equal" if not diffs else f"{len(diffs)} DIFFER, e.g. " + "; ".join(diffs[:5])))
                if diffs:
                    return 1
        runs: dict[str, list[dict]] = {label: [] for label, _ in sides}
        for i in range(args.repeat):
            order = sides if i % 2 == 0 else sides[::-1]
            for label, path in order:
                runs[label].append(_run(path, records, args.replays, False, args.profile and label == "this", tmp))
    up2 = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    print(f"uptime after: {up2}")
    print("us per cycle by CPU clock (min over replays), median over repeats: per-cycle path | window close each | "
          "amortised (per-cycle + close / 100)")
    for name, _, _ in POINTS:
        for stage in ("tdc_watch", "gain_watch"):
            line = f"  {name:11s} {stage:10s}"
            meds = {}
            for label in runs:
                s = [_summary(r[name])[stage] for r in runs[label]]
                meds[label] = {k: statistics.median(x[k] for x in s) for k in s[0]}
                m = meds[label]
                line += f" {label}: {m['per_cycle_us']:7.2f} | {m['close_us']:9.1f} | {m['amortised_us']:7.2f};"
            if "base" in runs:
                for k in ("per_cycle_us", "close_us", "amortised_us"):
                    ratios = [_summary(b[name])[stage][k] / max(_summary(t[name])[stage][k], 1e-9)
                              for b, t in zip(runs["base"], runs["this"], strict=True)]
                    line += f" base/this {k.split('_')[0]} {statistics.median(ratios):.2f} ({min(ratios):.2f}-" \
                            f"{max(ratios):.2f})"
            print(line)
    if args.profile:
        for name, _, _ in POINTS:
            print(f"\ncProfile of the replay, {name} (own us per cycle, cum us per cycle, calls per cycle):")
            for fn, own, cum, calls in runs["this"][0][name]["profile"]:
                print(f"  {own:8.2f} {cum:8.2f} {calls:6.2f}  {fn}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
