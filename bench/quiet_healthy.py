"""Healthy logs through the discrepancy workflow with and without the floored test on a quiet residual, in one run
(issue 27: something named on a healthy log <= 5 %; design note 61).

    python -m bench.quiet_healthy

Each log: the product's simulator (default realistic effects on, nothing hidden), the workflow with
Options(max_steps=2) twice -- ``floored_when_quiet=False`` (the plain held-out test alone, as before note 61) and
True (choice.within_model_error) -- and the count of logs on which something is named, each way. The logs: note 53's
validation list (bench.calibrate_chain_floor.VALIDATE; its last, deutz 3000 rpm 0.9 seed 5, is the defect's log at
84 cycles: not a validation of this rule) and MORE, seeds none of the matrices' (1-3), the chain floor's tuning logs
nor VALIDATE's. Nothing is tuned here: the rule's numbers are the workflow's min_delta_chi2 and the healthy gap's
ratio 1.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import time  # noqa: E402

from frictionwatch.core.discrepancy import Options, discover  # noqa: E402
from frictionwatch.core.model.engine_model import EngineModel  # noqa: E402

from bench.calibrate_chain_floor import VALIDATE, healthy_cycles  # noqa: E402

# (engine, rpm, load, seed, cycles): the brief's points (k9k 1800/2000/3000 rpm, maruti, deutz) at seeds 9 and 11
MORE = tuple((e, r, ld, s, 84) for e, r, ld in (("k9k-4cyl", 1800.0, 0.6), ("k9k-4cyl", 2000.0, 0.6),
                                                 ("k9k-4cyl", 3000.0, 0.9), ("maruti-3cyl", 1500.0, 0.5),
                                                 ("maruti-3cyl", 4000.0, 0.8), ("deutz-1cyl", 1500.0, 0.6),
                                                 ("deutz-1cyl", 3000.0, 0.9))
             for s in (9, 11))


def _named(doc: dict) -> list[str]:
    return [f"{f['effect']}[{f['cylinder']}] " + ", ".join(f"{k} {v:.4g} +- {f['sigma'].get(k, float('nan')):.2g}"
                                                          for k, v in f["parameters"].items())
            for f in doc["found"]]


def main() -> None:
    counts = {False: 0, True: 0}
    logs = VALIDATE + MORE
    for e, r, ld, s, n in logs:
        spec, cycles = healthy_cycles(e, r, ld, s, n)
        said = []
        for floored in (False, True):
            t0 = time.process_time()
            doc = discover(EngineModel.from_spec(spec), cycles,
                           Options(max_steps=2, floored_when_quiet=floored)).to_json()
            named = _named(doc)
            counts[floored] += bool(named)
            said.append(f"{'after' if floored else 'before'}: {doc['outcome']}, named {named or 'nothing'}, refused "
                        f"{[x['candidate'] for x in doc['refused']]} ({time.process_time() - t0:.1f} s CPU)")
        print(f"{e} {r:g} rpm {ld:g} seed {s}, {n} cycles -- " + "; ".join(said), flush=True)
    print(f"named on {counts[False]} of {len(logs)} healthy logs before, {counts[True]} of {len(logs)} after")


if __name__ == "__main__":
    main()
