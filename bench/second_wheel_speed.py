"""CPU per genset-v20 cycle of the one pipeline with one wheel, two wheels (the free end's own speed and tooth
learning) and the joint fit (MonitorConfig(second_wheel=True)), on the same simulated records.

    nice .venv/bin/python -m bench.second_wheel_speed [--cycles 150] [--seed 13]

Each variant runs the records twice through a fresh service.pipeline.EnginePipeline (assembler, monitor, watches);
the second pass is timed (process CPU time: the first compiles and warms up). Real time is 80 ms a cycle (1500 rpm).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import EnginePipeline

from bench.accuracy_v20_wheels import TWO_WHEELS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=150)
    ap.add_argument("--seed", type=int, default=13)
    args = ap.parse_args()
    spec = load_engine(TWO_WHEELS)
    sim = simulate(spec, 1500.0, 0.75, args.cycles, args.seed, second_wheel=True)
    variants = {"one_wheel": (replace(sim.info, second_wheel=None), MonitorConfig()),
                "two_wheels": (sim.info, MonitorConfig()), "joint": (sim.info, MonitorConfig(second_wheel=True))}
    for name, (info, cfg) in variants.items():
        for _ in range(2):
            pipe = EnginePipeline(spec, info, cfg)
            t0 = time.process_time()
            n = sum(o.ok for r in sim.records for o in pipe.outcomes(r)) + sum(o.ok for o in pipe.outcomes(None))
            cpu = time.process_time() - t0
        print(f"{name}: {n} cycles, {1e3 * cpu / n:.2f} ms CPU a cycle, {0.08 / (cpu / n):.1f}x real time")


if __name__ == "__main__":
    main()
