"""Ground truth of a simulation run from the plant's cycle-boundary integrals (see core.plant.simulate for conventions).

Every mean torque is cycle work / 4 pi [N m]; cycle n spans the true flywheel angle [4 pi n, 4 pi (n+1)). Built as
the run goes (``TruthAccumulator``): per-cycle entries as each cycle completes, per-run aggregates as running sums.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import numpy as np
from frictionwatch.core.model.engine import EngineSpec, mep_per_torque
from frictionwatch.core.plant.plant import FOUR_PI
from frictionwatch.core.plant.plant_setup import PlantModel

GRID_MAX_CYL = 4  # the 1-deg friction grid goes into the JSON truth for engines with at most this many cylinders


def _r(x: float) -> float:
    return float(f"{x:.10g}")


class TruthAccumulator:
    """The run's ground truth built cycle by cycle: ``add(rows, index, grid)`` takes the plant's cycle-boundary rows
    and 1-deg grid rows of one stretch of the run and returns the truth entries (and diagnostics) of the output cycles
    it completes; ``summary(...)`` the per-run aggregates, summed as the cycles come (memory independent of the
    number of cycles). Cycle n is complete once its end row (boundary n + 1) has arrived."""

    def __init__(self, spec: EngineSpec, plant: PlantModel, cycles: int, t_out0: float,
                 coefficients_of: Callable[[np.ndarray], np.ndarray] | None = None):
        """coefficients_of(cycle indices (n,)) -> (n, z, L): each output cycle's coefficients when they change
        mid-run (an effect's ``from_cycle``); None: ``plant.coef`` throughout. The per-cylinder ``coefficients``
        of the summary are the plant's at the end of the run."""
        z, n_terms = spec.n_cyl, len(plant.library)
        self.spec, self.plant, self.cycles, self.t0 = spec, plant, cycles, t_out0
        self.coefficients_of = coefficients_of
        self.done = 0  # output cycles completed
        self.prev: np.ndarray | None = None  # the row of boundary ``done`` once seen
        self.grid = np.zeros((0, 3))  # grid rows from cycle ``done`` on
        self.sums = {"fric": np.zeros(z), "gas": np.zeros(z), "extra": np.zeros(z), "pmax": np.zeros(z),
                     "basis": np.zeros((z, n_terms)), "load": 0.0, "damp": 0.0, "dt": 0.0}

    def checkpoint(self) -> dict:
        """The running sums and the cycle in hand between chunks, as copies."""
        return copy.deepcopy({"done": self.done, "prev": self.prev, "grid": self.grid, "sums": self.sums})

    def restore(self, ck: dict) -> None:
        """Continue from ``checkpoint()`` of the same run."""
        ck = copy.deepcopy(ck)
        self.done, self.prev, self.grid, self.sums = ck["done"], ck["prev"], ck["grid"], ck["sums"]

    def add(self, rows: np.ndarray, index: np.ndarray, grid: np.ndarray) -> tuple[list[dict], dict]:
        """rows: cycle-boundary rows with their boundary ``index`` (negative while settling); grid: (g, 3) rows
        (time, friction torque, flywheel speed) continuing the 1-deg grid from theta_F = 0."""
        spec, plant, z = self.spec, self.plant, self.spec.n_cyl
        q, n_terms = plant.nq_cyl, len(plant.library)
        nq = z * q + 4
        if grid.size:
            self.grid = np.concatenate([self.grid, grid])
        keep = (index >= 0) & (index <= self.cycles)  # rows come once each, boundaries in order
        new = rows[keep]
        if self.prev is None and new.shape[0]:
            if index[keep][0] != 0:
                raise RuntimeError("plant: the first output cycle boundary is missing (internal error)")
            self.prev, new = new[0], new[1:]
        n_c = new.shape[0]
        if n_c == 0:
            return [], {}
        if self.grid.shape[0] < n_c * 720:  # the grid points of a cycle come in the steps before its end boundary
            raise RuntimeError("plant: the 1-deg grid fell behind the cycle boundaries (internal error)")
        rows = np.concatenate([self.prev[None, :], new])
        first = self.done
        self.done += n_c
        self.prev = rows[-1]
        t0 = self.t0
        d = np.diff(rows, axis=0)  # (n_c, 1 + nq + z): per-cycle increments
        dt = d[:, 0]
        cum = d[:, 1:1 + nq]
        pmax = rows[1:, 1 + nq:]  # the max is reset at each boundary, so row n+1 holds cycle n's max
        coef = plant.coef if self.coefficients_of is None else self.coefficients_of(np.arange(first, first + n_c))
        gas = cum[:, 0:z * q:q]  # (n_c, z) J
        basis = np.stack([cum[:, k * q + 1:k * q + 1 + n_terms] for k in range(z)], axis=1)  # (n_c, z, L) J
        extra = cum[:, n_terms + 1:z * q:q]
        fric = np.einsum("czl,czl->cz", basis, np.broadcast_to(coef, basis.shape)) + extra  # (n_c, z) J
        g = z * q
        w_load, w_damp = cum[:, g], cum[:, g + 1]
        vd = spec.displacement_cyl
        grid, self.grid = self.grid[:n_c * 720], self.grid[n_c * 720:]
        fgrid, wgrid = grid[:, 1].reshape(n_c, 720), grid[:, 2].reshape(n_c, 720)
        tgrid = grid[:, 0].reshape(n_c, 720) - t0
        s = self.sums
        s["fric"] += fric.sum(axis=0)
        s["gas"] += gas.sum(axis=0)
        s["extra"] += extra.sum(axis=0)
        s["pmax"] += pmax.sum(axis=0)
        s["basis"] += basis.sum(axis=0)
        s["load"] += float(w_load.sum())
        s["damp"] += float(w_damp.sum())
        s["dt"] += float(dt.sum())

        cyc = []
        for n in range(n_c):
            c = {"index": first + n, "t_start_s": _r(rows[n, 0] - t0), "rpm_mean": _r(120.0 / dt[n]),
                 "load_torque_nm": _r(w_load[n] / FOUR_PI), "friction_torque_mean_nm": _r(fric[n].sum() / FOUR_PI),
                 "indicated_torque_nm": _r(gas[n].sum() / FOUR_PI),
                 "damper_coupling_loss_nm": _r(w_damp[n] / FOUR_PI),
                 "cylinders": [{"friction_torque_mean_nm": _r(fric[n, k] / FOUR_PI),
                                "imep_bar": _r(gas[n, k] / vd / 1e5), "pmax_bar": _r(pmax[n, k] / 1e5)}
                               for k in range(z)]}
            if z <= GRID_MAX_CYL:
                c["friction_torque_grid_nm"] = [_r(v) for v in fgrid[n]]
            cyc.append(c)
        diag = {"friction_grid_nm": fgrid, "flywheel_speed_grid_rad_s": wgrid, "grid_time_s": tgrid,
                "cycle_t_start_s": rows[:-1, 0] - t0, "basis_work": basis, "cycle_increments": d}
        return cyc, diag

    def summary(self, *, rpm: float, load: float, seed: int, active: list, wheel: dict, operating: dict) -> dict:
        """The truth without its per-cycle list ("cycles"), once every output cycle has been added."""
        if self.done != self.cycles:
            raise RuntimeError(f"plant produced {self.done} output cycles, expected {self.cycles}")
        spec, plant, s, n_c = self.spec, self.plant, self.sums, self.cycles
        coef, vd = plant.coef, spec.displacement_cyl
        fmean = s["basis"] / (FOUR_PI * n_c)  # (z, L) cycle-mean of F_l over the output, angle mean
        cylinders = [{"cylinder": k + 1, "friction_torque_mean_nm": float(s["fric"][k]) / (FOUR_PI * n_c),
                      "fmep_bar": float(s["fric"][k]) / (FOUR_PI * n_c) * mep_per_torque(vd) / 1e5,
                      "imep_bar": float(s["gas"][k]) / (vd * n_c) / 1e5,
                      "pmax_bar_mean": float(s["pmax"][k] / n_c / 1e5),
                      "extra_friction_torque_nm": float(s["extra"][k]) / (FOUR_PI * n_c),
                      "coefficients": coef[k].tolist(), "coefficients_normalised": (coef[k] * fmean[k]).tolist(),
                      "friction_terms_nm": {name: float(coef[k, i] * fmean[k, i])
                                            for i, name in enumerate(plant.library.names)}}
                     for k in range(spec.n_cyl)]
        vd_tot = vd * spec.n_cyl * n_c
        fric, gas = float(s["fric"].sum()), float(s["gas"].sum())
        return {
            "engine": spec.name, "rpm": rpm, "load": load, "seed": seed, "cycles_count": n_c,
            "rpm_mean": float(120.0 * n_c / s["dt"]),
            "fmep_bar": fric / (FOUR_PI * n_c) * mep_per_torque(vd * spec.n_cyl) / 1e5,
            "imep_bar": gas / vd_tot / 1e5, "bmep_bar": s["load"] / vd_tot / 1e5,
            "friction_torque_mean_nm": fric / (FOUR_PI * n_c),
            "indicated_torque_mean_nm": gas / (FOUR_PI * n_c),
            "load_torque_mean_nm": s["load"] / (FOUR_PI * n_c),
            "damper_coupling_loss_nm": s["damp"] / (FOUR_PI * n_c),
            "cylinders": cylinders, "effects": active, "wheel": wheel, "operating": operating,
            "conventions": CONVENTIONS,
        }


CONVENTIONS = {
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
}
