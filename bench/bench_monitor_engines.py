"""bench.bench_monitor's per-engine figures for the engines named, without the others, the cold compile or scipy.

    python -m bench.bench_monitor_engines genset-v20 k9k-4cyl [--json out.json]

The same engine_bench as bench.bench_monitor (its operating points, cycles, seed, the timed pass's median of PASSES,
the stage split and the cProfile top 10), for looking at one or two engines' split while working on a stage: the
full bench also simulates deutz-1cyl and measures the cold compile in a fresh process, ~3 min more on a 2-core box.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from bench.bench_monitor import POINTS, engine_bench


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("engines", nargs="+", choices=[name for name, _, _ in POINTS])
    ap.add_argument("--json", type=Path, default=None, help="also write the result dict here")
    args = ap.parse_args()
    out = {}
    for name, rpm, load in POINTS:
        if name not in args.engines:
            continue
        e, _ = engine_bench(name, rpm, load, 0)
        out[name] = e
        print(f"\n{name} at {rpm:g} rpm: end to end {e['end_to_end']['mean_ms']:.3f} ms = assemble "
              f"{e['assemble']['mean_ms']:.3f} + monitor {e['monitor']['mean_ms']:.3f}; passes "
              f"{', '.join(f'{v:.3f}' for v in e['end_to_end_mean_ms_per_pass'])}")
        total = e["monitor_stages_ms"]["total (instrumented)"]
        print(f"monitor stages (ms per cycle, % of the instrumented total {total:.3f}):")
        for label, ms in e["monitor_stages_ms"].items():
            print(f"  {label[:60]:60s} {ms:8.3f} {100 * ms / total:6.1f} %")
        print("cProfile top 10 (own ms, cum ms, calls per cycle):")
        for p in e["profile_top10"]:
            print(f"  {p['own_ms_per_cycle']:8.3f} {p['cum_ms_per_cycle']:8.3f} {p['calls_per_cycle']:7.1f}  "
                  f"{p['function']}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
