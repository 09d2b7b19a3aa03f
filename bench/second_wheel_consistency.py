"""Are the second wheel's speed equations consistent with the plant? Their residual at the true friction scales.

    nice .venv/bin/python -m bench.second_wheel_consistency [--cycles 150] [--seed 7] [--load 0.75]

genset-v20 with its free-end wheel at one load; the joint fit on (MonitorConfig(second_wheel=True)); every cycle's
free-end equations (design, target) are taken as the monitor forms them (core.monitor.monitor calls
free_end_whitened: wrapped here to keep its inputs) and evaluated at the truth (every friction scale 1; the free
end's rows carry no tooth nuisance). Printed per half order (the rows the joint fit uses), after the first 30 cycles:
the mean residual against the measured speed harmonic, against its standard error, and the rows' summed sensitivity
to the scales against it (small: the row pulls the estimate hard where its residual is repeatable).
"""

from __future__ import annotations

import argparse

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor import monitor as mon
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import EnginePipeline

from bench.accuracy_v20_wheels import TWO_WHEELS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=150)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--load", type=float, default=0.75)
    args = ap.parse_args()
    kept = []
    whiten = mon.free_end_whitened

    def keep(stats, design, target, params, harmonics, fit, *rest):
        kept.append((design.copy(), target.copy(), harmonics.copy(), fit[0]))
        return whiten(stats, design, target, params, harmonics, fit, *rest)

    mon.free_end_whitened = keep
    try:
        spec = load_engine(TWO_WHEELS)
        sim = simulate(spec, 1500.0, args.load, args.cycles, args.seed, second_wheel=True)
        pipe = EnginePipeline(spec, sim.info, MonitorConfig(second_wheel=True))
        for record in sim.records:
            pipe.feed(record)
        pipe.flush()
    finally:
        mon.free_end_whitened = whiten
    p = pipe.state.layout.n_params
    theta = np.zeros(kept[0][0].shape[1])
    theta[:p] = 1.0
    rows = kept[30:]
    resid = np.array([t - d @ theta for d, t, _, _ in rows])
    speed = np.array([0.5j * w * np.arange(1, h.shape[0] + 1) * h for _, _, h, w in rows])
    half = np.arange(0, resid.shape[1], 2)
    mean = np.abs(resid.mean(axis=0))[half]
    sens = np.abs(np.array([d[:, :p] for d, _, _, _ in rows]).mean(axis=0)[half]).sum(axis=1)
    print(f"{len(rows)} cycles; order, |mean residual| / |speed harmonic|, / its standard error, sensitivity / it")
    for i, j in enumerate(half):
        se = resid[:, j].std() / np.sqrt(len(rows))
        print(f"{(j + 1) / 2:5.1f}  {mean[i] / np.abs(speed.mean(axis=0)[j]):7.3f}  {mean[i] / se:6.1f}  "
              f"{sens[i] / mean[i]:7.1f}")


if __name__ == "__main__":
    main()
