"""Fisher information of genset-v20's friction parameters from the tooth times, as the monitor's own equations hold it.

    nice .venv/bin/python -m bench.information_v20 collect [--cycles 140] [--loads 0.55 0.75 0.95] [--seed 21]
    .venv/bin/python -m bench.information_v20 report                  # -> bench/results/information_v20.json, docs/information/

``collect`` simulates each load (plant noise, tooth-spacing error and combustion variability at their defaults) and
runs the one pipeline (core.monitor.pipeline.CyclePipeline over the pipeline's assembled cycles) with no forgetting.
Per cycle after the warm-up it keeps what the monitor accumulates: the whitened
information A^T A of the flywheel rows (the difference of the accumulator, exact) and of the mean-balance row. For
a second wheel at the free end (the front hub) it evaluates the same harmonic balance with the chain's transfer to
that node (core.model.chain, core.model.dynamics.Receptance.speed_transfer), whitened with the flywheel's noise
model (same tooth count and timer) and with its own in-band tooth-error nuisances. It also keeps each cylinder's
indicated torque and its change for a 0.1 deg TDC shift, and the friction rows d T_f,k / d theta.

``report`` forms the Cramér-Rao bound C(N) = (N I_bar + I_prior)^-1 for N cycles (I_prior: the weak prior and the
tooth-error prior of the nuisances; "with siblings": plus the monitor's sibling prior), each cylinder's relative
friction sigma sqrt(r_k C r_k) / (r_k . 1), the cycles each needs for sigma <= 2.5 % (5 % at 2 sigma), per
configuration: one load, the three loads mixed, and either with the free-end wheel. Floors no cycle count removes:
the monitor's repeatable model error (model_rel_error of each speed harmonic) through its own systematic map, and a
cylinder's TDC and pressure-gain error through its indicated torque.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.kinematics import kinematics
from frictionwatch.core.monitor.balance.harmonic_balance import harmonic_balance, operating_point
from frictionwatch.core.monitor.identify.parameters import prior_normal
from frictionwatch.core.monitor.monitor import CycleRejected
from frictionwatch.core.monitor.pipeline import CyclePipeline
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.monitor.teeth.tooth_fit import fit_cycle_teeth
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles

from bench.information_figures import figures, print_table

ENGINE, RPM = "genset-v20", 1500.0
FREE_END_NODE = "front_hub"
DATA = Path("out/information")
OUT_JSON = Path(__file__).parent / "results" / "information_v20.json"
TARGET_REL = 0.025  # 1-sigma for "within 5 % at 2 sigma"
TDC_STEP_DEG = 0.1


def indicated_torque(spec, grid: np.ndarray, pressure: np.ndarray, shift_deg: float = 0.0) -> np.ndarray:
    """(z,) cycle-mean indicated torque [N m] of each cylinder, its pressure read ``shift_deg`` late (a TDC error)."""
    local = np.mod(grid[None, :] - spec.firing_angles[:, None], 4 * np.pi)
    _, dx, _ = kinematics(local.ravel(), spec.kinematics_params())
    dv = spec.piston_area * dx.reshape(local.shape)
    p = np.empty_like(pressure)
    for k in range(pressure.shape[0]):
        p[k] = np.interp(grid - np.radians(shift_deg), grid, pressure[k], period=4 * np.pi)
    return np.mean(p * dv, axis=1)  # uniform grid over 4 pi: (1/4pi) \oint p dV = mean(p dV/dtheta)


def _fit_and_point(spec, state, cycle, cfg):
    """The monitor's own tooth fit of ``cycle`` and its operating point at the state: (flywheel, theta_start, op)."""
    m = state.n_harmonics
    fly, _, theta_start, _ = fit_cycle_teeth(cycle, spec.sensors.wheel_teeth, m, state.n_nuisance, state.teeth,
                                             state.tooth_patterns, cfg.drift_nuisance, m, cfg.fit_drift,
                                             cfg.tooth_learning)
    op = operating_point(spec, state.op, fly.omega_mean, cycle.load_torque, m, cfg.rebuild_tolerance,
                         cfg.variable_inertia, state.layout)
    return fly, theta_start, op


