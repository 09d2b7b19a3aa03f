"""Tune how a leak past the rings is sized from the pressure apart from the logs that validate it (issue 27 item 3;
design note 97).

    python -m bench.calibrate_blow_by [--write]     # the tuning logs: each cylinder's compression against its siblings'

core.discrepancy.pressure_channel names blow_by where the monitor flags a cylinder's compression (blow_by_cyl<k>)
and sizes it as mass_loss = BLOW_BY_PER_LN x the ln deficit of its compression pressure against the siblings' (the
ring indicators' compression_ratio, read ~30 deg before TDC), 1 sigma from BLOW_BY_REL (the factor's relative spread)
and BLOW_BY_FLOOR_LN (a healthy cylinder's persistent offset) among others. Each tuning log: the product's simulator
(default realistic effects on), CYCLES cycles, the monitor's run as the workflow makes it (residuals.run_model,
pinned), the mean deficit over the cycles after the workflow's warm-up. Tuned on points and seeds no matrix row runs
(bench.bench_discrepancy: k9k 1800/0.6 and 3000/0.9, maruti 1500/0.5 and 4000/0.8) nor bench.discrepancy_null's:
the matrix's blow_by and worn-ring-with-leak rows validate it.

- BLOW_BY_PER_LN: the least-squares factor through the origin of the hidden mass_loss on the leaking cylinders'
  deficits (the leak's share lost before the reading depends on the engine and the point: one factor, its spread
  in BLOW_BY_REL);
- BLOW_BY_REL: the rms relative error of that factor's sizes over the leak logs, x MARGIN, rounded up;
- BLOW_BY_FLOOR_LN: the rms mean deficit of every cylinder of the healthy logs, x MARGIN, rounded up.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
from datetime import date  # noqa: E402

import numpy as np  # noqa: E402
from frictionwatch.core.discrepancy import Options  # noqa: E402
from frictionwatch.core.discrepancy.residuals import pinned_config, run_model  # noqa: E402
from frictionwatch.core.discrepancy.tuned import Tuned, round_up, write_tuned  # noqa: E402
from frictionwatch.core.model.effects import make_effect  # noqa: E402
from frictionwatch.core.model.engine import load_engine  # noqa: E402
from frictionwatch.core.model.engine_model import EngineModel  # noqa: E402
from frictionwatch.core.model.view import reference  # noqa: E402
from frictionwatch.core.plant.simulate import simulate  # noqa: E402
from frictionwatch.core.tuned import Case  # noqa: E402
from frictionwatch.service.pipeline import assembled_cycles  # noqa: E402

CYCLES = 120
MARGIN = 1.5
# (engine, rpm, load, seed): none of the matrix's points nor seeds (1-5), other speeds and loads of both engines
TUNE = (("k9k-4cyl", 2300.0, 0.7, 31), ("k9k-4cyl", 2700.0, 0.8, 32), ("k9k-4cyl", 2000.0, 0.5, 33),
        ("maruti-3cyl", 2500.0, 0.6, 31), ("maruti-3cyl", 3300.0, 0.7, 32), ("maruti-3cyl", 2000.0, 0.5, 33))
# per point: healthy, and a leak of 8 % on cylinder 2 and one of 16 % on cylinder 3 (the matrix's 12 % between)
LEAKS = ((), ((2, 0.08),), ((3, 0.16),))


def deficits(engine: str, rpm: float, load: float, seed: int, leaks) -> tuple[np.ndarray, np.ndarray]:
    """(z,) each cylinder's mean ln compression pressure against its siblings' after the warm-up, and (z,) the
    cycles the monitor flagged its compression as a leak."""
    spec = load_engine(engine)
    effects = [make_effect("blow_by", {"cylinder": c, "mass_loss": m}) for c, m in leaks]
    sim = simulate(spec, rpm, load, CYCLES, seed, effects=effects)
    cycles, _ = assembled_cycles(spec, sim.info, sim.records)
    res = run_model(EngineModel.from_spec(spec), reference(cycles), pinned_config(), cycles)
    scored = res.index >= cycles[Options().warmup].index
    return np.nanmean(res.compression_ln[scored], axis=0), res.leak_flagged[scored].sum(axis=0)


def case_text(engine: str, rpm: float, load: float, seed: int, leaks) -> str:
    return str(Case(engine, rpm, load, seed, tuple(f"blow_by:cylinder={c},mass_loss={m:g}" for c, m in leaks)))


def tune() -> dict:
    healthy, leak = [], []
    rows = []
    for engine, rpm, load, seed in TUNE:
        for leaks in LEAKS:
            d, flags = deficits(engine, rpm, load, seed, leaks)
            rows.append({"case": case_text(engine, rpm, load, seed, leaks), "deficit_ln": d.round(5).tolist(),
                         "flagged": flags.tolist()})
            print(json.dumps(rows[-1]), flush=True)
            if not leaks:
                healthy += d.tolist()
            for c, m in leaks:
                leak.append((m, float(d[c - 1])))
    m, d = np.array(leak).T
    per_ln = float(np.sum(m * -d) / np.sum(d * d))
    rel = float(np.sqrt(np.mean((per_ln * -d / m - 1.0) ** 2)))
    floor = float(np.sqrt(np.mean(np.square(healthy))))
    return {"rows": rows, "per_ln": per_ln, "rel": rel, "floor_ln": floor,
            "on": [r["case"] for r in rows]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="write the three numbers into core/discrepancy/tuned.json")
    args = ap.parse_args()
    out = tune()
    print(json.dumps({k: v for k, v in out.items() if k != "rows"}, indent=1))
    if args.write:
        day, by, on = date.today().isoformat(), "python -m bench.calibrate_blow_by --write", out["on"]
        n_leak = len(TUNE) * sum(1 for x in LEAKS if x)
        write_tuned({
            "BLOW_BY_PER_LN": Tuned(round(out["per_ln"], 2), by, on,
                                    f"the least-squares factor through the origin of the hidden mass_loss on the "
                                    f"leaking cylinder's mean ln compression deficit against its siblings' over "
                                    f"{n_leak} leak logs ({CYCLES} cycles): {out['per_ln']:.3f}, rounded", day),
            "BLOW_BY_REL": Tuned(round_up(MARGIN * out["rel"]), by, on,
                                 f"the rms relative error of BLOW_BY_PER_LN's sizes over the same logs: "
                                 f"{out['rel']:.4f}, x {MARGIN:g}, rounded up", day),
            "BLOW_BY_FLOOR_LN": Tuned(round_up(MARGIN * out["floor_ln"]), by, on,
                                      f"the rms mean ln compression deficit against the siblings' of every cylinder "
                                      f"of the {len(TUNE)} healthy logs: {out['floor_ln']:.5f}, x {MARGIN:g}, "
                                      "rounded up", day)})


if __name__ == "__main__":
    main()
