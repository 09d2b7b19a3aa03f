"""`make bench`: run every benchmark in its own process (so peak RSS is its own), print a table, write
bench/results/make_bench.json. Speed targets live here, never in timed tests."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

BENCHES = ["bench_simulate", "bench_sim_long", "bench_monitor", "bench_cycles", "bench_drivers", "bench_log_format", "bench_discrepancy",
           "long_run_cost"]
OUT = Path(__file__).parent / "results" / "make_bench.json"


def run_one(name: str) -> dict:
    code = (f"import json, resource, bench.{name} as b; r = b.run(); "
            "r['peak_rss_mb'] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1); "
            "print('@@' + json.dumps(r, default=float))")
    t0 = time.perf_counter()
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    sys.stdout.write(proc.stdout.split("@@")[0])
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else f"exit {proc.returncode}"}
    result = json.loads(proc.stdout.split("@@", 1)[1])
    result["wall_s"] = round(time.perf_counter() - t0, 2)
    return result


def main() -> int:
    results = {}
    for name in BENCHES:
        if not Path(__file__).with_name(f"{name}.py").exists():
            continue
        print(f"== {name}", flush=True)
        results[name] = run_one(name)
    results["machine"] = {"cpus": os.cpu_count(), "python": sys.version.split()[0]}
    OUT.write_text(json.dumps(results, indent=1, default=float))
    print(f"\nwrote {OUT}")
    failed = [k for k, v in results.items() if isinstance(v, dict) and "error" in v]
    for k in failed:
        print(f"{k}: FAILED: {results[k]['error']}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
