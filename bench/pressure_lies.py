"""Pressure sensors that lie (design note 144): one cylinder's channel of a simulated log made to fail in service, the
monitor not told, run through the one pipeline (core.monitor.pipeline.CyclePipeline after the pipeline's assembler);
what it flags, on which cylinder, and how far its engine FMEP lands from the healthy run's in the healthy run's sigma.

    python -m bench.pressure_lies [--cycles N] [--engines k9k-4cyl,...] [--faults negated,dead_zero] [--seed S]
    python -m bench.pressure_lies --no-check      # the same with the trace plausibility check left out

Faults act on the records (PressureFrame rows), as a plant's channel would: negated (amplifier polarity), dead (all
zero; a constant 1 bar), stuck (frozen at its value at mid-run), clipped (saturated at 60 % of the channel's healthy
peak), phase_360 (the trace one crank revolution late: its peak at gas-exchange TDC), swapped (cylinders 1 and 2
exchanged), clock_x2 / clock_x0.5 (the channel's sample period stated half / twice what it is: its trace stretched or
squeezed against the crank), spikes (+40 bar single samples, 0.1 %), dropouts (runs of 5 zero samples), drift (an
offset rising to +3 bar over the run: a thermal shock's slow part). Figures, not pass/fail: the pass/fail checks are
tests/core/test_pressure_trace.py.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.pipeline import STAGES, CyclePipeline, PressureTrace
from frictionwatch.core.monitor.report.run_summary import end_of_run_status
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.core.types import PressureBlock, PressureFrame
from frictionwatch.service.pipeline import assembled_cycles

# two operating points per engine (the second is where the check's thresholds were not tuned: note 144)
POINTS = {"k9k-4cyl": ((1700.0, 1.0), (2600.0, 0.4)), "maruti-3cyl": ((3000.0, 0.8), (2000.0, 0.35)),
          "deutz-1cyl": ((2400.0, 0.8), (1600.0, 0.4)), "genset-v20": ((1500.0, 0.75), (1500.0, 0.35))}
FAULTS = ("healthy", "negated", "dead_zero", "dead_const", "stuck", "clipped", "phase_360", "swapped", "clock_x2",
          "clock_x0.5", "spikes", "dropouts", "drift")
SIBLING_ONLY = ("swapped",)  # a fault that needs a second cylinder


def _rows(records, cyl: int):
    """(record index, row) of every pressure frame that carries cylinder ``cyl`` (1-based)."""
    return [(i, r.cylinders.index(cyl)) for i, r in enumerate(records)
            if type(r) is PressureFrame and cyl in r.cylinders]


def lie(records: list, fault: str, cyl: int, tick_hz: float, rpm: float, seed: int = 0) -> list:
    """``records`` with cylinder ``cyl``'s channel failed as ``fault`` (module doc); the others as they were."""
    records = list(records)
    where = _rows(records, cyl)
    if fault == "healthy" or not where:
        return records
    rng = np.random.default_rng(seed)
    chan = np.concatenate([records[i].values[r] for i, r in where])
    n_frame = records[where[0][0]].values.shape[1]
    if fault == "negated":
        new = -chan
    elif fault == "dead_zero":
        new = np.zeros_like(chan)
    elif fault == "dead_const":
        new = np.full_like(chan, 1.0e5)
    elif fault == "stuck":
        new = chan.copy()
        new[chan.size // 2:] = chan[chan.size // 2]
    elif fault == "clipped":
        new = np.minimum(chan, 0.6 * chan.max())
    elif fault == "phase_360":
        per_rev = int(round(60.0 / rpm * tick_hz / records[where[0][0]].period_ticks))
        new = np.concatenate([chan[:per_rev], chan[:-per_rev]])  # late by one revolution (the first copied)
    elif fault == "swapped":
        other = 2 if cyl == 1 else 1
        src = _rows(records, other)
        new = np.concatenate([records[i].values[r] for i, r in src])
        for (i, r), (j, q) in zip(where, src, strict=True):
            v = records[j].values.copy()
            v[q] = records[i].values[r]
            records[j] = replace(records[j], values=v)
    elif fault == "spikes":
        new = chan.copy()
        hit = rng.random(chan.size) < 1e-3
        new[hit] += 40e5
    elif fault == "dropouts":
        new = chan.copy()
        for s in np.flatnonzero(rng.random(chan.size) < 2e-4):
            new[s:s + 5] = 0.0
    elif fault == "drift":
        new = chan + np.linspace(0.0, 3e5, chan.size)
    elif fault.startswith("clock_x"):
        return _clock(records, where, float(fault.removeprefix("clock_x")))
    else:
        raise ValueError(f"unknown fault {fault!r}; known: {', '.join(FAULTS)}")
    for k, (i, r) in enumerate(where):
        v = records[i].values.copy()
        v[r] = new[k * n_frame:(k + 1) * n_frame]
        records[i] = replace(records[i], values=v)
    return records


def _clock(records: list, where: list, factor: float) -> list:
    """The channel taken out of its frames into blocks whose time base runs ``factor`` times the truth's (its sample
    period stated ``factor`` times what it is) from the first frame on."""
    t_first = records[where[0][0]].t0_ticks
    for i, r in where:
        f = records[i]
        keep = [c for k, c in enumerate(f.cylinders) if k != r]
        rows = np.delete(f.values, r, axis=0)
        t0 = t_first + round((f.t0_ticks - t_first) * factor)
        block = PressureBlock(f.cylinders[r], t0, f.period_ticks * factor, f.values[r].copy())
        records[i] = [replace(f, cylinders=tuple(keep), values=rows), block] if keep else [block]
    out = []
    for rec in records:
        out += rec if isinstance(rec, list) else [rec]
    blocks = sorted((r for r in out if type(r) is PressureBlock), key=lambda b: b.t0_ticks)
    rest = [r for r in out if type(r) is not PressureBlock]
    # a block enters the stream where its stated time is (the assembler reads records in arrival order)
    merged, b = [], 0
    for rec in rest:
        t = getattr(rec, "t0_ticks", None)
        if t is None:
            t = getattr(rec, "ticks", None)
            t = int(t[0]) if isinstance(t, np.ndarray) and t.size else t
        while b < len(blocks) and t is not None and blocks[b].t0_ticks <= t:
            merged.append(blocks[b])
            b += 1
        merged.append(rec)
    return merged + blocks[b:]


def run(name: str, point: tuple[float, float], fault: str, cycles: int, seed: int, cyl: int,
        stages=STAGES) -> dict:
    """One case: the flags at the end, the faulty cylinder's figure status, the engine FMEP and its sigma."""
    spec = load_engine(name)
    rpm, load = point
    sim = simulate(spec, rpm, load, cycles, seed=seed)
    records = lie(sim.records, fault, cyl, sim.info.tick_hz, rpm, seed)
    cyc, retired = assembled_cycles(spec, sim.info, records)
    pipe = CyclePipeline(spec, stages=stages)
    results = []
    for c in cyc:
        try:
            o = pipe.process(c)
        except Exception as exc:  # noqa: BLE001 -- a crash is a finding of the bench, reported as one
            return {"crash": f"{type(exc).__name__}: {exc}"}
        if o.ok:
            results.append(o.result)
    if not results:
        return {"crash": None, "ok": 0, "skipped": dict(pipe.skipped), "retired": dict(retired)}
    _, active, status = end_of_run_status(results)
    last = results[-1]
    sensor = sorted(f for f in active if f.startswith("sensor_"))
    return {"crash": None, "ok": len(results), "skipped": dict(pipe.skipped), "retired": dict(retired),
            "flags": sensor, "engine_status": status.engine.status,
            "cyl_status": status.cylinders[cyl - 1].status, "fmep": last.smoothed.total_fmep / 1e5,
            "sigma": last.smoothed.total_fmep_sigma / 1e5, "imep": float(last.imep[cyl - 1]) / 1e5}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=40)
    ap.add_argument("--engines", default=",".join(POINTS))
    ap.add_argument("--faults", default=",".join(FAULTS))
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--points", default="0,1")
    ap.add_argument("--no-check", action="store_true", help="the pipeline without the trace plausibility stage")
    args = ap.parse_args()
    stages = tuple(s for s in STAGES if not (args.no_check and isinstance(s, PressureTrace)))
    print(f"{'engine':12} {'pt':>2} {'fault':11} {'ok':>3} {'FMEP bar':>9} {'sigma':>6} {'dev/sig':>7} "
          f"{'IMEPk':>7} {'cyl':>10} {'engine':>10}  sensor flags active at the end; skipped")
    for name in args.engines.split(","):
        for p in (int(x) for x in args.points.split(",")):
            base = None
            for fault in args.faults.split(","):
                if name == "deutz-1cyl" and fault in SIBLING_ONLY:
                    continue
                cyl = 1 if fault == "swapped" else load_engine(name).n_cyl  # the last cylinder: not cylinder 1
                r = run(name, POINTS[name][p], fault, args.cycles, args.seed, cyl, stages)
                if r.get("crash"):
                    print(f"{name:12} {p:2d} {fault:11} CRASH {r['crash']}", flush=True)
                    continue
                if r["ok"] == 0:
                    print(f"{name:12} {p:2d} {fault:11} no cycle analysed {r['skipped']} {r['retired']}", flush=True)
                    continue
                if fault == "healthy":
                    base = r
                dev = (r["fmep"] - base["fmep"]) / base["sigma"] if base else math.nan
                print(f"{name:12} {p:2d} {fault:11} {r['ok']:3d} {r['fmep']:9.3f} {r['sigma']:6.3f} {dev:+7.1f} "
                      f"{r['imep']:7.2f} {r['cyl_status']:>10} {r['engine_status']:>10}  "
                      f"{','.join(f.removeprefix('sensor_') for f in r['flags']) or '-'}; "
                      f"{r['skipped'] or ''}{r['retired'] or ''}", flush=True)


if __name__ == "__main__":
    main()
