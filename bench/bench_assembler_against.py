"""The cycle assembler alone against another checkout: every Cycle the same, then its CPU time per cycle, alternated.

    python -m bench.bench_assembler_against --base ../base [--repeat 5] [--passes 5] [--cycles 120] [--check-only]

Streams (simulated once here, given to both checkouts): bench.bench_monitor's points (deutz-1cyl 3000 rpm, k9k-4cyl
4000 rpm, genset-v20 1500 rpm, full load, seed 1); genset-v20 with its pressure as one block per cylinder
(bench.common.as_blocks: how CAN / DAQ drivers deliver it); genset-v20 with a free-end wheel
(bench/genset-v20-two-wheels.toml, half the cycles); and '-faulty' copies of k9k, genset-v20 and its blocks in which
records are lost, repeated or reversed (``faulty``), so skips, refusals and resyncs are compared too.

Check (before any timing): each checkout's own assembler (service.pipeline.cycle_assembler, the pipeline's) over
every stream; every field of every Cycle (arrays: dtype, shape, contiguity and every value, NaN where NaN; the second
wheel's edges likewise) and the assembler's counters (skipped, truncated, stats, dropped, next_index) must be equal,
else the differences are listed and the run stops (exit 1).

Timing: each measurement is a fresh process of one checkout (its own .venv, from its own directory): one untimed
pass (numba cache, first calls), then ``passes`` passes of ``service.pipeline.assembled_cycles`` (the pipeline's
assembler over a stream, nothing around it) over each stream timed by the thread's CPU time, the median
pass's ms per cycle met kept (assembled or skipped: a faulty stream's skips cost too). Per repeat the order is base, this, base again: base / this is the figure,
base / base (identical code, two processes) the control that shows what noise alone moves. Reported: the median
(min-max) of each ratio over the repeats, and ``uptime`` before and after (quiet-bench.md: only ratios from one run).
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

TWO_WHEELS = Path(__file__).with_name("genset-v20-two-wheels.toml")

_CHILD = r"""
import dataclasses, json, pickle, sys, time
from pathlib import Path
from frictionwatch.core.model.engine import load_engine
from frictionwatch.service.pipeline import assembled_cycles, cycle_assembler
data = pickle.load(open(sys.argv[1], "rb"))
def assemble(spec, info, records):  # the check reads the pipeline's assembler's counters too (as bench.common does)
    asm = cycle_assembler(spec, info)
    out = [c for r in records for c in asm.feed(r)]
    return out + asm.flush(), asm
specs = {k: load_engine(Path(e) if e.endswith(".toml") else e) for k, (e, _, _) in data.items()}
if sys.argv[2] == "check":
    res = {}
    for k, (_, info, records) in data.items():
        cycles, asm = assemble(specs[k], info, records)
        res[k] = {"cycles": cycles, "counters": (dict(asm.skipped), dict(asm.truncated), dict(asm.stats),
                                                   dict(asm.dropped()), asm.next_index)}
    pickle.dump(res, open(sys.argv[3], "wb"))
