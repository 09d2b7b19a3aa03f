"""Sensor faults on every preset: what the sensor-health stage (core.monitor.checks.sensor_health) finds, and total FMEP
with the stage on (corrected, sigma including the sensors' remaining uncertainty) and off (raw).

    python -m bench.sensor_faults [--cycles N] [--engines k9k-4cyl,...] [--faults "healthy,cyl2 gain 1.05"]
    python -m bench.sensor_faults --timing --engines genset-v20 --cycles 40

Simulated logs the monitor is not told about (seed 1, default effects, cov_imep 0.02), assembled by the pipeline's
assembler and run through the one pipeline (core.monitor.pipeline.CyclePipeline: the monitor and the running
calibration watches, whose flags join the stage's in the results). Figures, not pass/fail: the table is quoted in the
work's report; the pass/fail checks are tests/core/test_sensor_health.py.
"""

from __future__ import annotations

import argparse
import math

from frictionwatch.core.model.effects.catalog import PressureGain, PressureOffset, TdcOffset
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.checks.sensor_health import SensorHealthConfig
from frictionwatch.core.monitor.pipeline import CyclePipeline
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles

POINTS = {"k9k-4cyl": (1700.0, 1.0), "maruti-3cyl": (3000.0, 0.8), "deutz-1cyl": (2400.0, 0.8),
          "genset-v20": (1500.0, 0.75)}
FAULTS = {
    "healthy": [],
    "wheel +1.0 deg": [TdcOffset(deg=1.0, cylinder=0)],
    "wheel -0.6 deg": [TdcOffset(deg=-0.6, cylinder=0)],
    "cyl2 +1.2 deg": [TdcOffset(deg=1.2, cylinder=2)],
    "cyl2 gain 1.05": [PressureGain(gain=1.05, cylinder=2)],
    "cyl2 offset +0.6 bar": [PressureOffset(pa=0.6e5, cylinder=2)],
}


def run(name: str, effects: list, cycles: int) -> dict:
    spec = load_engine(name)
    rpm, load = POINTS[name]
    sim = simulate(spec, rpm, load, cycles, seed=1, effects=effects or None)
    cyc, _ = assembled_cycles(spec, sim.info, sim.records)
    out = {}
    for label, cfg in (("on", MonitorConfig(sensor_health=SensorHealthConfig())), ("off", MonitorConfig())):
        pipe = CyclePipeline(spec, cfg)
        flagged = 0
        for c in cyc:
            o = pipe.process(c)
            if not o.ok:
                continue
            res = o.result
            flagged += bool(res.sensor_health and res.sensor_health.flags)
        out[label] = (res, flagged)
    res, flagged = out["on"]
    h = res.sensor_health
    truth = sim.truth["fmep_bar"] * 1e5
    watches = [f for f in res.flags if f.startswith("sensor_") and f not in h.flags]  # the calibration watches'
    return {"flags": ",".join(f.replace("sensor_", "") for f in h.flags) or "-", "flagged": flagged / len(cyc),
            "watch_flags": ",".join(f.replace("sensor_", "") for f in watches) or "-",
            "wheel": math.degrees(h.wheel_tdc_offset), "wheel_sigma": math.degrees(h.wheel_tdc_offset_sigma),
            "cyl2_tdc": math.degrees(h.tdc_offset[min(1, spec.n_cyl - 1)]),
            "cyl2_gain": float(h.pressure_gain[min(1, spec.n_cyl - 1)]),
            "cyl2_off": float(h.pressure_offset[min(1, spec.n_cyl - 1)] / 1e5),
            "err": res.smoothed.total_fmep / truth - 1.0, "sig": res.smoothed.total_fmep_sigma / truth,
            "raw_err": out["off"][0].smoothed.total_fmep / truth - 1.0,
            "raw_sig": out["off"][0].smoothed.total_fmep_sigma / truth}


def timing(name: str, cycles: int) -> None:
    """Per-cycle cost of the stage: its two calls timed inside the monitor (best of 3 passes), and the pipeline's
    whole cycle with it (core.monitor.pipeline.CyclePipeline.process: the monitor and the running watches)."""
    import time

    from frictionwatch.core.monitor import monitor

    spec = load_engine(name)
    sim = simulate(spec, *POINTS[name], cycles, seed=1)
    cyc, _ = assembled_cycles(spec, sim.info, sim.records)
    spent = [0.0]

    def timed(fn):
        def call(*args, **kwargs):
            t0 = time.perf_counter()
            out = fn(*args, **kwargs)
            spent[0] += time.perf_counter() - t0
            return out
        return call

    originals = monitor.check_cycle, monitor.corrected_inputs
    monitor.check_cycle, monitor.corrected_inputs = (timed(f) for f in originals)
    stage = whole = math.inf
    try:
        for _ in range(3):
            pipe = CyclePipeline(spec)
            spent[0] = 0.0
            t0 = time.perf_counter()
            for c in cyc:
                pipe.process(c)
            whole = min(whole, (time.perf_counter() - t0) / len(cyc))
            stage = min(stage, spent[0] / len(cyc))
    finally:
        monitor.check_cycle, monitor.corrected_inputs = originals
    print(f"{name}: the sensor-health stage {1e3 * stage:.3f} ms/cycle of the pipeline's {1e3 * whole:.3f} "
          f"({len(cyc)} cycles, best of 3 passes)")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=60)
    ap.add_argument("--engines", default=",".join(POINTS))
    ap.add_argument("--faults", default=",".join(FAULTS), help="comma-separated labels of FAULTS")
    ap.add_argument("--timing", action="store_true", help="only the per-cycle cost of the stage")
    args = ap.parse_args()
    if args.timing:
        for name in args.engines.split(","):
            timing(name, args.cycles)
        return
    print(f"{'engine':12} {'fault':22} {'wheel deg':>13} {'cyl2 deg':>8} {'gain2':>6} {'off2 bar':>8} "
          f"{'FMEP err':>8} {'sigma':>6} {'raw err':>8} {'raw sig':>7} {'flagged':>7}  flags at the end "
          f"(stage; watches)")
    for name in args.engines.split(","):
        for fault in args.faults.split(","):
            effects = FAULTS[fault]
            if name == "deutz-1cyl" and "cyl2" in fault:
                continue
            r = run(name, effects, args.cycles)
            print(f"{name:12} {fault:22} {r['wheel']:+6.2f}±{r['wheel_sigma']:.2f} {r['cyl2_tdc']:+8.2f} "
                  f"{r['cyl2_gain']:6.3f} {r['cyl2_off']:+8.2f} {100 * r['err']:+7.1f}% {100 * r['sig']:5.1f}% "
                  f"{100 * r['raw_err']:+7.1f}% {100 * r['raw_sig']:6.1f}% {100 * r['flagged']:6.0f}%  {r['flags']}; {r['watch_flags']}",
                  flush=True)


if __name__ == "__main__":
    main()
