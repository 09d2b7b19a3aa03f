"""The found parameters' sigma, calibrated apart from the matrix that validates it (issue 27 item 2: the truth within
2 sigma in >= 90 % of the matrix). Not run by the test suite.

    python -m bench.discrepancy_sigma [--engine E ...] [--out FILE] [--write]
    python -m bench.discrepancy_sigma --rows FILE... [--write]     # again from saved --out files

Runs the hidden-effect matrix's judged cases (bench.discrepancy_cases CASES, with a main parameter) on each engine
at a TUNE operating point and seed that the matrix does not use (its points are discrepancy_cases ENGINES', its
seeds 1 and 2), and prints, over the cases named right (a parameter stopped at its bound left out): each
z = (found - truth) / sigma and the share within 2 sigma. What the fit's sigma (statistics and the model-error floor,
core.discrepancy.fit.parameter_sigma) leaves out is the effect's own model error, relative to its size: the smallest
EFFECT_REL_ERROR (to 2 figures, rounded up) that puts 90 % of them within 2 sigma is printed, and written into
core/discrepancy/tuned.json with --write; the matrix then validates it.
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
from frictionwatch.core.discrepancy.fit import EFFECT_REL_ERROR  # noqa: E402
from frictionwatch.core.discrepancy.tuned import TUNED_PATH, Tuned, round_up, write_tuned  # noqa: E402
from frictionwatch.core.model.effects import EFFECTS  # noqa: E402

from bench.bench_discrepancy import matrix  # noqa: E402
from bench.discrepancy_cases import ENGINES, cases_for  # noqa: E402

# one operating point and seed per engine, inside its speed range, none a log of the matrix (ENGINES points x seeds
# 1-2) nor of bench/discrepancy_null.py (tests/core/test_tuned_provenance.py)
TUNE = {"k9k-4cyl": ((2200.0, 0.7), 3), "maruti-3cyl": ((2600.0, 0.6), 4), "deutz-1cyl": ((2200.0, 0.7), 3),
        "genset-v20": ((1450.0, 0.6), 3)}
COVERAGE = 0.9


def _specs(effect: str) -> tuple:
    specs = EFFECTS[effect].candidate
    return tuple(s for s in (specs if isinstance(specs, tuple) else (specs,)) if s is not None)


def no_effect_value(effect: str, param: str) -> float:
    """The parameter's value at which the effect does nothing (its candidate's x0)."""
    return next(s.x0[s.params.index(param)] for s in _specs(effect) if param in s.params)


def at_bound(effect: str, value: float) -> bool:
    """Whether ``value`` is a bound of one of the effect's candidate parameters: a fit stopped there says nothing
    of its sigma (the mismatch laws' fraction is bounded at 1, the matrix's truth)."""
    return any(np.isclose(value, b, rtol=0, atol=1e-12) for s in _specs(effect) for b in (*s.lo, *s.hi))


def z_scores(engine: str, cycles: int = 120) -> list[dict]:
    point, seed = TUNE[engine]
    assert point not in ENGINES[engine]["points"]
    judged = [label for label, truths, _ in cases_for(engine) if any(t[2] is not None for t in truths)]
    mains = {label: {t[0]: t[2] for t in truths} for label, truths, _ in cases_for(engine)}
    rows = matrix(cycles, (point,), (seed,), judged, engine)["rows"]
    out = []
    for r in rows:
        if not r.get("named_right"):
            continue
        for c in r.get("checks", []):
            if c.get("found") and c.get("sigma") and not at_bound(c["effect"], c["parameter"]):
                x0 = no_effect_value(c["effect"], mains[r["case"]][c["effect"]])
                size = abs(c["parameter"] - x0)
                out.append({"engine": engine, "case": r["case"], "effect": c["effect"], "truth": c["truth"],
                            "found": c["parameter"], "sigma": c["sigma"], "size": size,
                            # the sigma without the effect's own part at the EFFECT_REL_ERROR it ran with
                            "sigma_fit": float(np.sqrt(max(c["sigma"] ** 2 - (EFFECT_REL_ERROR * size) ** 2, 0.0))),
                            "z": (c["parameter"] - c["truth"]) / c["sigma"]})
    return out


def rel_error_for(zs: list[dict], coverage: float = COVERAGE) -> float:
    """The smallest relative error e (bisection) with the ``coverage`` quantile of |found - truth| /
    sqrt(sigma_fit^2 + (e size)^2) at most 2."""
    err = np.abs([z["found"] - z["truth"] for z in zs])
    fit_sigma, size = np.array([z["sigma_fit"] for z in zs]), np.array([z["size"] for z in zs])

    def q(e: float) -> float:
        return float(np.quantile(err / np.hypot(fit_sigma, e * size), coverage))

    lo, hi = 0.0, 1.0
    if q(lo) <= 2.0:
        return 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if q(mid) <= 2.0 else (mid, hi)
    return hi


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engine", action="append", choices=sorted(TUNE))
    ap.add_argument("--rows", type=Path, nargs="+", help="saved --out files instead of new runs")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--write", action="store_true", help="write EFFECT_REL_ERROR and its provenance into "
                                                         "core/discrepancy/tuned.json")
    args = ap.parse_args()
    if args.rows:
        zs = [z for path in args.rows for z in json.loads(path.read_text())["rows"]]
    else:
        zs = [z for e in (args.engine or sorted(TUNE)) for z in z_scores(e)]
    for z in zs:
        print(f"{z['engine']:12s} {z['case']:30s} {z['effect']:18s} truth {z['truth']:<10.4g} found "
              f"{z['found']:<10.4g} sigma {z['sigma']:<9.3g} z {z['z']:+.2f}")
    a = np.abs([z["z"] for z in zs])
    rel = rel_error_for(zs) if zs else float("nan")
    summary = {"named_right": len(zs), "within_2_sigma": int(np.sum(a <= 2.0)), "effect_rel_error": rel}
    print(json.dumps(summary))
    if args.out:
        args.out.write_text(json.dumps({"rows": zs, **summary}, indent=1))
    if args.write:
        engines = sorted({z["engine"] for z in zs})
        on = tuple(f"{e} {TUNE[e][0][0]:g} rpm {TUNE[e][0][1]:g} seed {TUNE[e][1]}" for e in engines)
        figure = (f"{summary['within_2_sigma']} of {summary['named_right']} found parameters within 2 sigma at "
                  f"EFFECT_REL_ERROR {EFFECT_REL_ERROR:g}; the smallest relative error of the found effect's size "
                  f"that puts 90 % within 2 sigma: {rel:.4f}, rounded up")
        write_tuned({"EFFECT_REL_ERROR": Tuned(round_up(rel), "python -m bench.discrepancy_sigma --write", on, figure,
                                               date.today().isoformat())})
        print(f"EFFECT_REL_ERROR {round_up(rel):g} written to {TUNED_PATH}")


if __name__ == "__main__":
    main()
