"""Which files of core/ one cycle's state passes through in the one pipeline (issue 26's check: "following a cycle's
state visits <= 15 files"), and how often it comes back to a file it had left.

    python -m bench.cycle_walk [--engine k9k-4cyl] [--list]

A steady-state cycle (the 30th of a 3000 rpm / 0.9 load run, seed 3; genset-v20 at 1500 rpm) goes through
``CyclePipeline.process`` (the model's view, the monitor, the running watches) under ``sys.setprofile``; every
Python-level call whose code is in core/ is one step. Reported: the calls, the distinct files (all of core/, and of
core/monitor alone) and the re-entries: a step into a file that the walk had visited and left before (a file calling
itself does not count; a call into another file and back does). Numba kernels count as the one call into them (their
compiled body is not Python). This is what the issue measured as "visits 27 files and returns 17 times" at 89a3aad;
its exact rule for a "return" was not written down, so compare figures of this script with each other only.
Figures of this script, k9k-4cyl and genset-v20 alike: 124 calls, 27 files of core/ (24 of core/monitor), 21
re-entries at 1a68ef3; 119 calls, 25 files (22), 13 re-entries after design note 110.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import Counter

from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.pipeline import CyclePipeline
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles

WARM_CYCLES = 29  # cycles before the walked one: past every first-cycle branch (priors, windows' first fits)


def walk(engine: str) -> list[str]:
    """The core/ file (relative to core/) of each Python call during one steady-state CyclePipeline.process."""
    spec = load_engine(engine)
    rpm = 1500.0 if engine == "genset-v20" else 3000.0
    sim = simulate(spec, rpm, 0.9, WARM_CYCLES + 2, seed=3)
    cycles, _ = assembled_cycles(spec, sim.info, sim.records)
    pipe = CyclePipeline(spec)
    for c in cycles[:WARM_CYCLES]:
        pipe.process(c)
    root = os.path.dirname(sys.modules["frictionwatch.core"].__file__) + os.sep
    steps: list[str] = []

    def on_event(frame, event, arg):
        if event == "call" and frame.f_code.co_filename.startswith(root):
            steps.append(frame.f_code.co_filename[len(root):])

    sys.setprofile(on_event)
    try:
        pipe.process(cycles[WARM_CYCLES])
    finally:
        sys.setprofile(None)
    return steps


def summary(steps: list[str]) -> dict:
    """Calls, distinct files (core/, core/monitor/) and re-entries of a walk (see the module docstring)."""
    seen: set[str] = set()
    reentries, prev = 0, None
    for f in steps:
        if f != prev:
            reentries += f in seen
            seen.add(f)
            prev = f
    return {"calls": len(steps), "files": len(seen), "monitor_files": sum(f.startswith("monitor") for f in seen),
            "reentries": reentries}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--engine", default="k9k-4cyl")
    ap.add_argument("--list", action="store_true", help="also the calls per file")
    a = ap.parse_args()
    steps = walk(a.engine)
    s = summary(steps)
    print(f"{a.engine}: {s['calls']} calls, {s['files']} files of core/ ({s['monitor_files']} of core/monitor), "
          f"{s['reentries']} re-entries (issue 26's check: <= 15 files)")
    if a.list:
        for f, n in Counter(steps).most_common():
            print(f"{n:5d}  {f}")


if __name__ == "__main__":
    main()
