"""numba's/LLVM's optimisation settings against the monitor's cold compile and per-cycle CPU time (design note 98).

    python -m bench.compile_opt [--rounds 2] [--passes 3] [--set LABEL=VAR=V,VAR=V ...] [--out F]

Each setting (default: NUMBA_OPT 3 -- numba's default --, 2, 1, 0; ``--set`` gives others, e.g.
``O2-noloopvec=NUMBA_OPT=2,NUMBA_LOOP_VECTORIZE=0``) is a set of environment variables for fresh processes of this
checkout, each setting with its own empty numba cache folder per round (the cache's fingerprint does not see an
environment variable: a shared folder would load kernels compiled under another setting). Per setting and round:

1. the cold compile, ``bench_monitor.cold_compile`` (first pass minus warm pass of service.pipeline.run on the
   12-cycle streams, summed over the engines; it fills the folder);
2. the product path's per-cycle time by this thread's CPU clock, ``bench_monitor_against._one`` (EnginePipeline.outcomes
   per record, bench_monitor's points, 120 cycles, ``passes`` passes per engine, kernels loaded from the folder);
3. in the first round only, every cycle's outcome (``service.pipeline.run``, loading from the folder) compared with
   the first setting's, number by number within ``bench_monitor_against.RTOL`` (``differences``).

Settings alternate within a round and the order reverses every other round (A B C, C B A, ...). Reported per
setting: the median cold compile and per-cycle CPU ms, and their ratios to the first setting's within each round (the
median of the rounds): a shared box moves the absolute figures, ``uptime`` is printed beside each measurement.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import pickle
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.bench_monitor import POINTS, cold_compile
from bench.bench_monitor_against import _OUTCOMES, RTOL, _one, _records, differences, plain
from bench.compile_events import short_runs

DEFAULT = {"O3": {"NUMBA_OPT": "3"}, "O2": {"NUMBA_OPT": "2"}, "O1": {"NUMBA_OPT": "1"}, "O0": {"NUMBA_OPT": "0"}}


def uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip().split("load average:")[-1].strip()


def outcomes(checkout: Path, records: Path, env: dict, out: Path) -> dict:
    """Every cycle's outcome (``plain``) of service.pipeline.run on the records, by engine, in a fresh process."""
    script = _OUTCOMES.replace("\nfrom frictionwatch", "\n" + inspect.getsource(plain) + "\nfrom frictionwatch", 1)
    proc = subprocess.run([sys.executable, "-c", script, str(records), str(out)], capture_output=True, text=True,
                          env=env, cwd=checkout, check=False)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr.strip()[-2000:])
    return pickle.loads(out.read_bytes())


def measure(settings: dict[str, dict], rounds: int, passes: int, cycles: int) -> dict:
    checkout = Path(__file__).resolve().parents[1]
    short = short_runs([p[0] for p in POINTS])
    rows: dict[str, list[dict]] = {k: [] for k in settings}
    same: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        records = Path(tmp) / "records.pkl"
        _records(cycles, records)
        reference = None
        for r in range(rounds):
            order = list(settings) if r % 2 == 0 else list(settings)[::-1]
            for label in order:
                cache = Path(tmp) / f"cache-{label}-{r}"
                cache.mkdir()
                extra = dict(settings[label], NUMBA_CACHE_DIR=str(cache))
                load0 = uptime()
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                cold = cold_compile(short, env_extra=settings[label], cache_dir=cache)
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                cold_cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
                cpu = _one(checkout, records, passes, "cpu", env_extra=extra)
                row = {"round": r, "load_before": load0, "load_after": uptime(),
                       "compile_s": cold.get("compile_s_total"), "cold_cpu_s": round(cold_cpu, 2),
                       "compile_error": cold.get("error"), "import_s": cold.get("import_s"),
                       "cpu_ms": {name: statistics.median(v) for name, v in cpu.items()}}
                rows[label].append(row)
                print(f"round {r} {label:14s} compile {row['compile_s']} s (its process's CPU "
                      f"{row['cold_cpu_s']} s), cpu ms/cycle "
                      + ", ".join(f"{k} {v:.4f}" for k, v in row["cpu_ms"].items())
                      + f"  (load {load0} .. {row['load_after']})", flush=True)
                if r == 0:
                    tree = outcomes(checkout, records, dict(os.environ, **extra), Path(tmp) / f"out-{label}.pkl")
                    if reference is None:
                        reference = (label, tree)
                    else:
                        same[label] = {}
                        for name in tree:
                            diffs, n = differences(reference[1][name], tree[name], name)
                            same[label][name] = {"numbers": n, "differences": diffs}
                        print(f"  same figures as {reference[0]} (rtol {RTOL:g}): " + "; ".join(
                            f"{k} {len(v['differences'])} of {v['numbers']} differ" for k, v in same[label].items()),
                            flush=True)
    first = next(iter(settings))
    table = {}
    for label, rs in rows.items():
        ratio_c = [x["compile_s"] / f["compile_s"] for x, f in zip(rs, rows[first], strict=True)]
        table[label] = {"compile_s": statistics.median(x["compile_s"] for x in rs),
                        "compile_ratio": statistics.median(ratio_c), "compile_ratios": ratio_c,
                        "cold_cpu_s": statistics.median(x["cold_cpu_s"] for x in rs),
                        "cold_cpu_ratios": [x["cold_cpu_s"] / f["cold_cpu_s"]
                                            for x, f in zip(rs, rows[first], strict=True)],
                        "cpu_ms": {n: statistics.median(x["cpu_ms"][n] for x in rs) for n in rs[0]["cpu_ms"]},
                        "cpu_ratio": {n: statistics.median(x["cpu_ms"][n] / f["cpu_ms"][n]
                                                           for x, f in zip(rs, rows[first], strict=True))
                                      for n in rs[0]["cpu_ms"]}}
    return {"rows": rows, "table": table, "same": same, "reference": first}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--passes", type=int, default=3)
    ap.add_argument("--cycles", type=int, default=120)
    ap.add_argument("--set", action="append", default=None, metavar="LABEL=VAR=V,VAR=V",
                    help="a setting (repeat; the first is the reference); default: NUMBA_OPT 3, 2, 1, 0")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    settings = DEFAULT
    if a.set:
        settings = {}
        for s in a.set:
            label, _, assigns = s.partition("=")
            settings[label] = dict(kv.split("=", 1) for kv in assigns.split(",") if kv)
    r = measure(settings, a.rounds, a.passes, a.cycles)
    if a.out:
        a.out.write_text(json.dumps(r, indent=1))
    ref = r["reference"]
    print(f"\nsetting: cold compile s, /{ref} median (per round); the cold process's CPU s (/{ref} per round) | "
          f"per-cycle CPU ms, /{ref} (median of rounds)")
    for label, e in r["table"].items():
        print(f"  {label:14s} {e['compile_s']:6.1f} {e['compile_ratio']:.3f} "
              f"({', '.join(f'{x:.3f}' for x in e['compile_ratios'])}); process CPU {e['cold_cpu_s']:6.1f} "
              f"({', '.join(f'{x:.3f}' for x in e['cold_cpu_ratios'])}) | "
              + ", ".join(f"{n} {e['cpu_ms'][n]:.4f} {e['cpu_ratio'][n]:.3f}" for n in e["cpu_ms"]))


if __name__ == "__main__":
    main()
