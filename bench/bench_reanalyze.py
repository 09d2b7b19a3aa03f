"""Speed of `frictionwatch reanalyze`: logs per minute over an archive of simulated logs, on a local Dask cluster of
1 and 2 worker processes, against a plain serial loop over the same per-log function (the Dask overhead).

    python -m bench.bench_reanalyze [--archive DIR] [--repeat N]

The archive (built once, kept in DIR, default /tmp/fw-reanalyze-bench): 12 logs, k9k-4cyl and genset-v20 mixed,
40-200 cycles each, in two folders that reuse file names. Every mode analyses every log with the spec the log
carries; the first call in each process (numba loading its kernels from the on-disk cache) is outside the timing:
the serial loop warms on the first log, the cluster's workers through the reanalyze warm-up. The machine's load
average is printed beside the figures: on a shared box they move with it.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

# (folder, name, engine, rpm, load, cycles, seed): names repeat across folders on purpose
ARCHIVE = [
    ("site-a", "run01", "k9k-4cyl", 1500.0, 0.5, 40, 1), ("site-a", "run02", "genset-v20", 1500.0, 0.8, 60, 2),
    ("site-a", "run03", "k9k-4cyl", 2500.0, 0.9, 120, 3), ("site-a", "run04", "genset-v20", 1500.0, 1.0, 200, 4),
    ("site-a", "run05", "k9k-4cyl", 3500.0, 0.3, 200, 5), ("site-a", "run06", "genset-v20", 1200.0, 0.6, 80, 6),
    ("site-b", "run01", "genset-v20", 1500.0, 0.5, 40, 7), ("site-b", "run02", "k9k-4cyl", 1100.0, 0.7, 160, 8),
    ("site-b", "run03", "genset-v20", 1600.0, 0.9, 120, 9), ("site-b", "run04", "k9k-4cyl", 2000.0, 1.0, 100, 10),
    ("site-b", "run05", "genset-v20", 1500.0, 0.7, 180, 11), ("site-b", "run06", "k9k-4cyl", 3000.0, 0.6, 60, 12),
]


def build_archive(root: Path) -> list[Path]:
    """Simulate the archive's logs that are not there yet (each with its truth file beside it)."""
    from frictionwatch.service.cli import main

    logs = []
    for folder, name, engine, rpm, load, cycles, seed in ARCHIVE:
        path = root / folder / f"{name}.mcap"
        if not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            rc = main(["simulate", "--engine", engine, "--rpm", str(rpm), "--load", str(load), "--cycles", str(cycles),
                       "--seed", str(seed), "-o", str(path)])
            if rc != 0:
                raise SystemExit(f"could not simulate {path}")
        logs.append(path)
    return logs


def serial(logs: list[Path]) -> tuple[float, float]:
    """(wall time, the longest log's time) of a plain loop over the per-log function the workers run (warmed on
    the first log first)."""
    from frictionwatch.service.reanalyze import analyze_one

    analyze_one(str(logs[0]), None)
    t = time.perf_counter()
    longest = 0.0
    for log in logs:
        row = analyze_one(str(log), None)
        if row["status"] != "ok":
            raise SystemExit(f"{log}: {row['reason']}")
        longest = max(longest, row["elapsed_s"])
    return time.perf_counter() - t, longest


def on_cluster(logs: list[Path], workers: int) -> tuple[float, float]:
    """(warm-up s, wall time s of the run) on a fresh LocalCluster of ``workers`` processes."""
    from frictionwatch.service.reanalyze import ModelChoice, run_on_dask, start_client, warm_workers

    with start_client(None, workers) as client:
        t = time.perf_counter()
        warm_workers(client, logs)
        warm = time.perf_counter() - t
        t = time.perf_counter()
        rows = list(run_on_dask(client, logs, ModelChoice.stored()))
        wall = time.perf_counter() - t
    bad = [r for _, r in rows if r["status"] != "ok"]
    if bad or len(rows) != len(logs):
        raise SystemExit(f"cluster run incomplete: {bad[:1]}")
    return warm, wall


def run(archive: Path = Path("/tmp/fw-reanalyze-bench"), repeat: int = 1) -> dict:
    logs = build_archive(archive)
    cycles = sum(c for *_, c, _ in ARCHIVE)
    out: dict = {"logs": len(logs), "cycles": cycles, "cores": os.cpu_count(), "runs": []}
    for _ in range(repeat):
        load_before = os.getloadavg()[0]
        s, longest = serial(logs)
        w1, c1 = on_cluster(logs, 1)
        w2, c2 = on_cluster(logs, 2)
        out["runs"].append({
            "load_avg_1min_before": round(load_before, 2), "load_avg_1min_after": round(os.getloadavg()[0], 2),
            "serial_s": round(s, 2), "serial_logs_per_min": round(60 * len(logs) / s, 2),
            "serial_longest_log_s": round(longest, 2),
            "dask_1_worker_s": round(c1, 2), "dask_1_worker_logs_per_min": round(60 * len(logs) / c1, 2),
            "dask_1_worker_warmup_s": round(w1, 2),
            "dask_2_workers_s": round(c2, 2), "dask_2_workers_logs_per_min": round(60 * len(logs) / c2, 2),
            "dask_2_workers_warmup_s": round(w2, 2),
        })
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--archive", type=Path, default=Path("/tmp/fw-reanalyze-bench"))
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--build-only", action="store_true", help="simulate the archive and stop")
    a = parser.parse_args()
    if a.build_only:
        print("\n".join(map(str, build_archive(a.archive))))
    else:
        print(json.dumps(run(a.archive, a.repeat), indent=1))