else:
    out = {}
    for k, (_, info, records) in data.items():
        assembled_cycles(specs[k], info, records)
        ms = []
        for _ in range(int(sys.argv[3])):
            t0 = time.thread_time()
            cycles, skipped = assembled_cycles(specs[k], info, records)  # the pipeline's assembly, nothing around it
            ms.append((time.thread_time() - t0) * 1e3 / max(len(cycles) + sum(skipped.values()), 1))
            del cycles
        out[k] = sorted(ms)[len(ms) // 2]
    print("@@" + json.dumps(out))
"""


def faulty(records: list) -> list:
    """A stream with faults a bus or a driver makes: every 97th record lost (of pressure blocks every 1000th), every
    13th load reading and every 11th pressure record sent twice (refused, counted), every 10th tooth batch in reverse
    order (its edges refused: a data gap)."""
    from frictionwatch.core.types import LoadSample, PressureBlock, PressureFrame, ToothBatch

    out, seen = [], {LoadSample: 0, PressureFrame: 0, PressureBlock: 0, ToothBatch: 0}
    for i, r in enumerate(records):
        kind = type(r)
        k = seen[kind] = seen.get(kind, 0) + 1
        if (i % 97 == 50 and kind is not PressureBlock) or (kind is PressureBlock and k % 1000 == 500):
            continue  # (a block is one cylinder's: one lost in 97 would leave no cycle whole, nothing to compare)
        if (kind is LoadSample and k % 13 == 0) or (kind in (PressureFrame, PressureBlock) and k % 11 == 0):
            out += [r, r]
        elif kind is ToothBatch and k % 10 == 0:
            out.append(ToothBatch(r.ticks[::-1].copy()))
        else:
            out.append(r)
    return out


def streams(cycles: int) -> dict:
    """{stream: (engine name or toml path, AcquisitionInfo, records)} (module doc)."""
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.plant.simulate import simulate

    from bench.common import as_blocks

    data = {}
    for name, rpm, load in POINTS:
        sim = simulate(load_engine(name), rpm, load, cycles, seed=SEED)
        data[name] = (name, sim.info, list(sim.records))
    name, info, records = data["genset-v20"]
    data["genset-v20-blocks"] = (name, info, as_blocks(records))
    sim = simulate(load_engine(TWO_WHEELS), 1500.0, 1.0, max(cycles // 2, 4), seed=SEED, second_wheel=True)
    data["genset-v20-two-wheels"] = (str(TWO_WHEELS.resolve()), sim.info, list(sim.records))
    for k in ("k9k-4cyl", "genset-v20", "genset-v20-blocks"):
        e, info, records = data[k]
        data[k + "-faulty"] = (e, info, faulty(records))
    return data


def differences(a, b, where: str) -> list[str]:
    """Where two assembled values (Cycles, their fields, counters) are not the same, bit for bit."""
    import dataclasses

    import numpy as np

    if type(a).__name__ != type(b).__name__:
        return [f"{where}: {type(a).__name__} against {type(b).__name__}"]
    if isinstance(a, np.ndarray):
        same = (a.dtype == b.dtype and a.shape == b.shape and a.flags.c_contiguous == b.flags.c_contiguous
                and np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))
        return [] if same else [f"{where}: arrays differ"]
    if dataclasses.is_dataclass(a):
        return [d for f in dataclasses.fields(a) for d in differences(getattr(a, f.name), getattr(b, f.name),
                                                                        f"{where}.{f.name}")]
    if isinstance(a, dict):
        if a.keys() != b.keys():
            return [f"{where}: keys {sorted(set(a) ^ set(b), key=str)} in one only"]
        return [d for k in a for d in differences(a[k], b[k], f"{where}.{k}")]
    if isinstance(a, list | tuple):
        if len(a) != len(b):
            return [f"{where}: {len(a)} against {len(b)} items"]
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in differences(x, y, f"{where}[{i}]")]
    if isinstance(a, float) and a != a:
        return [] if b != b else [f"{where}: nan against {b!r}"]
    return [] if a == b else [f"{where}: {a!r} against {b!r}"]


def _run(checkout: Path, *args: str) -> str:
    proc = subprocess.run([str(checkout / ".venv" / "bin" / "python"), "-c", _CHILD, *args], capture_output=True,
                          text=True, cwd=checkout, check=False,
                          env=dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1"))
    if proc.returncode != 0:
        raise RuntimeError(f"{checkout}: {proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else 'failed'}")
    return proc.stdout


def _uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()


def compare(this: Path, base: Path, repeat: int, passes: int, cycles: int, check_only: bool) -> dict:
    out: dict = {"uptime_before": _uptime()}
    with tempfile.TemporaryDirectory() as tmp:
        records = Path(tmp) / "streams.pkl"
        records.write_bytes(pickle.dumps(streams(cycles)))
        trees = {}
        for label, checkout in (("base", base), ("this", this)):
            _run(checkout, str(records), "check", str(Path(tmp) / f"{label}.pkl"))
            trees[label] = pickle.loads((Path(tmp) / f"{label}.pkl").read_bytes())
        diffs = [d for k in trees["base"] for d in differences(trees["base"][k], trees["this"][k], k)]
        out["check"] = {k: {"cycles": len(v["cycles"]), "skipped": v["counters"][0]} for k, v in trees["base"].items()}
        out["differences"] = diffs
        if diffs or check_only:
            return out
        runs: dict[str, list[dict]] = {"base": [], "this": [], "control": []}
        for _ in range(repeat):
            for label, checkout in (("base", base), ("this", this), ("control", base)):
                runs[label].append(json.loads(_run(checkout, str(records), "time", str(passes)).split("@@", 1)[1]))
    out["uptime_after"] = _uptime()
    for k in runs["base"][0]:
        speed = [b[k] / t[k] for b, t in zip(runs["base"], runs["this"], strict=True)]
        noise = [b[k] / c[k] for b, c in zip(runs["base"], runs["control"], strict=True)]
        out[k] = {"base_ms": round(statistics.median(r[k] for r in runs["base"]), 4),
                  "this_ms": round(statistics.median(r[k] for r in runs["this"]), 4),
                  "base/this": [round(statistics.median(speed), 3), round(min(speed), 3), round(max(speed), 3)],
                  "base/base (control)": [round(statistics.median(noise), 3), round(min(noise), 3),
                                          round(max(noise), 3)]}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True, help="the other checkout (with its own .venv)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--passes", type=int, default=5)
    ap.add_argument("--cycles", type=int, default=120)
    ap.add_argument("--check-only", action="store_true")
    args = ap.parse_args(argv)
    out = compare(Path.cwd(), args.base.resolve(), args.repeat, args.passes, args.cycles, args.check_only)
    print(json.dumps(out, indent=1))
    return 1 if out["differences"] else 0


if __name__ == "__main__":
    sys.exit(main())
