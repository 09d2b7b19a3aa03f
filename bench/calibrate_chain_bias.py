"""Tune the shaft line's own bias in a fitted chain stiffness apart from the logs that validate it (issue 27 item 2;
design note 103).

    python -m bench.calibrate_chain_bias [--engine E] [--out FILE]     # the tuning logs through the workflow
    python -m bench.calibrate_chain_bias --rows FILE... [--write]      # again from saved --out files

The chain 50 % stiffer on k9k was named in tolerance but 2.7-7.6 sigma low on every matrix row (design note 101): the
fit converges, and the monitor's shaft line reads a stiffer plant's low by 8-24 % of the excess, a model error that
grows with the distance from the record's line and that neither CHAIN_FLOOR (a healthy log's error, near 1) nor
EFFECT_REL_ERROR carries. core.discrepancy.fit's CHAIN_STIFFNESS_REL (tuned.json CHAIN_STIFFNESS_REL) is that error
relative to the fitted excess |stiffness_scale - 1|, added in quadrature to the fit's sigma (fit.parameter_floor).

Each tuning log: the product's simulator with the chain's stiffness scaled by S (damping as recorded), default
realistic effects on, 120 cycles (the matrix's), at operating points and seeds no matrix row runs; the workflow
(discover, default Options) as the matrix runs it. Over the logs that name chain_mismatch at a fitted point, the
smallest relative error that puts every one's truth within 2 sigma (sigma the fit's without CHAIN_STIFFNESS_REL),
rounded up; the matrix (bench.bench_discrepancy --case "chain_mismatch" / "chain_mismatch -20%") then validates it.
A fit that stopped at one of the candidate's start points (its seeds, 0.75 and 4/3 with the damping at 1: the refinement
never moved from there) is counted and said, not used: it is a fit that did not converge, on the wrong side of 1 as
often as not (k9k 2000/0.5 with the truth 1.7: 0.75), which no error relative to |x - 1| describes. Since design note
106 the refinement fits from a start point (fit._from_start) and a fit still ending at one is refused
(choice.not_fitted): the stored tuning rows predate it (3 of 34 named stopped there); not re-run since.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from datetime import date  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from frictionwatch.core.discrepancy import discover, fit  # noqa: E402
from frictionwatch.core.discrepancy.candidates import candidate_library  # noqa: E402
from frictionwatch.core.discrepancy.fit import CHAIN_STIFFNESS_REL  # noqa: E402
from frictionwatch.core.discrepancy.tuned import TUNED_PATH, Tuned, round_up, write_tuned  # noqa: E402
from frictionwatch.core.model.effects import make_effect  # noqa: E402
from frictionwatch.core.model.engine import load_engine  # noqa: E402
from frictionwatch.core.model.engine_model import EngineModel  # noqa: E402
from frictionwatch.core.tuned import Case  # noqa: E402

from bench.discrepancy_cases import ENGINES, cycles_of  # noqa: E402

CYCLES = 120
SCALES = (0.8, 1.3, 1.5, 1.7)
SEEDS = (31, 32, 33)
# operating points no matrix row runs (discrepancy_cases ENGINES: k9k 1800/0.6, 3000/0.9; maruti 1500/0.5, 4000/0.8)
# k9k also beside its matrix points (1700, 1900 beside 1800; 2900, 3200 beside 3000), where the bias was seen
POINTS = {"k9k-4cyl": ((2000.0, 0.5), (2300.0, 0.7), (2700.0, 0.8), (1700.0, 0.6), (1900.0, 0.7), (2900.0, 0.9),
                       (3200.0, 0.8)),
          "maruti-3cyl": ((2500.0, 0.6), (3300.0, 0.7))}
NAME = "CHAIN_STIFFNESS_REL"


def logs(engine: str) -> list[tuple[float, float, int, float]]:
    """(rpm, load, seed, S): every scale at every point, the seeds in turn (one log each: the workflow costs ~10-30 s
    of CPU a log)."""
    out = []
    for i, (rpm, load) in enumerate(POINTS[engine]):
        assert (rpm, load) not in ENGINES[engine]["points"]
        for j, s in enumerate(SCALES):
            out.append((rpm, load, SEEDS[(i + j) % len(SEEDS)], s))
    return out


def run_log(engine: str, rpm: float, load: float, seed: int, scale: float) -> dict:
    effects = [make_effect("chain_mismatch", {"stiffness_scale": scale})]
    c0 = time.process_time()
    model, cycles = cycles_of(rpm, load, CYCLES, seed, effects, "default", engine)
    doc = discover(model, cycles).to_json()
    hit = next((f for f in doc["found"] if f["effect"] == "chain_mismatch"), None)
    row = {"engine": engine, "rpm": rpm, "load": load, "seed": seed, "truth": scale, "outcome": doc["outcome"],
           "found": [f["effect"] for f in doc["found"]], "rel_in_force": CHAIN_STIFFNESS_REL,
           "cpu_s": round(time.process_time() - c0, 1)}
    if hit is not None:
        x, sigma = hit["parameters"]["stiffness_scale"], hit["sigma"]["stiffness_scale"]
        # the fit's own sigma: the relative error in force taken back out (it enters in quadrature)
        fit_sigma = float(np.sqrt(max(sigma**2 - (CHAIN_STIFFNESS_REL * abs(x - 1.0)) ** 2, 0.0)))
        row.update({"x": x, "sigma": sigma, "sigma_fit": fit_sigma, "z": (x - scale) / sigma,
                    "damping": hit["parameters"].get("damping_scale")})
    return row


def at_start(row: dict) -> bool:
    """Whether the fit stopped at one of the chain candidate's start points (stiffness and damping both a seed's)."""
    cand = next(c for c in candidate_library(EngineModel.from_spec(load_engine(row["engine"])))
                if c.effect == "chain_mismatch")
    return fit.at_start(cand, np.array([row["x"], row["damping"]]))


def rel_needed(row: dict) -> float:
    """The relative error of |x - 1| that, added in quadrature to the fit's sigma, puts the truth at 2 sigma."""
    d, excess = abs(row["x"] - row["truth"]), abs(row["x"] - 1.0)
    return float(np.sqrt(max((d / 2.0) ** 2 - row["sigma_fit"] ** 2, 0.0)) / excess) if excess > 0 else 0.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engine", action="append", choices=sorted(POINTS))
    ap.add_argument("--rows", type=Path, nargs="+", help="saved --out files instead of new runs")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--point", action="append", help="only these operating points, RPM/LOAD (e.g. 1700/0.6)")
    ap.add_argument("--write", action="store_true", help=f"write {NAME} and its provenance into {TUNED_PATH}")
    args = ap.parse_args()
    if args.rows:
        rows = [r for path in args.rows for r in json.loads(path.read_text())["rows"]]
    else:
        rows = []
        for e in args.engine or sorted(POINTS):
            for rpm, load, seed, s in logs(e):
                if args.point and f"{rpm:g}/{load:g}" not in args.point:
                    continue
                rows.append(run_log(e, rpm, load, seed, s))
                print(json.dumps(rows[-1]), flush=True)
                if args.out:
                    args.out.write_text(json.dumps({"rows": rows}, indent=1))
    named = [r for r in rows if "x" in r]
    stuck = [r for r in named if at_start(r)]
    fitted = [r for r in named if not at_start(r)]
    for r in rows:
        said = (f"x {r['x']:.4f} +- {r['sigma']:.4f} (fit {r['sigma_fit']:.4f}), bias {r['x'] - r['truth']:+.4f} "
                f"= {(r['x'] - r['truth']) / (r['truth'] - 1.0):+.1%} of the excess, needs {rel_needed(r):.4f}"
                + (" (stopped at a start point: not used)" if at_start(r) else "")
                if "x" in r else f"chain not named: {r['outcome']} {r['found']}")
        print(f"{r['engine']:12s} {r['rpm']:g}/{r['load']:g} s{r['seed']} S {r['truth']:g}: {said}")
    rel = max((rel_needed(r) for r in fitted), default=float("nan"))
    print(json.dumps({"logs": len(rows), "named": len(named), "at_start": len(stuck), "rel_needed_max": rel}))
    if args.write:
        on = tuple(str(Case(r["engine"], r["rpm"], r["load"], r["seed"],
                            (f"chain_mismatch:stiffness_scale={r['truth']:g}",))) for r in rows)
        figure = (f"the smallest relative error of the fitted excess |stiffness_scale - 1| that puts every tuning "
                  f"fit's truth within 2 sigma ({len(fitted)} fits; of {len(rows)} logs {len(named)} named the chain, "
                  f"{len(stuck)} of them stopped at a start point, not used; scales "
                  f"{', '.join(f'{s:g}' for s in SCALES)}; {CYCLES} cycles): {rel:.4f}, rounded up")
        write_tuned({NAME: Tuned(round_up(rel), "python -m bench.calibrate_chain_bias --write", on, figure,
                                 date.today().isoformat())})
        print(f"{NAME} {round_up(rel):g} written to {TUNED_PATH}")


if __name__ == "__main__":
    main()
