"""Where a healthy engine's sibling spread of the ring leak effect comes from (issue 29 item 3): an accuracy run,
not a test; the figures go into the work's report and design note 32.

    python -m bench.ring_sibling_spread --engine genset-v20 --cycles 300
    python -m bench.ring_sibling_spread --engine genset-v20 --without torsional_flexibility
    python -m bench.ring_sibling_spread --engine genset-v20 --without tooth_spacing_error,sensor_noise --fuel-spread 0
    python -m bench.ring_sibling_spread --engine genset-v20 --effect ring_wear:cylinder=10,mass_loss=0.03,gain=1.3

Streams the simulator (core.plant.sim_stream) through ``EnginePipeline`` (the preset model, no commissioning) and
reads every cycle's ring indicators (core.monitor.checks.ring_pressure, each cylinder read at its own throw's angle
where the monitor's model has a flexible shaft) and the monitor's static twist of each cylinder's throw ahead of the
flywheel (``EnginePipeline.cylinder_twist``). Prints one JSON line: per cylinder the mean leak effect
(n_expansion_dev - n_compression_dev) / 2 over the cycles after ``--skip`` and the mean twist [deg]; over the
cylinders without an effect the spread (min, max, SD) about their median and the least-squares slope of the effect
on the twist [per deg]; the faulty cylinders' effect and their indicators (both exponents' deviation, the expansion
deficit, the compression ratio) against the healthy median, and the healthy cylinders' SD of each indicator; the
per-cycle scatter's standard error of a mean (``mean_se``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.checks.ring_condition import leak_effect
from frictionwatch.core.plant.simulate import start_simulation
from frictionwatch.service.pipeline import EnginePipeline

from bench.ring_after_commission import POINTS


def measure(engine: str, seed: int, cycles: int, skip: int, without: tuple[str, ...], effects: list[str],
            fuel_spread: float, load: float | None = None) -> dict:
    rpm, load0 = POINTS[engine]
    spec = load_engine(engine)
    sim = start_simulation(spec, rpm, load0 if load is None else load, cycles, seed,
                           effects=[parse_effect(e) for e in effects], without=set(without), cov_imep=0.03,
                           fuel_spread=fuel_spread)
    pipe = EnginePipeline(spec, sim.info)
    raw, twist, rows = [], [], []
    t0 = time.process_time()
    for chunk in sim.chunks():
        for record in chunk.records:
            for res in pipe.feed(record):
                if res.ring is None or res.index < skip:
                    continue
                tw = pipe.cylinder_twist()
                eff = leak_effect(res.ring.n_compression_dev, res.ring.n_expansion_dev)
                raw.append(eff)
                rows.append(np.array([res.ring.n_compression_dev, res.ring.n_expansion_dev,
                                      res.ring.expansion_deficit, res.ring.compression_ratio]))
                twist.append(np.degrees(tw))
    raw_m, tw_m = (np.nanmean(np.array(a), axis=0) for a in (raw, twist))
    ind_m = np.nanmean(np.array(rows), axis=0)  # (4, z)
    faulty = {int(e.split("cylinder=")[1].split(",")[0]) - 1 for e in effects if "cylinder=" in e}
    healthy = np.array([k for k in range(spec.n_cyl) if k not in faulty])

    def spread(x: np.ndarray) -> dict:
        h = x[healthy] - np.median(x[healthy])
        return {"min": round(float(h.min()), 5), "max": round(float(h.max()), 5), "sd": round(float(h.std()), 5)}

    tc = tw_m[healthy] - tw_m[healthy].mean()
    slope = float(tc @ (raw_m[healthy] - raw_m[healthy].mean()) / (tc @ tc)) if tc @ tc > 0 else float("nan")
    return {"engine": engine, "seed": seed, "cycles_used": len(raw), "without": list(without), "effects": effects,
            "fuel_spread": fuel_spread, "load": load0 if load is None else load,
            "leak_effect": [round(float(v), 5) for v in raw_m],
            "twist_deg": [round(float(v), 4) for v in tw_m],
            "mean_se": round(float(np.nanmedian(np.nanstd(np.array(raw), axis=0))) / np.sqrt(len(raw)), 5), "healthy_spread_raw": spread(raw_m),
            "slope_per_deg": round(slope, 5),
            "faulty_vs_healthy_median": {str(k + 1): round(float(raw_m[k] - np.median(raw_m[healthy])), 5)
                                         for k in faulty},
            "faulty_indicators": {str(k + 1): dict(zip(("n_compression", "n_expansion", "expansion_deficit",
                                                        "compression_ratio"),
                                                       (round(float(v), 5) for v in (ind_m[:, k] - np.median(
                                                           ind_m[:, healthy], axis=1)))))
                                  for k in faulty},
            "healthy_indicator_sd": [round(float(v), 5) for v in ind_m[:, healthy].std(axis=1)],
            "cpu_s": round(time.process_time() - t0, 1)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench.ring_sibling_spread", description=__doc__.split("\n\n")[0])
    ap.add_argument("--engine", choices=sorted(POINTS), default="genset-v20")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--cycles", type=int, default=300)
    ap.add_argument("--skip", type=int, default=50, help="first cycles left out (the monitor settling)")
    ap.add_argument("--without", default="", help="default-on simulator effects turned off, comma-separated")
    ap.add_argument("--effect", action="append", default=[], help="a simulator effect (name:param=value,...)")
    ap.add_argument("--fuel-spread", type=float, default=0.01)
    ap.add_argument("--load", type=float, default=None, help="fraction of full load (default: the bench point's)")
    a = ap.parse_args(argv)
    without = tuple(w for w in a.without.split(",") if w)
    print(json.dumps(measure(a.engine, a.seed, a.cycles, a.skip, without, a.effect, a.fuel_spread, a.load)),
          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
