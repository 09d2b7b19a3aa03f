"""The found parameters' sigma, calibrated apart from the matrix that validates it (issue 27 item 2: the truth within
2 sigma in >= 90 % of the matrix). Not run by the test suite.

    python -m bench.discrepancy_sigma [--engine E ...] [--out FILE]

Runs the hidden-effect matrix's judged cases (bench.bench_discrepancy CASES, with a main parameter) on each engine
at a TUNE operating point and seed that the matrix does not use (its points are bench_discrepancy ENGINES', its
seeds 1 and 2), and prints, over the cases named right (a parameter stopped at its bound left out): each z = (found - truth) / sigma, the share within 2 sigma,
and the factor every sigma would need for 90 % of them to be within 2 sigma (the 90th percentile of |z|, over 2).
A factor above 1 is what core.discrepancy.fit.SIGMA_SCALE is set to (rounded up); the matrix then validates it.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
from datetime import date  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from frictionwatch.core.discrepancy.fit import SIGMA_SCALE  # noqa: E402
from frictionwatch.core.discrepancy.tuned import TUNED_PATH, Tuned, round_up, write_tuned  # noqa: E402
from frictionwatch.core.model.effects import EFFECTS  # noqa: E402

from bench.bench_discrepancy import ENGINES, cases_for, matrix  # noqa: E402

# one operating point and seed per engine, inside its speed range, none of the matrix's (ENGINES points, seeds 1-2)
TUNE = {"k9k-4cyl": ((2200.0, 0.7), 3), "maruti-3cyl": ((2600.0, 0.6), 3), "deutz-1cyl": ((2200.0, 0.7), 3),
        "genset-v20": ((1450.0, 0.6), 3)}
COVERAGE = 0.9


def at_bound(effect: str, value: float) -> bool:
    """Whether ``value`` is a bound of one of the effect's candidate parameters: a fit stopped there says nothing
    of its sigma (the mismatch laws' fraction is bounded at 1, the matrix's truth)."""
    specs = EFFECTS[effect].candidate
    specs = specs if isinstance(specs, tuple) else (specs,)
    return any(np.isclose(value, b, rtol=0, atol=1e-12) for s in specs if s is not None for b in (*s.lo, *s.hi))


def z_scores(engine: str, cycles: int = 120) -> list[dict]:
    point, seed = TUNE[engine]
    assert point not in ENGINES[engine]["points"]
    judged = [label for label, truths, _ in cases_for(engine) if any(t[2] is not None for t in truths)]
    rows = matrix(cycles, (point,), (seed,), judged, engine)["rows"]
    out = []
    for r in rows:
        if not r.get("named_right"):
            continue
        for c in r.get("checks", []):
            if c.get("found") and c.get("sigma") and not at_bound(c["effect"], c["parameter"]):
                out.append({"engine": engine, "case": r["case"], "effect": c["effect"], "truth": c["truth"],
                            "found": c["parameter"], "sigma": c["sigma"],
                            "z": (c["parameter"] - c["truth"]) / c["sigma"]})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engine", action="append", choices=sorted(TUNE))
    ap.add_argument("--out", type=Path)
    ap.add_argument("--write", action="store_true", help="write SIGMA_SCALE (the current one x the factor, never "
                                                         "below 1, rounded up) into core/discrepancy/tuned.json")
    args = ap.parse_args()
    zs = [z for e in (args.engine or sorted(TUNE)) for z in z_scores(e)]
    for z in zs:
        print(f"{z['engine']:12s} {z['case']:30s} {z['effect']:18s} truth {z['truth']:<10.4g} found "
              f"{z['found']:<10.4g} sigma {z['sigma']:<9.3g} z {z['z']:+.2f}")
    a = np.abs([z["z"] for z in zs])
    factor = float(np.quantile(a, COVERAGE)) / 2.0 if a.size else float("nan")
    summary = {"named_right": len(zs), "within_2_sigma": int(np.sum(a <= 2.0)),
               "factor_for_90_percent": factor}
    print(json.dumps(summary))
    if args.out:
        args.out.write_text(json.dumps({"rows": zs, **summary}, indent=1))
    if args.write:
        engines = args.engine or sorted(TUNE)
        on = tuple(f"{e} {TUNE[e][0][0]:g} rpm {TUNE[e][0][1]:g} seed {TUNE[e][1]}" for e in engines)
        value = round_up(max(1.0, SIGMA_SCALE * factor))
        figure = (f"{summary['within_2_sigma']} of {summary['named_right']} found parameters within 2 sigma at scale "
                  f"{SIGMA_SCALE:g}; the 90th percentile of |z| {2.0 * factor:.3f}, so x {factor:.3f}, rounded up")
        write_tuned({"SIGMA_SCALE": Tuned(value, "python -m bench.discrepancy_sigma --write", on, figure,
                                          date.today().isoformat())})
        print(f"SIGMA_SCALE {value:g} written to {TUNED_PATH}")


if __name__ == "__main__":
    main()
