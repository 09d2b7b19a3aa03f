"""Tune how a leak past the rings is sized from the pressure apart from the logs that validate it (issue 27 item 3;
design note 97).

    python -m bench.calibrate_blow_by [--write]     # the tuning logs: each cylinder's compression against its siblings'

core.discrepancy.pressure_channel names blow_by where the monitor flags a cylinder's compression (blow_by_cyl<k>)
and sizes it as mass_loss = BLOW_BY_SHARE_SCALE / (LEAK_GAMMA x share) x the ln deficit of its compression pressure
against the siblings' (the ring indicators' compression_ratio, read ~30 deg before TDC; share: the leak's share gone
by then, core.discrepancy.leak_share, from the log's own mean pressure), 1 sigma from BLOW_BY_REL (the sizes'
relative spread) and BLOW_BY_FLOOR_LN (a healthy cylinder's persistent offset) among others (design notes 97, 149). Each tuning log: the product's simulator
(default realistic effects on), CYCLES cycles, the monitor's run as the workflow makes it (residuals.run_model,
pinned), the mean deficit over the cycles after the workflow's warm-up. Tuned on points and seeds no matrix row runs
(bench.bench_discrepancy: k9k 1800/0.6 and 3000/0.9, maruti 1500/0.5 and 4000/0.8) nor bench.discrepancy_null's:
the matrix's blow_by and worn-ring-with-leak rows validate it.

- BLOW_BY_SHARE_SCALE: the least-squares scale through the origin of the hidden mass_loss on the leaking cylinders'
  deficit / (LEAK_GAMMA x share) (what the share's approximations -- a constant trapped mass, the mean trace's
  temperature, gamma -- leave: one number; design note 97's one factor for every engine was BLOW_BY_PER_LN);
- BLOW_BY_REL: the rms relative error of that scale's sizes over the leak logs, x MARGIN, rounded up;
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
from frictionwatch.core.discrepancy.leak_share import LEAK_GAMMA, leak_share, mean_pressure  # noqa: E402
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


def deficits(engine: str, rpm: float, load: float, seed: int, leaks) -> tuple[np.ndarray, np.ndarray, float]:
    """(z,) each cylinder's mean ln compression pressure against its siblings' after the warm-up, (z,) the cycles
    the monitor flagged its compression as a leak, and the leak's share gone by the reading (leak_share, from the
    same cycles' mean pressure, as the workflow reads it)."""
    spec = load_engine(engine)
    effects = [make_effect("blow_by", {"cylinder": c, "mass_loss": m}) for c, m in leaks]
    sim = simulate(spec, rpm, load, CYCLES, seed, effects=effects)
    cycles, _ = assembled_cycles(spec, sim.info, sim.records)
    res = run_model(EngineModel.from_spec(spec), reference(cycles), pinned_config(), cycles)
    warmup = Options().warmup
    scored = res.index >= cycles[warmup].index
    share = leak_share(spec, *mean_pressure(cycles[warmup:]))
    return np.nanmean(res.compression_ln[scored], axis=0), res.leak_flagged[scored].sum(axis=0), share


def case_text(engine: str, rpm: float, load: float, seed: int, leaks) -> str:
    return str(Case(engine, rpm, load, seed, tuple(f"blow_by:cylinder={c},mass_loss={m:g}" for c, m in leaks)))


def tune() -> dict:
    healthy, leak = [], []
    rows = []
    for engine, rpm, load, seed in TUNE:
        for leaks in LEAKS:
            d, flags, share = deficits(engine, rpm, load, seed, leaks)
            rows.append({"case": case_text(engine, rpm, load, seed, leaks), "deficit_ln": d.round(5).tolist(),
                         "flagged": flags.tolist(), "share": round(share, 5)})
            print(json.dumps(rows[-1]), flush=True)
            if not leaks:
                healthy += d.tolist()
            for c, m in leaks:
                leak.append((m, float(d[c - 1]) / (LEAK_GAMMA * share), float(d[c - 1])))
    m, x, d = np.array(leak).T
    scale = float(np.sum(m * -x) / np.sum(x * x))
    rel = float(np.sqrt(np.mean((scale * -x / m - 1.0) ** 2)))
    # the one factor of design note 97 on the same logs, for comparison
    per_ln = float(np.sum(m * -d) / np.sum(d * d))
    rel_one = float(np.sqrt(np.mean((per_ln * -d / m - 1.0) ** 2)))
    floor = float(np.sqrt(np.mean(np.square(healthy))))
    return {"rows": rows, "scale": scale, "rel": rel, "one_factor": per_ln, "rel_one_factor": rel_one,
            "floor_ln": floor, "on": [r["case"] for r in rows]}


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
            "BLOW_BY_SHARE_SCALE": Tuned(round(out["scale"], 3), by, on,
                                         f"the least-squares scale through the origin of the hidden mass_loss on the "
                                         f"leaking cylinder's mean ln compression deficit against its siblings' over "
                                         f"LEAK_GAMMA x the leak's share gone by the reading, {n_leak} leak logs "
                                         f"({CYCLES} cycles): {out['scale']:.4f}, rounded", day),
            "BLOW_BY_REL": Tuned(round_up(MARGIN * out["rel"]), by, on,
                                 f"the rms relative error of BLOW_BY_SHARE_SCALE's sizes over the same logs: "
                                 f"{out['rel']:.4f}, x {MARGIN:g}, rounded up (one factor for every log: "
                                 f"{out['rel_one_factor']:.4f})", day),
            "BLOW_BY_FLOOR_LN": Tuned(round_up(MARGIN * out["floor_ln"]), by, on,
                                      f"the rms mean ln compression deficit against the siblings' of every cylinder "
                                      f"of the {len(TUNE)} healthy logs: {out['floor_ln']:.5f}, x {MARGIN:g}, "
                                      "rounded up", day)})


if __name__ == "__main__":
    main()
