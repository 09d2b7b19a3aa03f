"""TDC from each cylinder's pressure on the product's simulator, with a wheel TDC offset the monitor is not told of
(issue 25; core/monitor/calibration/tdc.py). Not run by the test suite.

    python -m bench.tdc_from_pressure                # the table: tested-on cases
    python -m bench.tdc_from_pressure --tune         # the cases the window edges and the systematic were chosen on
    python -m bench.tdc_from_pressure --engine k9k-4cyl --load 1.0 --deg 1.0   # one case

Every case: ``simulate`` with ``tdc_offset:cylinder=0,deg=X`` (the whole wheel off: every cylinder's true TDC lies X
later than stated), the default realistic effects on, cycles assembled as the monitor assembles them, then
``tdc_of_cycles``. A case passes when every cylinder's found offset is within 0.15 deg of X. Printed per case: the
worst cylinder's error, the mean found offset, the median sigma and how many cylinders have the truth within 2 sigma.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from frictionwatch.core.model.effects import make_effect  # noqa: E402
from frictionwatch.core.model.engine import load_engine  # noqa: E402
from frictionwatch.core.monitor.calibration.tdc import tdc_of_cycles  # noqa: E402
from frictionwatch.core.plant.simulate import simulate  # noqa: E402
from frictionwatch.service.pipeline import assembled_cycles  # noqa: E402

TOLERANCE_DEG = 0.15
# The thermodynamic TDC is that of the throw. On the default (flexible) crank each throw twists against the wheel
# (k9k-4cyl 1700 rpm full load: cylinder 1 -0.29 deg, cylinder 4 -0.08 deg on a healthy run; rigid: -0.05 and -0.04),
# and the truth file does not give that twist. So the per-cylinder check runs on a rigid crank; the flexible crank
# is checked as found(offset) - found(healthy) of the same engine, load and seed (--flexible).
RIGID = ("torsional_flexibility",)
OFFSETS = (0.0, 0.3, -0.3, 0.6, -0.6, 1.0, -1.0, 1.5, -1.5)
# (engine, rpm, load): two loads each
POINTS = {
    "k9k-4cyl": ((1700.0, 1.0), (2500.0, 0.5)),
    "maruti-3cyl": ((3000.0, 0.8), (2000.0, 0.4)),
    "deutz-1cyl": ((2600.0, 1.0), (1800.0, 0.5)),
    "genset-v20": ((1500.0, 1.0), (1500.0, 0.5)),
}
# the window edges and SYSTEMATIC_SIGMA_DEG were chosen on these (seed 1); the table is every other case, seed 2
TUNE = (("k9k-4cyl", 1700.0, 1.0), ("maruti-3cyl", 3000.0, 0.8))
TUNE_OFFSETS = (0.0, 1.0, -1.0)


def assembled(engine: str, rpm: float, load: float, cycles: int, seed: int, deg: float, rigid: bool = True):
    spec = load_engine(engine)
    effects = [make_effect("tdc_offset", {"cylinder": 0, "deg": deg})] if deg else []
    sim = simulate(spec, rpm, load, cycles, seed, effects=effects, without=RIGID if rigid else ())
    return spec, assembled_cycles(spec, sim.info, sim.records)[0]  # the pipeline's assembler


def case(engine: str, rpm: float, load: float, deg: float, cycles: int, seed: int, flexible: bool = False) -> dict:
    spec, cyc = assembled(engine, rpm, load, cycles, seed, deg, rigid=not flexible)
    t0 = time.perf_counter()
    found = tdc_of_cycles(cyc, spec)
    dt = time.perf_counter() - t0
    off = np.array([f.offset_deg for f in found if f is not None])
    # sigma without the two model doubts (wall heat x1.3, a constant loss): what the fit itself can tell
    core = np.array([math.hypot(f.evidence["statistical_deg"], f.evidence["systematic_deg"]) for f in found
                     if f is not None])
    if flexible:  # relative to the healthy run: the throws' twist cancels
        _, healthy = assembled(engine, rpm, load, cycles, seed, 0.0, rigid=False)
        off = off - np.array([f.offset_deg for f in tdc_of_cycles(healthy, spec) if f is not None])
    sig = np.array([f.sigma_deg for f in found if f is not None])
    err = off - deg
    return {"engine": engine, "rpm": rpm, "load": load, "truth_deg": deg, "seed": seed, "cycles": len(cyc),
            "found_deg": [round(x, 3) for x in off], "sigma_deg": [round(x, 3) for x in sig],
            "worst_err_deg": float(np.max(np.abs(err))), "within_2sigma": int(np.sum(np.abs(err) <= 2 * sig)),
            "sigma_core_deg": [round(x, 3) for x in core], "within_2sigma_core": int(np.sum(np.abs(err) <= 2 * core)),
            "n_cyl": int(off.size), "pass": bool(np.max(np.abs(err)) <= TOLERANCE_DEG), "fit_s": round(dt, 2),
            "pegging_bar": [round(f.pegging_pa * 1e-5, 3) for f in found if f is not None]}


def line(r: dict) -> str:
    return (f"{r['engine']:12s} {r['rpm']:5.0f} {r['load']:4.2f} {r['truth_deg']:+5.2f} | mean {np.mean(r['found_deg']):+6.3f}"
            f" worst err {r['worst_err_deg']:5.3f} | sigma {np.median(r['sigma_deg']):5.3f} in 2 sigma "
            f"{r['within_2sigma']}/{r['n_cyl']} | sigma(fit only) {np.median(r['sigma_core_deg']):5.3f} in 2 sigma "
            f"{r['within_2sigma_core']}/{r['n_cyl']} | {'ok' if r['pass'] else 'FAIL'}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--tune", action="store_true")
    ap.add_argument("--flexible", action="store_true", help="default crank, found offsets relative to a healthy run")
    ap.add_argument("--offsets", default=None, help="comma-separated offsets [deg] instead of the full set")
    ap.add_argument("--engine")
    ap.add_argument("--rpm", type=float)
    ap.add_argument("--load", type=float)
    ap.add_argument("--deg", type=float)
    ap.add_argument("--cycles", type=int, default=40)
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    if a.engine:
        rpm = a.rpm or POINTS[a.engine][0][0]
        load = a.load if a.load is not None else POINTS[a.engine][0][1]
        cases = [(a.engine, rpm, load, d) for d in ((a.deg,) if a.deg is not None else OFFSETS)]
        seed = a.seed or 1
    elif a.tune:
        cases = [(e, r, ld, d) for e, r, ld in TUNE for d in TUNE_OFFSETS]
        seed = a.seed or 1
    else:
        offs = tuple(float(x) for x in a.offsets.split(",")) if a.offsets else OFFSETS
        cases = [(e, r, ld, d) for e, pts in POINTS.items() for r, ld in pts for d in offs
                 if not ((e, r, ld) in TUNE and d in TUNE_OFFSETS) and not (a.flexible and d == 0.0)]
        seed = a.seed or 2
    rows = []
    for e, r, ld, d in cases:
        row = case(e, r, ld, d, a.cycles, seed, a.flexible)
        rows.append(row)
        print(line(row), flush=True)
    errs = np.array([x for r in rows for x in np.array(r["found_deg"]) - r["truth_deg"]])
    print(f"{sum(r['pass'] for r in rows)}/{len(rows)} cases within {TOLERANCE_DEG} deg; rms error "
          f"{math.sqrt(np.mean(errs**2)):.3f} deg over {errs.size} cylinder estimates; "
          f"{sum(r['within_2sigma'] for r in rows)}/{sum(r['n_cyl'] for r in rows)} within 2 sigma, "
          f"{sum(r['within_2sigma_core'] for r in rows)} within 2 sigma(fit only)")
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
