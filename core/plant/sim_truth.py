"""Ground truth of a simulation run from the plant's cycle-boundary integrals (see core.plant.simulate for conventions).

Every mean torque is cycle work / 4 pi [N m]; cycle n spans the true flywheel angle [4 pi n, 4 pi (n+1)).
"""

from __future__ import annotations

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.plant.plant import FOUR_PI
from frictionwatch.core.plant.plant_setup import PlantModel

GRID_MAX_CYL = 4  # the 1-deg friction grid goes into the JSON truth for engines with at most this many cylinders


def _r(x: float) -> float:
    return float(f"{x:.10g}")


def build_truth(spec: EngineSpec, plant: PlantModel, out: dict, *, cycles: int, rpm: float, load: float, seed: int,
                active: dict, wheel: dict, operating: dict, coef_cycles: np.ndarray | None = None
                ) -> tuple[dict, dict]:
    """The truth JSON and the test diagnostics. ``coef_cycles`` (cycles, z, L): the coefficients of each output cycle
    when they change mid-run (an effect's ``from_cycle``); default ``plant.coef`` throughout. The per-cylinder
    ``coefficients`` reported are the plant's at the end of the run."""
    z = spec.n_cyl
    q = plant.nq_cyl  # per cylinder: gas, the L loss terms, extra friction
    n_terms = len(plant.library)
    nq = z * q + 4
    rows, idx = out["cycle_rows"], out["cycle_index"]
    first = int(np.nonzero(idx == 0)[0][0])
    rows = rows[first:first + cycles + 1]
    if rows.shape[0] != cycles + 1:
        raise RuntimeError(f"plant produced {rows.shape[0] - 1} output cycles, expected {cycles}")
    t0 = out["t_out0"]
    d = np.diff(rows, axis=0)  # (cycles, 1 + nq + z): per-cycle increments
    dt = d[:, 0]
    cum = d[:, 1:1 + nq]
    pmax = rows[1:, 1 + nq:]  # the max is reset at each boundary, so row n+1 holds cycle n's max
    coef = plant.coef
    gas = cum[:, 0:z * q:q]  # (cycles, z) J
    basis = np.stack([cum[:, k * q + 1:k * q + 1 + n_terms] for k in range(z)], axis=1)  # (cycles, z, L) J
    extra = cum[:, n_terms + 1:z * q:q]
    coef_c = np.broadcast_to(coef, basis.shape) if coef_cycles is None else coef_cycles
    fric = np.einsum("czl,czl->cz", basis, coef_c) + extra  # (cycles, z) J
    g = z * q
    w_load, w_damp = cum[:, g], cum[:, g + 1]
    vd = spec.displacement_cyl
    grid = out["grid"][: cycles * 720]
    grid_ok = grid.shape[0] == cycles * 720
    fgrid = grid[:, 1].reshape(cycles, 720) if grid_ok else None
    wgrid = grid[:, 2].reshape(cycles, 720) if grid_ok else None
    tgrid = grid[:, 0].reshape(cycles, 720) - out["t_out0"] if grid_ok else None

    cyc = []
    for n in range(cycles):
        c = {"index": n, "t_start_s": _r(rows[n, 0] - t0), "rpm_mean": _r(120.0 / dt[n]),
             "load_torque_nm": _r(w_load[n] / FOUR_PI), "friction_torque_mean_nm": _r(fric[n].sum() / FOUR_PI),
             "indicated_torque_nm": _r(gas[n].sum() / FOUR_PI),
             "damper_coupling_loss_nm": _r(w_damp[n] / FOUR_PI),
             "cylinders": [{"friction_torque_mean_nm": _r(fric[n, k] / FOUR_PI), "imep_bar": _r(gas[n, k] / vd / 1e5),
                            "pmax_bar": _r(pmax[n, k] / 1e5)} for k in range(z)]}
        if fgrid is not None and z <= GRID_MAX_CYL:
            c["friction_torque_grid_nm"] = [_r(v) for v in fgrid[n]]
        cyc.append(c)

    tot = lambda a: float(a.sum())
    n_c = cycles
    fmean = basis.sum(axis=0) / (FOUR_PI * n_c)  # (z, L) cycle-mean of F_l over the output, angle mean
    cylinders = [{"cylinder": k + 1, "friction_torque_mean_nm": tot(fric[:, k]) / (FOUR_PI * n_c),
                  "fmep_bar": tot(fric[:, k]) / (vd * n_c) / 1e5, "imep_bar": tot(gas[:, k]) / (vd * n_c) / 1e5,
                  "pmax_bar_mean": float(pmax[:, k].mean() / 1e5),
                  "extra_friction_torque_nm": tot(extra[:, k]) / (FOUR_PI * n_c),
                  "coefficients": coef[k].tolist(), "coefficients_normalised": (coef[k] * fmean[k]).tolist(),
                  "friction_terms_nm": {name: float(coef[k, i] * fmean[k, i])
                                        for i, name in enumerate(plant.library.names)}}
                 for k in range(z)]
    vd_tot = vd * z * n_c
    truth = {
        "engine": spec.name, "rpm": rpm, "load": load, "seed": seed, "cycles_count": cycles,
        "rpm_mean": float(120.0 * n_c / dt.sum()),
        "fmep_bar": tot(fric) / vd_tot / 1e5, "imep_bar": tot(gas) / vd_tot / 1e5,
        "bmep_bar": tot(w_load) / vd_tot / 1e5,
        "friction_torque_mean_nm": tot(fric) / (FOUR_PI * n_c),
        "indicated_torque_mean_nm": tot(gas) / (FOUR_PI * n_c),
        "load_torque_mean_nm": tot(w_load) / (FOUR_PI * n_c),
        "damper_coupling_loss_nm": tot(w_damp) / (FOUR_PI * n_c),
        "cylinders": cylinders, "cycles": cyc, "effects": active, "wheel": wheel, "operating": operating,
        "conventions": {
            "angle": "crank angle in cylinder 1's convention, 0 = cylinder-1 firing TDC; truth uses the TRUE "
                     "flywheel-node angle theta_F; the stated wheel (AcquisitionInfo) is theta_W = theta_F + "
                     "tdc_offset(all)",
            "cycle": "cycle n = theta_F in [4 pi n, 4 pi (n+1)); t_start_s in the tick time base (tick 0 = start "
                     "of the records, at theta_F = -2 pi)",
            "mean_torque": "cycle work / 4 pi [N m]; mep = work / displacement; per-cylinder values use the "
                           "cylinder's own throw speed",
            "friction": "mechanical friction only (the loss terms friction_terms_nm + extra_friction); relative-damper "
                        "dissipation is damper_coupling_loss_nm; imep is net (whole 720 deg)",
            "friction_torque_grid_nm": "total friction torque [N m] at theta_F = 4 pi n + i deg, i = 0..719",
            "signs": "friction and load torques are magnitudes opposing rotation",
        },
    }
    diag = {"friction_grid_nm": fgrid, "flywheel_speed_grid_rad_s": wgrid, "grid_time_s": tgrid, "cycle_t_start_s": rows[:-1, 0] - t0,
            "basis_work": basis, "cycle_increments": d, "t_out0": t0,
            "tooth_errors_deg": np.asarray(wheel["tooth_errors_deg"]), "edge_times_s": out["edges"][:, 0] - t0,
            "edge_index": out["edges"][:, 1].astype(int), "pressure_true_pa": out["samples"]}
    return truth, diag