def second_wheel_design(spec, state, cycle, cfg, node: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """This cycle's speed equations at ``node`` (the monitor's balance with that node's transfer): design (M, P),
    the tooth-fit noise floor (M,) [rad^2/s^2], the flywheel speed harmonics' sizes w_m |Phi_m| (M,) [rad/s] and
    the modelled speed harmonics' sizes at ``node`` (M,) [rad/s]."""
    m = state.n_harmonics
    fly, theta_start, op = _fit_and_point(spec, state, cycle, cfg)
    transfer = np.ascontiguousarray(op.receptance.speed_transfer(node), dtype=np.complex128)
    op2 = replace(op, transfer=transfer, chain=op.chain._replace(transfer=transfer))
    bal = harmonic_balance(op2, state.params, state.n_nuisance, state.relative_motion, state.static, cycle.grid,
                           cycle.pressure, fly, theta_start, cfg.passes, cfg.time_samples)
    freq = 0.5 * fly.omega_mean * np.arange(1, m + 1)
    floor = freq**2 * 2.0 * fly.residual_rms**2 / fly.n_edges
    return bal.rows.design, floor, freq * np.abs(fly.harmonics), np.abs(bal.node_speed[node])


def whitened_info(design: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    a = np.concatenate([design.real, design.imag]) / np.concatenate([sigma, sigma])[:, None]
    return a.T @ a


def collect_load(load: float, cycles: int, seed: int) -> dict:
    """One load's per-cycle averages (see the module doc)."""
    sim = simulate(load_engine(ENGINE), RPM, load, cycles, seed=seed)
    pipe = CyclePipeline(load_engine(ENGINE), MonitorConfig(forgetting=1.0))
    spec, cfg = pipe.view.spec, pipe.monitor_cfg  # the spec and config the monitor runs with
    cycs, _ = assembled_cycles(spec, sim.info, sim.records)
    node = spec.node_names.index(FREE_END_NODE)
    state = pipe.state
    m = state.n_harmonics
    sums = {"fly": 0.0, "free": 0.0, "balance": 0.0, "sys_map": 0.0, "e2": 0.0, "budget": 0.0, "free_sys_map": 0.0,
            "free_e2": 0.0}
    t_i, d_tdc, n = [], [], 0
    for c in cycs:
        before = state
        outcome = pipe.process(c)
        if not outcome.ok:
            continue
        state, res = pipe.state, outcome.result
        try:  # this cycle's equations at the free end, from the state the monitor analysed it with
            design2, floor, size, size2 = second_wheel_design(spec, before, c, cfg, node)
        except CycleRejected:
            continue
        if before.cycles < cfg.warmup_cycles:
            continue
        d_ref = state.accumulator.info_reference - before.accumulator.info_reference
        sums["fly"] = sums["fly"] + state.accumulator.info - before.accumulator.info - d_ref
        sums["balance"] = sums["balance"] + d_ref
        sigma = np.sqrt(np.maximum(state.stats.var, floor))
        sums["free"] = sums["free"] + whitened_info(design2, sigma)
        inv2 = 1.0 / np.concatenate([sigma, sigma])
        sums["free_sys_map"] = sums["free_sys_map"] + (np.concatenate([design2.real, design2.imag]) * inv2[:, None]
                                                       * inv2[:, None]).T  # A^T D of the whitened rows
        e2_free = (cfg.model_rel_error * size2) ** 2 / 2.0
        sums["free_e2"] = sums["free_e2"] + np.concatenate([e2_free, e2_free])
        sums["sys_map"] = sums["sys_map"] + (state.accumulator.sys_map - before.accumulator.sys_map)[:, :2 * m]
        e2 = (cfg.model_rel_error * size) ** 2 / 2.0  # the monitor's repeatable model error per real component
        sums["e2"] = sums["e2"] + np.concatenate([e2, e2])
        budget = np.maximum(np.abs(state.stats.mean) ** 2 / 2.0, e2)  # what the monitor books as repeatable
        sums["budget"] = sums["budget"] + np.concatenate([budget, budget])
        t_i.append(indicated_torque(spec, c.grid, c.pressure))
        d_tdc.append(indicated_torque(spec, c.grid, c.pressure, TDC_STEP_DEG) - t_i[-1])
        n += 1
    truth = np.array([k["friction_torque_mean_nm"] for k in sim.truth["cylinders"]])
    out = {k: v / n for k, v in sums.items()}
    out.update(load=load, n=n, p_f=state.layout.n_params, n_nuisance=state.n_nuisance,
               indicated=np.mean(t_i, axis=0), d_tdc=np.mean(d_tdc, axis=0),
               cyl_rows=_cylinder_rows(spec, before, c, cfg), truth_friction=truth, prior_info=state.prior.info,
               sibling_free_prior=_prior_without_siblings(spec, state, cfg), estimate=state.params,
               monitor_sigma=res.smoothed.friction_torque_mean_sigma, monitor_mean=res.smoothed.friction_torque_mean,
               data_gain=res.smoothed.data_gain)
    return out


def _prior_without_siblings(spec, state, cfg) -> np.ndarray:
    return prior_normal(spec, state.layout, state.n_nuisance, cfg.parameter_sigma, cfg.tooth_error_deg, 0.0).info


def _cylinder_rows(spec, state, cycle, cfg) -> np.ndarray:
    """d T_f,k / d theta (z, P_f) at the state's parameters: the monitor's own rows of this cycle."""
    fly, theta_start, op = _fit_and_point(spec, state, cycle, cfg)
    bal = harmonic_balance(op, state.params, state.n_nuisance, state.relative_motion, state.static, cycle.grid,
                           cycle.pressure, fly, theta_start, cfg.passes, cfg.time_samples)
    return bal.rows.cylinder_rows[:, :state.layout.n_params]


# ---- report -------------------------------------------------------------------------------------------------------

N_GRID = np.unique(np.round(np.logspace(1, 7, 121)).astype(int))


def load_data() -> dict[float, dict]:
    out = {}
    for f in sorted(DATA.glob("load*.npz")):
        d = dict(np.load(f))
        out[float(d["load"])] = d
    if not out:
        raise SystemExit(f"no collected data in {DATA}: run 'collect' first")
    return out


def two_wheel(info_fly: np.ndarray, info_free: np.ndarray, p_f: int, n_nu: int) -> np.ndarray:
    """Information over [friction (p_f), flywheel nuisances (n_nu), free-end nuisances (n_nu)]: each wheel carries
    its own tooth-spacing error."""
    p = p_f + 2 * n_nu
    out = np.zeros((p, p))
    a = np.r_[0:p_f, p_f:p_f + n_nu]
    b = np.r_[0:p_f, p_f + n_nu:p]
    out[np.ix_(a, a)] += info_fly
    out[np.ix_(b, b)] += info_free
    return out


def two_wheel_prior(prior: np.ndarray, p_f: int, n_nu: int) -> np.ndarray:
    out = two_wheel(prior, np.zeros_like(prior), p_f, n_nu)
    nu = np.r_[p_f:p_f + n_nu]
    out[np.ix_(nu + n_nu, nu + n_nu)] = prior[np.ix_(nu, nu)]
    return out


def configurations(data: dict[float, dict], base: float) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """name -> (per-cycle data information, fixed prior without siblings, with siblings), over the parameters of
    that configuration (friction first)."""
    d0 = data[base]
    p_f, n_nu = int(d0["p_f"]), int(d0["n_nuisance"])
    one = d0["fly"] + d0["balance"]
    mix = np.mean([d["fly"] + d["balance"] for d in data.values()], axis=0)
    one2 = two_wheel(one, d0["free"], p_f, n_nu)
    mix2 = two_wheel(mix, np.mean([d["free"] for d in data.values()], axis=0), p_f, n_nu)
    pr, pr_s = d0["sibling_free_prior"], d0["prior_info"]
    pr2, pr2_s = two_wheel_prior(pr, p_f, n_nu), two_wheel_prior(pr_s, p_f, n_nu)
    f = np.r_[0:p_f]
    known = (one[np.ix_(f, f)], pr[np.ix_(f, f)], pr_s[np.ix_(f, f)])
    return {"one load, tooth pattern known": known,
            "one load, flywheel": (one, pr, pr_s), "load +-20 %, flywheel": (mix, pr, pr_s),
            "one load, two wheels": (one2, pr2, pr2_s), "load +-20 %, two wheels": (mix2, pr2, pr2_s)}


def relative_sigma(info: np.ndarray, prior: np.ndarray, n: float, rows: np.ndarray, p_f: int) -> np.ndarray:
    """(z,) 1-sigma of each cylinder's friction relative to it, after ``n`` cycles."""
    cov = np.linalg.inv(n * info + prior)[:p_f, :p_f]
    return np.sqrt(np.einsum("kp,pq,kq->k", rows, cov, rows)) / rows.sum(axis=1)


def cycles_needed(sig_of_n) -> np.ndarray:
    """Per cylinder, the smallest N of N_GRID with sigma <= TARGET_REL (inf if none)."""
    sig = np.array([sig_of_n(n) for n in N_GRID])  # (n_grid, z)
    ok = sig <= TARGET_REL
    first = np.where(ok.any(axis=0), ok.argmax(axis=0), -1)
    return np.where(first >= 0, N_GRID[np.maximum(first, 0)], np.inf), sig


def model_error_floor(d: dict, info: np.ndarray, rows: np.ndarray, p_f: int, key: str) -> np.ndarray:
    """(z,) relative sigma of each cylinder's friction from an error repeated every cycle (the monitor's systematic
    budget ``key``: 'e2' model_rel_error of each harmonic, 'budget' that or the persistent residual), N -> inf, by
    the data's pseudo-inverse (directions the data do not see are left out: a floor from below)."""
    b = d["sys_map"]  # (P, 2M) per-cycle A^T D of the speed rows
    s = (b * d[key][None, :]) @ b.T
    inv = np.linalg.pinv(info, rcond=1e-12, hermitian=True)
    cov = (inv @ s @ inv)[:p_f, :p_f]
    return np.sqrt(np.einsum("kp,pq,kq->k", rows, cov, rows)) / rows.sum(axis=1)


def two_wheel_sys(d: dict, p_f: int) -> np.ndarray:
    """Per-cycle B C B^T of both wheels, each harmonic's model error model_rel_error of its size at that wheel
    (taken independent between the wheels)."""
    n_nu = int(d["n_nuisance"])
    b1 = two_wheel(d["sys_map"] @ np.diag(d["e2"]) @ d["sys_map"].T, np.zeros_like(d["fly"]), p_f, n_nu)
    b2 = two_wheel(np.zeros_like(d["fly"]), d["free_sys_map"] @ np.diag(d["free_e2"]) @ d["free_sys_map"].T, p_f,
                   n_nu)
    return b1 + b2


def two_wheel_floor(d: dict, rows: np.ndarray, p_f: int) -> np.ndarray:
    """``model_error_floor`` with both wheels (``two_wheel_sys``)."""
    info = two_wheel(d["fly"] + d["balance"], d["free"], p_f, int(d["n_nuisance"]))
    inv = np.linalg.pinv(info, rcond=1e-12, hermitian=True)
    cov = (inv @ two_wheel_sys(d, p_f) @ inv)[:p_f, :p_f]
    return np.sqrt(np.einsum("kp,pq,kq->k", rows, cov, rows)) / rows.sum(axis=1)


def cmd_report(args) -> None:
    data = load_data()
    base = min(data, key=lambda x: abs(x - 0.75))
    d0 = data[base]
    p_f = int(d0["p_f"])
    rows = d0["cyl_rows"]
    truth = d0["truth_friction"]
    z = rows.shape[0]
    doc = {"engine": ENGINE, "rpm": RPM, "loads": sorted(data), "base_load": base,
           "cycles_per_load": {f"{k:.2f}": int(v["n"]) for k, v in data.items()}, "target_rel_sigma": TARGET_REL,
           "configurations": {}}
    curves = {}
    for name, (info, pr, pr_s) in configurations(data, base).items():
        need, sig = cycles_needed(lambda n, i=info, p=pr: relative_sigma(i, p, n, rows, p_f))
        need_s, _ = cycles_needed(lambda n, i=info, p=pr_s: relative_sigma(i, p, n, rows, p_f))
        at = {n: relative_sigma(info, pr, n, rows, p_f) for n in (2000, 10000, 45000)}
        doc["configurations"][name] = {
            "cycles_needed": [None if not np.isfinite(v) else int(v) for v in need],
            "cycles_needed_with_siblings": [None if not np.isfinite(v) else int(v) for v in need_s],
            **{f"rel_sigma_at_{n}": [round(float(v), 4) for v in s] for n, s in at.items()},
            "resolved_at_45000": int(np.sum(at[45000] <= TARGET_REL)),
        }
        curves[name] = sig
    one = d0["fly"] + d0["balance"]
    floors = {
        "tdc_0.1deg": {f"{k:.2f}": [round(float(v), 4) for v in np.abs(d["d_tdc"]) / d["truth_friction"]]
                       for k, d in data.items()},
        "gain_1pct": {f"{k:.2f}": [round(float(v), 4) for v in 0.01 * d["indicated"] / d["truth_friction"]]
                      for k, d in data.items()},
        "model_rel_error": [round(float(v), 4) for v in model_error_floor(d0, one, rows, p_f, "e2")],
        "model_rel_error_two_wheels": [round(float(v), 4) for v in two_wheel_floor(d0, rows, p_f)],
    }
    doc["floors"] = floors
    # what the monitor itself would state after N cycles at one load: the statistical bound with its priors plus its
    # repeatable-error budget through the same N cycles' rows (core.monitor.identify.accumulate's N^-1 B C B^T N^-1)
    doc["monitor_prediction"] = {}
    n_nu = int(d0["n_nuisance"])
    two = two_wheel(one, d0["free"], p_f, n_nu)
    two_sys = two_wheel_sys(d0, p_f)
    for key, info, prior in (("e2", one, d0["prior_info"]),
                             ("two_wheels_e2", two, two_wheel_prior(d0["prior_info"], p_f, n_nu))):
        b = d0["sys_map"]
        s_cyc = two_sys if key.startswith("two") else (b * d0[key][None, :]) @ b.T
        for n in (2000, 10000, 45000, 180000):
            cov = np.linalg.inv(n * info + prior)
            tot = (cov + n * n * cov @ s_cyc @ cov)[:p_f, :p_f]
            sig = np.sqrt(np.einsum("kp,pq,kq->k", rows, tot, rows)) / rows.sum(axis=1)
            doc["monitor_prediction"][f"{key}_{n}"] = {
                "rel_sigma": [round(float(v), 4) for v in sig], "at_most_2.5pct": int(np.sum(sig <= TARGET_REL)),
                "at_most_10pct": int(np.sum(sig <= 0.10))}
    doc["empirical"] = {f"{k:.2f}": {
        "cycles": int(d["n"]), "scale_error": [round(float(v), 4) for v in d["estimate"][:z] - 1.0],
        "monitor_rel_sigma": [round(float(v), 4) for v in d["monitor_sigma"] / d["truth_friction"]],
        "crb_rel_sigma_with_siblings": [round(float(v), 4) for v in relative_sigma(
            d["fly"] + d["balance"], d["prior_info"], float(d["n"]), d["cyl_rows"], p_f)]}
        for k, d in data.items()}
    doc["weak_directions"] = weak_directions(one, d0["sibling_free_prior"], p_f, z)
    OUT_JSON.write_text(json.dumps(doc, indent=1))
    figures(doc, curves, truth, N_GRID, TARGET_REL)
    print_table(doc)


def weak_directions(info: np.ndarray, prior: np.ndarray, p_f: int, z: int, n: int = 3) -> list[dict]:
    """The per-cylinder scale combinations the flywheel data pin down least (the nuisances and the engine-wide
    scales marginalised): eigenvectors of the Schur complement's smallest eigenvalues."""
    full = info + 1e-9 * prior
    a, b, c = full[:z, :z], full[:z, z:], full[z:, z:]
    schur = a - b @ np.linalg.solve(c, b.T)
    w, v = np.linalg.eigh(schur)
    return [{"per_cycle_information": float(w[i]), "vector": [round(float(x), 3) for x in v[:, i]]} for i in range(n)]


def cmd_collect(args) -> None:
    DATA.mkdir(parents=True, exist_ok=True)
    for load in args.loads:
        d = collect_load(load, args.cycles, args.seed)
        np.savez(DATA / f"load{load:.2f}.npz", **{k: np.asarray(v) for k, v in d.items()})
        print(f"load {load:.2f}: {d['n']} cycles collected", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(required=True)
    c = sub.add_parser("collect")
    c.add_argument("--cycles", type=int, default=140)
    c.add_argument("--loads", type=float, nargs="+", default=[0.55, 0.75, 0.95])
    c.add_argument("--seed", type=int, default=21)
    c.set_defaults(func=cmd_collect)
    r = sub.add_parser("report")
    r.set_defaults(func=cmd_report)
    args = ap.parse_args()
    args.func(args)


if __name__ == "__main__":
    main()
