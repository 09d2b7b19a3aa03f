"""serve's cold start, measured: `python -m frictionwatch.service.warmup LOG` on an empty numba cache, settings
alternated round by round (design notes 150, 160).

Each run is a fresh process with a fresh empty NUMBA_CACHE_DIR (removed after); printed per run: the load average
before and after, the warm-up's own line (its seconds: what serve's first cycle waits for), the process's wall clock
and the CPU of the process with its children (getrusage of the reaped children). A setting is a name, an
interpreter (a checkout's venv python: a base worktree for a "before") and extra arguments:

    python -m bench.cold_warmup --set base=/tmp/base/.venv/bin/python --set split=.venv/bin/python:--second-core=yes \\
        --rounds 2 [--log replay_logs/demo.mcap] [--json out.json]

Rounds alternate the settings' order (A B, B A, ...). On a shared box read same-round ratios, not seconds.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import tempfile
import time


def one(python: str, extra: list[str], log: str) -> dict:
    cache = tempfile.mkdtemp(prefix="fw-cold-")
    env = {**os.environ, "NUMBA_CACHE_DIR": cache, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    load0 = os.getloadavg()[0]
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([python, "-m", "frictionwatch.service.warmup", log, *extra], env=env, capture_output=True,
                          text=True, check=False)
    wall = time.perf_counter() - t0
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    shutil.rmtree(cache, ignore_errors=True)
    lines = proc.stdout.strip().splitlines()
    return {"load": [round(load0, 2), round(os.getloadavg()[0], 2)], "wall_s": round(wall, 1),
            "cpu_s": round(cpu1.ru_utime + cpu1.ru_stime - cpu0.ru_utime - cpu0.ru_stime, 1),
            "line": lines[-1] if lines else proc.stderr.strip()[-300:], "status": proc.returncode}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", action="append", required=True, help="NAME=PYTHON[:ARG[:ARG...]]")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--log", default="replay_logs/demo.mcap")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    settings = []
    for s in args.set:
        name, _, rest = s.partition("=")
        python, *extra = rest.split(":")
        settings.append((name, python, extra))
    runs = []
    for r in range(args.rounds):
        for name, python, extra in (settings if r % 2 == 0 else settings[::-1]):
            row = {"round": r + 1, "setting": name, **one(python, extra, args.log)}
            runs.append(row)
            print(json.dumps(row), flush=True)
            if args.json:
                with open(args.json, "w") as f:
                    json.dump(runs, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
