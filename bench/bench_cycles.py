"""Cycle assembly on a genset-v20 stream (160-2 wheel, 20 cylinders at 20 kHz, 1500 rpm).

    python -m bench.bench_cycles

The stream comes from the plant simulator (core.plant.simulate, the records as a log would replay them: teeth in batches,
one 10 ms pressure frame of all cylinders, load at 100 Hz). Stages, each timed per cycle on one core:

- assemble: every ``CycleAssembler.feed`` call between two emitted cycles (ring buffers, sync, phase, pressure
  resampling of 20 cylinders onto 720 points), i.e. the whole input-side work of one cycle; ``assemble_blocks`` is
  the same with the pressure as one block per cylinder (as CAN / DAQ drivers deliver it);
- latency: the single ``feed`` call that returned the cycle (what stands between the last tooth and the cycle);
Real time at 1500 rpm is 12.5 cycles/s.
"""

from __future__ import annotations

import time

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.drivers.assembly.cycles import CycleAssembler
from frictionwatch.service.pipeline import cycle_assembler

from bench.common import as_blocks, timed_assembly

CYCLES = 60
RPM = 1500.0


def _stats(ms: list[float]) -> dict:
    a = np.asarray(ms)
    return {"p50_ms": round(float(np.percentile(a, 50)), 4), "p99_ms": round(float(np.percentile(a, 99)), 4),
            "mean_ms": round(float(a.mean()), 4), "cycles_per_s": round(1000.0 / float(a.mean()), 1)}


def _assemble(spec, info, records) -> tuple[list, list[float], list[float], CycleAssembler]:
    """Cycles, per-cycle assembly ms and emitting-call ms (bench.common.timed_assembly; bench_monitor's
    assemble is the same share of the pipeline's ``outcomes`` calls), and the assembler."""
    asm = cycle_assembler(spec, info)  # the pipeline's own
    cycles, per_cycle, latency = [], [], []
    for c, asm_ms, emit_ms in timed_assembly(asm, records):
        cycles.append(c)
        per_cycle.append(asm_ms)
        latency.append(emit_ms)
    return cycles, per_cycle, latency, asm


def run() -> dict:
    spec = load_engine("genset-v20")
    t0 = time.perf_counter()
    res = simulate(spec, RPM, 1.0, CYCLES, seed=1)
    sim_s = time.perf_counter() - t0
    warm = simulate(spec, RPM, 1.0, 2, seed=2)
    _assemble(spec, warm.info, warm.records)  # warm the numba kernels
    _assemble(spec, warm.info, as_blocks(warm.records))
    cycles, per_cycle, latency, asm = _assemble(spec, res.info, res.records)
    blocks = as_blocks(res.records)
    _, per_cycle_blocks, _, _ = _assemble(spec, res.info, blocks)
    n_rec = len(res.records)

    asm_s = _stats(per_cycle)
    both = float(np.mean(per_cycle))
    return {
        "engine": spec.name, "rpm": RPM, "wheel": f"{spec.sensors.wheel_teeth}-{spec.sensors.wheel_missing}",
        "cylinders": spec.n_cyl, "pressure_hz": spec.sensors.pressure_rate_hz, "records": n_rec,
        "records_per_cycle": round(n_rec / CYCLES, 1), "records_per_cycle_blocks": round(len(blocks) / CYCLES, 1),
        "cycles_in": CYCLES, "cycles_out": len(cycles), "skipped": dict(asm.skipped),
        "assemble": asm_s, "assemble_blocks": _stats(per_cycle_blocks), "emit_latency": _stats(latency),
        "assemble_cycles_per_s": round(1000.0 / both, 1),
        "real_time_factor": round(1000.0 / both / (RPM / 120.0), 1),
        "simulate_s": round(sim_s, 2),
    }


def main() -> None:
    r = run()
    print(f"{r['engine']} {r['wheel']} wheel, {r['cylinders']} cylinders at {r['pressure_hz'] / 1e3:g} kHz, "
          f"{r['rpm']:g} rpm: {r['cycles_out']}/{r['cycles_in']} cycles from {r['records']} records "
          f"(skipped {r['skipped'] or 'none'})")
    print(f"{'stage':28s} {'cycles/s':>10s} {'p50 ms':>9s} {'p99 ms':>9s}")
    for key in ("assemble", "assemble_blocks", "emit_latency"):
        s = r[key]
        print(f"{key:28s} {s['cycles_per_s']:10.1f} {s['p50_ms']:9.3f} {s['p99_ms']:9.3f}")
    print(f"assemble: {r['assemble_cycles_per_s']} cycles/s = {r['real_time_factor']}x real time")


if __name__ == "__main__":
    main()
