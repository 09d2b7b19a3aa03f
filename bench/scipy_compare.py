"""Run the scipy baseline (bench/scipy_baseline.py) on a few of the cycles the monitor processed and compare:
time per cycle and speed-up, estimates against the monitor and against the simulator's truth."""

from __future__ import annotations

import time

import numpy as np
from frictionwatch.core.model.engine import EngineSpec

from bench.scipy_baseline import ChainODE, identify_cycle, periodic_solution
from bench.scipy_measure import measure


def monitor_noise(state, result, meas) -> tuple[np.ndarray | None, float | None]:
    """The monitor's noise model at this cycle (None where its state lacks it): sigma = sqrt(max(residual
    variance, tooth-fit floor)) and the balance sigma, as core.monitor.monitor whitens."""
    try:
        var = np.asarray(state.stats.var, dtype=np.float64)
        bal_var = float(state.stats.balance_var)
    except AttributeError:
        return None, None
    freq = 0.5 * meas.omega * np.arange(1, var.shape[0] + 1)
    floor = freq**2 * 2.0 * meas.edge_noise**2 / meas.n_edges + 1e-12
    t_i = float(np.sum(result.indicated_torque))
    return np.sqrt(np.maximum(var, floor)), float(np.sqrt(max(bal_var, (0.002 * t_i) ** 2, 1e-6)))


def pick_method(spec: EngineSpec, meas, layout) -> dict:
    """One cycle from constant speed with RK45 and with LSODA: seconds, RHS calls; the faster one is used."""
    ode = ChainODE(spec, meas)
    coef = layout.coefficients(np.ones(layout.n_params))
    out = {}
    for method in ("RK45", "LSODA"):
        t0 = time.perf_counter()
        s = periodic_solution(ode, coef, method=method, max_cycles=1)
        dt = time.perf_counter() - t0
        out[method] = {"s_per_cycle": round(dt, 3), "rhs_calls_per_cycle": s.rhs_calls,
                       "us_per_rhs_call": round(1e6 * dt / s.rhs_calls, 1)}
    out["used"] = min(("RK45", "LSODA"), key=lambda k: out[k]["s_per_cycle"])
    return out


def compare(spec: EngineSpec, sim, cycles: list, kept: list, n: int, monitor_ms: float, e2e_ms: float) -> dict:
    """Baseline on the last ``n`` monitored cycles (warm-started one from the next, the first from constant speed).

    cycles: the monitored cycles; kept: (state after, result) of the last len(kept) >= n of them; monitor_ms, e2e_ms:
    the monitor's and the end-to-end mean time per cycle from the timed pass."""
    if len(kept) < min(n, len(cycles)):
        raise ValueError(f"the scipy baseline on {n} cycles needs their states; {len(kept)} kept")
    idx = list(range(max(0, len(cycles) - n), len(cycles)))
    base = len(cycles) - len(kept)  # kept[j - base] belongs to cycles[j]
    st0 = kept[idx[0] - base][0]
    layout = st0.layout
    meas0 = measure(spec, cycles[idx[0]], st0.n_harmonics, getattr(st0.teeth, "correction", None))
    methods = pick_method(spec, meas0, layout)
    per, warm = [], None
    for j in idx:
        state, res = kept[j - base]
        c = cycles[j]
        meas = measure(spec, c, state.n_harmonics, getattr(state.teeth, "correction", None))
        sigma, s_bal = monitor_noise(state, res, meas)
        b = identify_cycle(spec, meas, layout, sigma, s_bal, method=methods["used"], warm=warm)
        warm = b.warm
        truth = np.array([x["friction_torque_mean_nm"] for x in sim.truth["cycles"][c.index]["cylinders"]])
        mon = np.asarray(res.cycle.friction_torque_mean)
        mon_sig = np.asarray(res.cycle.friction_torque_mean_sigma)
        resolved = np.isfinite(mon)
        pc = layout.per_cylinder
        per.append({
            "cycle": int(c.index), "seconds": round(b.seconds, 2), "fits": b.fits, "ls_evaluations": b.nfev,
            "cycles_simulated": b.cycles_simulated, "rhs_calls": b.rhs_calls,
            "r_squared": round(b.r_squared, 5), "monitor_r_squared": round(float(res.r_squared), 5),
            "total_friction_nm": {"scipy": round(float(b.friction_mean.sum()), 4),
                                  "monitor_cycle": round(float(res.cycle.total_friction_torque), 4),
                                  "monitor_smoothed": round(float(res.smoothed.total_friction_torque), 4),
                                  "truth": round(float(truth.sum()), 4)},
            "per_cylinder_rms_rel_error_vs_truth": {
                "scipy": round(float(np.sqrt(np.mean((b.friction_mean / truth - 1.0) ** 2))), 5),
                "monitor_cycle_resolved": round(float(np.sqrt(np.mean((mon[resolved] / truth[resolved] - 1.0) ** 2))),
                                                5) if resolved.any() else None},
            "monitor_cycle_resolved_cylinders": int(resolved.sum()),
            "scipy_within_2sigma_of_truth_by_monitor_sigma": round(float(np.mean(
                np.abs(b.friction_mean - truth) <= 2.0 * mon_sig)), 3),
            "scipy_minus_monitor_resolved_rms_nm": round(float(np.sqrt(np.mean(
                (b.friction_mean - mon)[resolved] ** 2))), 5) if resolved.any() else None,
            "theta_scipy": np.round(b.theta, 4).tolist(),
            "theta_monitor_smoothed": np.round(np.asarray(state.params)[: layout.n_params], 4).tolist(),
            "theta_rms_diff_per_cylinder_params": round(float(np.sqrt(np.mean(
                (b.theta[pc] - np.asarray(state.params)[: layout.n_params][pc]) ** 2))), 4) if pc.any() else None,
        })
    secs = np.array([p["seconds"] for p in per])
    steady = secs[1:] if secs.size > 1 else secs
    speedup = float(steady.mean()) / (1e-3 * monitor_ms)
    tot = per[-1]["total_friction_nm"]
    summary = (f"{len(per)} cycles, {secs[0]:.1f} s for the first (from constant speed), "
               f"{steady.mean():.1f} s per warm-started cycle ({methods['used']}, "
               f"{methods[methods['used']]['us_per_rhs_call']} us per RHS call); speed-up of the monitor "
               f"{speedup:,.0f}x (monitor: CyclePipeline.process) / {float(steady.mean()) / (1e-3 * e2e_ms):,.0f}x (end to end); "
               f"last cycle total friction scipy {tot['scipy']:.3f}, monitor {tot['monitor_cycle']:.3f}, "
               f"truth {tot['truth']:.3f} N m; r2 scipy {per[-1]['r_squared']:.4f}, monitor "
               f"{per[-1]['monitor_r_squared']:.4f}")
    return {"methods": methods, "cycles": per, "first_cycle_s": round(float(secs[0]), 2),
            "warm_cycle_s_mean": round(float(steady.mean()), 2),
            "speedup_vs_monitor": round(speedup, 1), "speedup_vs_end_to_end": round(
                float(steady.mean()) / (1e-3 * e2e_ms), 1), "summary": summary}
