"""The plant's integrator against the former one, RK4 on the whole plant at 0.125 deg (design note 123's reference):
the records' and the truth's differences on the three accuracy cases, 24 cycles, seed 3.

    python -m bench.bench_plant_integrator [--cycles 24] [--engines genset-v20 k9k-4cyl deutz-1cyl]

Both runs put tick 0 at the exact time of theta_F = -2 pi (the kernel's crossing inside its step, design note 123's
"landed"; before, it was the first step at or past it, a common offset of every record of up to a step). Figures:
tooth times (max shift, also over the tooth period), tooth intervals (max change), the flywheel speed at each degree
(relative), pressure samples (max change, also over the peak), each cycle's per-cylinder friction, the run's
per-cylinder friction, FMEP, IMEP and the friction on the 1-deg grid (relative). A dyno engine's free speed wanders
by parts in 1e6 between any two integrators, and its tooth times and pressure samples with it (the shift grows over
the run); the grid-locked genset-v20 does not drift.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

CASES = {"genset-v20": (1500.0, 0.75, {}), "k9k-4cyl": (2000.0, 0.7, {"ring_wear": {}}),
         "deutz-1cyl": (2600.0, 0.8, {})}
REFERENCE_STEP_DEG = 0.125


def _run(engine: str, cycles: int, reference: bool) -> dict:
    import frictionwatch.core.plant.sim_run as sim_run
    import frictionwatch.core.plant.simulate as sm
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.plant.plant_advance import advance
    from frictionwatch.core.plant.plant_rk4_reference import advance_rk4

    step = sm.STEP_DEG
    sim_run.advance, sm.STEP_DEG = (advance_rk4, REFERENCE_STEP_DEG) if reference else (advance, step)
    try:
        rpm, load, fx = CASES[engine]
        r = sm.simulate(load_engine(engine), rpm, load, cycles, 3, effects=fx, friction_grid=True)
    finally:
        sim_run.advance, sm.STEP_DEG = advance, step
    d, t = r.diagnostics, r.truth
    return {"edge_t": d["edge_times_s"], "edge_i": d["edge_index"], "p": d["pressure_true_pa"],
            "w": d["flywheel_speed_grid_rad_s"], "fgrid": d["friction_grid_nm"], "fmep": t["fmep_bar"],
            "imep": t["imep_bar"], "fric": np.array([c["friction_torque_mean_nm"] for c in t["cylinders"]]),
            "cyc": np.array([[c["friction_torque_mean_nm"] for c in e["cylinders"]] for e in t["cycles"]]),
            "period": 2 * np.pi / load_engine(engine).sensors.wheel_teeth / (rpm * np.pi / 30), "h": r.truth[
                "operating"]["step_s"]}


def compare(a: dict, b: dict) -> dict:
    """b against the reference a."""
    ta, tb, ia, ib = a["edge_t"], b["edge_t"], a["edge_i"], b["edge_i"]
    if ia[0] != ib[0]:  # one edge more at the start of one of them
        ta, ia = (ta[1:], ia[1:]) if ia[1] == ib[0] else (ta, ia)
        tb, ib = (tb[1:], ib[1:]) if ib[1] == ia[0] else (tb, ib)
    n = min(ta.size, tb.size)
    assert np.array_equal(ia[:n], ib[:n])
    shift = np.abs(tb[:n] - ta[:n]).max()
    m = min(a["p"].shape[0], b["p"].shape[0])
    dp = np.abs(b["p"][:m] - a["p"][:m]).max()
    rel = lambda x, y: float(np.max(np.abs(x / y - 1)))  # noqa: E731
    return {"step_s": b["h"], "tooth_shift_ns": shift * 1e9, "tooth_shift_per_period": shift / a["period"],
            "interval_change_ns": float(np.abs(np.diff(tb[:n]) - np.diff(ta[:n])).max()) * 1e9,
            "speed_at_angle_rel": float(np.abs(b["w"] - a["w"]).max() / np.abs(a["w"]).mean()),
            "pressure_pa": float(dp), "pressure_per_peak": float(dp / a["p"].max()),
            "cycle_friction_rel": rel(b["cyc"], a["cyc"]), "run_friction_rel": rel(b["fric"], a["fric"]),
            "fmep_rel": rel(b["fmep"], a["fmep"]), "imep_rel": rel(b["imep"], a["imep"]),
            "friction_grid_per_peak": float(np.abs(b["fgrid"] - a["fgrid"]).max() / np.abs(a["fgrid"]).max())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=24)
    ap.add_argument("--engines", nargs="+", default=list(CASES))
    args = ap.parse_args()
    out = {e: compare(_run(e, args.cycles, True), _run(e, args.cycles, False)) for e in args.engines}
    print(json.dumps({e: {k: float(f"{v:.3g}") for k, v in r.items()} for e, r in out.items()}, indent=1))


if __name__ == "__main__":
    main()
