"""The torque balance's model error on healthy two-point logs (issue 27, design notes 62 and 68): the tools behind
``bench_discrepancy --balance-across-points`` and ``--balance-terms`` (their command lines are there), and the seeds
and margin ``bench.discrepancy_null --tune-kinetic`` tunes features.NULL_KINETIC with."""

from __future__ import annotations

import json

from frictionwatch.core.discrepancy import Options
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.cmd_discrepancy import assemble

from bench.discrepancy_cases import ENGINES, TWO_POINT_CYCLES, cycles_of, two_point_steps


def balance_across_points(seeds: tuple[int, ...]) -> dict:
    """The balance's model error at each point of a healthy two-point log (the matrix's two-point log: dyno engines
    at their point 1, the grid genset at point 0, TWO_POINT_CYCLES cycles, nothing hidden): each point's mean balance
    residual, its sigma, its measured friction and its mean kinetic term (Residuals.kinetic) in the training and the
    held-out half (the workflow's split, Options()), as laws.point_balance reads them, and over both ("all").
    ``figure``: NULL_KINETIC, the smallest share of a point's |mean kinetic term| that, added in quadrature to
    NULL_BALANCE x its friction and 2 sigma of the point mean's own scatter, covers every point's |mean residual| over
    the whole log ("all": the systematic error, least diluted by the scatter a half's 16-32 cycles carry), x
    BALANCE_MARGIN, rounded up (features.balance_point_floor_nm; design note 68). ``largest_ratio``: the largest |mean residual| / friction (note 65's figure). Tune on
    seeds no matrix or test runs (BALANCE_TUNE_SEEDS); SEEDS, the stored s3 rows and seeds 7, 9 validate."""
    import numpy as np
    from frictionwatch.core.discrepancy.features import NULL_BALANCE
    from frictionwatch.core.discrepancy.residuals import pinned_config, run_model
    from frictionwatch.core.model.view import reference
    from frictionwatch.core.tuned import round_up

    opt, rows = Options(), []
    for engine in ENGINES:
        p = 0 if load_engine(engine).load.kind == "grid" else 1
        rpm, load = ENGINES[engine]["points"][p]
        for seed in seeds:
            model, cycles = cycles_of(rpm, load, TWO_POINT_CYCLES, seed, [], "default", engine, None,
                                      two_point_steps(engine, p))
            res = run_model(model, reference(cycles), pinned_config(), cycles)
            split = opt.warmup + (len(cycles) - opt.warmup) // 2
            first, held = cycles[opt.warmup].index, cycles[split].index
            for half, mask in (("train", (res.index >= first) & (res.index < held)), ("held", res.index >= held),
                               ("all", res.index >= first)):
                part = res.take(mask)
                for g in np.unique(part.group if part.group is not None else [0]):
                    i = np.flatnonzero(part.group == g) if part.group is not None else np.arange(part.n_cycles)
                    ok = i[np.isfinite(part.balance[i]) & np.isfinite(part.friction[i])]
                    if g < 0 or ok.size < 2:
                        continue
                    b, f = float(np.mean(part.balance[ok])), float(np.mean(part.friction[ok]))
                    se = float(np.std(part.balance[ok], ddof=1) / np.sqrt(ok.size))
                    k = float(np.mean(part.kinetic[ok]))
                    # the systematic part: beyond NULL_BALANCE's floor and 2 sigma of the mean's own scatter (which
                    # point_balance adds to each point's variance apart)
                    beyond = float(np.sqrt(max(b * b - (NULL_BALANCE * f) ** 2 - (2.0 * se) ** 2, 0.0)))
                    rows.append({"case": f"{engine} {rpm:g} rpm {load:g} seed {seed}", "half": half,
                                 "rpm": float(np.mean(part.omega[ok])) * 30.0 / np.pi, "balance_nm": b,
                                 "sigma_nm": se, "friction_nm": f, "ratio": abs(b) / f, "kinetic_nm": k,
                                 "beyond_balance_floor_nm": beyond,
                                 "of_kinetic": beyond / abs(k) if beyond > 0 else 0.0})
                    print(json.dumps(rows[-1]), flush=True)
    share = max(r["of_kinetic"] for r in rows if r["half"] == "all")
    halves = [r for r in rows if r["half"] != "all"]
    return {"rows": rows, "largest_ratio": max(r["ratio"] for r in halves), "largest_of_kinetic": share,
            "figure": round_up(BALANCE_MARGIN * share), "on": sorted({r["case"] for r in rows})}


