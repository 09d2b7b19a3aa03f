"""Small helpers shared by the benchmarks: percentile summaries and per-cycle timing of the cycle assembler alone
(bench/bench_cycles.py; the assembler the pipeline builds, service.pipeline.cycle_assembler)."""

from __future__ import annotations

import time
from collections.abc import Iterable

import numpy as np
from frictionwatch.core.types import Cycle, PressureFrame, StreamRecord
from frictionwatch.drivers.assembly.cycles import CycleAssembler
from frictionwatch.drivers.assembly.pressure_ring import frame_blocks


def summary_ms(values_ms: Iterable[float]) -> dict:
    """p50, p99, mean [ms] and the rate it allows [1/s] of per-cycle times given in ms."""
    a = np.asarray(list(values_ms), dtype=np.float64)
    if a.size == 0:
        return {"n": 0}
    mean = float(a.mean())
    return {"n": int(a.size), "p50_ms": round(float(np.percentile(a, 50)), 4),
            "p99_ms": round(float(np.percentile(a, 99)), 4), "mean_ms": round(mean, 4),
            "max_ms": round(float(a.max()), 4), "cycles_per_s": round(1000.0 / mean, 1) if mean > 0 else None}


def as_blocks(records: Iterable[StreamRecord]) -> list[StreamRecord]:
    """The records with every PressureFrame split into its per-cylinder PressureBlocks (how a CAN or DAQ driver
    delivers the same samples), in place of the frame."""
    return [b for r in records for b in (frame_blocks(r) if isinstance(r, PressureFrame) else (r,))]


def timed_assembly(asm: CycleAssembler, records: Iterable[StreamRecord]
                   ) -> Iterable[tuple[Cycle, float, float]]:
    """Feed ``records`` and yield (cycle, assembly_ms, emit_ms) per emitted cycle.

    assembly_ms: all ``feed`` calls since the previous emission, shared among the cycles emitted together (the whole
    input-side work of a cycle); emit_ms: the one call that returned the cycle (between its last tooth and the
    cycle being available)."""
    acc = 0.0
    for rec in records:
        t0 = time.perf_counter()
        out = asm.feed(rec)
        dt = time.perf_counter() - t0
        acc += dt
        if out:
            for c in out:
                yield c, 1e3 * acc / len(out), 1e3 * dt
            acc = 0.0
    t0 = time.perf_counter()
    out = asm.flush()
    dt = time.perf_counter() - t0
    for c in out:
        yield c, 1e3 * (acc + dt) / len(out), 1e3 * dt