def balance_terms(engine: str, seed: int, without: tuple[str, ...] = (), learn_teeth: bool = True) -> dict:
    """Per cycle of a healthy two-point log (as ``balance_across_points``): the balance residual and the terms the
    monitor made it of (its friction from indicated - load - coupling loss - kinetic; the model's friction) beside
    the simulator's truth of the same cycle (friction, indicated, load, coupling loss, and the kinetic term from its
    flywheel speed: at theta = 2 pi and from its cycle-mean speeds with J(2 pi), and from its cycles' angle-averaged
    energies 1/2 J(theta) w^2 as the monitor's since design note 69), with the cycles since the point's first: which
    term is off where (design notes 68, 69). ``without``: default effects off in the plant (sensor_noise,
    tooth_spacing_error); ``learn_teeth``: the monitor's tooth learner."""
    import dataclasses

    import numpy as np
    from frictionwatch.core.discrepancy.residuals import STAGES, CyclePipeline, TdcWatch, pinned_config
    from frictionwatch.core.model.kinematics import variable_inertia
    from frictionwatch.core.model.view import reference
    from frictionwatch.core.monitor.balance.mean_balance import mid_cycle_inertia

    spec = load_engine(engine)
    p = 0 if spec.load.kind == "grid" else 1
    rpm, load = ENGINES[engine]["points"][p]
    sim = simulate(spec, rpm, load, TWO_POINT_CYCLES, seed, effects=[], without=without,
                   load_steps=two_point_steps(engine, p))
    model = EngineModel.from_spec(spec)
    cycles = assemble(model, sim.info, sim.records).cycles
    config = dataclasses.replace(pinned_config(), learn_teeth=learn_teeth)
    stages = tuple(dataclasses.replace(s, per_window=spec.n_cyl, window=len(cycles) + 1) if isinstance(s, TdcWatch)
                   else s for s in STAGES)
    pipe = CyclePipeline(model, config, reference(cycles), stages=stages)
    truth = {c["index"]: c for c in sim.truth["cycles"]}
    w = sim.diagnostics["flywheel_speed_grid_rad_s"]  # (cycles, 720) true flywheel speed, 1-deg grid from theta 0
    inertia = mid_cycle_inertia(spec)
    j_theta = variable_inertia(np.radians(np.arange(w.shape[1]) * 720.0 / w.shape[1]), spec.firing_angles,
                               spec.kinematics_params(), spec.reciprocating_mass, spec.total_inertia)[0]
    energy = 0.5 * np.mean(j_theta * w * w, axis=1)  # each cycle's angle-averaged energy (1-deg grid)
    rows, last_rpm, since = [], None, 0
    for c in cycles:
        r = pipe.process(c).result
        if r is None or r.index not in truth or r.index < 1 or not np.isfinite(r.friction_balance):
            continue
        t = truth[r.index]
        since = 0 if last_rpm is None or abs(r.rpm_mean - last_rpm) > 0.1 * last_rpm else since + 1
        last_rpm = r.rpm_mean if since == 0 else last_rpm
        i = r.index
        rows.append({"index": i, "since": since, "rpm": r.rpm_mean, "residual_nm": r.friction_balance
                     - float(np.mean(r.friction_torque)), "friction_nm": r.friction_balance,
                     "true_friction_nm": t["friction_torque_mean_nm"], "model_friction_nm": float(np.mean(
                         r.friction_torque)), "kinetic_nm": inertia * r.acceleration,
                     "kinetic_true_mid_nm": inertia * (w[i, 360] ** 2 - w[i - 1, 360] ** 2) / (8.0 * np.pi),
                     "kinetic_true_mean_nm": inertia * (w[i].mean() ** 2 - w[i - 1].mean() ** 2) / (8.0 * np.pi),
                     "kinetic_true_energy_nm": (energy[i] - energy[i - 1]) / (4.0 * np.pi),
                     "indicated_nm": r.indicated_window, "true_indicated_nm": t["indicated_torque_nm"],
                     "load_nm": r.load_torque, "true_load_nm": t["load_torque_nm"], "coupling_nm": r.coupling_loss,
                     "true_coupling_nm": t["damper_coupling_loss_nm"]})
    for r in rows:  # what the kinetic term would have to be for the truth's friction
        r["kinetic_needed_nm"] = r["kinetic_nm"] + r["friction_nm"] - r["true_friction_nm"]
    return {"engine": engine, "seed": seed, "without": list(without), "learn_teeth": learn_teeth, "rows": rows}


def balance_terms_points(doc: dict) -> list[dict]:
    """Per point of ``balance_terms``' rows (a block: the rows from one 'since = 0' to the next; blocks whose first
    speeds lie within 15 % pooled as one point): cycles, mean residual and its scatter, the floor NULL_BALANCE x
    the mean friction, and the mean error of the monitor's kinetic term against the one the truth's friction needs
    and against the truth's angle-averaged energies (N m; NaN where a saved output lacks a column)."""
    import numpy as np
    from frictionwatch.core.discrepancy.features import NULL_BALANCE

    points: dict[float, list[dict]] = {}
    block_rpm = None
    for r in doc["rows"]:
        if r["since"] == 0 or block_rpm is None:
            block_rpm = next((k for k in points if abs(r["rpm"] - k) < 0.15 * k), r["rpm"])
        points.setdefault(block_rpm, []).append(r)
    out = []
    for rpm, rows in sorted(points.items()):
        keys = ("residual_nm", "friction_nm", "kinetic_nm", "kinetic_needed_nm", "kinetic_true_energy_nm",
                "kinetic_true_mid_nm")
        col = {k: np.array([r.get(k, np.nan) for r in rows], dtype=float) for k in keys}
        out.append({"rpm": round(rpm), "cycles": len(rows), "residual_nm": float(col["residual_nm"].mean()),
                    "residual_sd_nm": float(col["residual_nm"].std(ddof=1)) if len(rows) > 1 else float("nan"),
                    "floor_nm": NULL_BALANCE * abs(float(col["friction_nm"].mean())),
                    "kinetic_error_nm": float((col["kinetic_nm"] - col["kinetic_needed_nm"]).mean()),
                    "kinetic_vs_true_energy_nm": float((col["kinetic_nm"] - col["kinetic_true_energy_nm"]).mean()),
                    "true_mid_vs_needed_nm": float((col["kinetic_true_mid_nm"] - col["kinetic_needed_nm"]).mean()),
                    "true_energy_vs_needed_nm": float((col["kinetic_true_energy_nm"]
                                                       - col["kinetic_needed_nm"]).mean())})
    return out


# the seeds NULL_KINETIC is tuned on (bench.discrepancy_null --tune-kinetic --write): none a matrix (SEEDS, s3) or a
# test runs
BALANCE_TUNE_SEEDS = (21, 22)
BALANCE_MARGIN = 1.5  # as every floor: the largest healthy figure x 1.5 (bench/discrepancy_null.MARGIN)
