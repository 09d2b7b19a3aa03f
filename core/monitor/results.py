"""The typed per-cycle result of the monitor (SI inside; engineering units only in ``to_json``).

Two friction estimates stand side by side: ``cycle`` from this cycle's equations alone (plus the priors), and
``smoothed`` from the normal equations accumulated over past cycles with forgetting. Each carries 1-sigma
uncertainties. A value the data cannot resolve is NaN in the arrays, False in the ``resolved`` masks and ``None`` in
JSON, never a number.

Residuals stay available for the alert and discrepancy layers: speed residual harmonics (engine order m/2) and the
measured and model flywheel speed on the crank-angle grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

PA_PER_BAR = 1e5


@dataclass(frozen=True)
class FrictionEstimate:
    """Per-cylinder friction of one estimate (z cylinders, 6 Rezeka-Henein terms).

    friction_torque_mean (z,) N m, work mean over the cycle (NaN where unresolved); *_sigma are 1-sigma
    fmep (z,) Pa; coefficients (z, L) raw a_kl of the model's L loss terms; coefficients_normalised (z, L) N m, a_kl <F_kl> (physics.md §7)
    resolved (z,) bool; coefficient_resolved (z, 6) bool
    total_friction_torque N m (engine), total_fmep Pa; prior_friction_torque_mean (z,) N m: the Eq. 6 sharing
    weight: effective number of cycles behind the estimate; chi2_reduced of the speed fit
    data_gain (z,): share of what is known about each cylinder's deviation from the equal share that came from the
    speed signal rather than the priors and the mean balance (0..1; 1 for a single cylinder)
    source: "data", or "prior: <why>" when every friction figure is withheld (NaN) because nothing measured it: no
    load and no deceleration to balance (core.monitor.identification.measured_or_withheld)
    """

    friction_torque_mean: np.ndarray
    friction_torque_mean_sigma: np.ndarray
    fmep: np.ndarray
    fmep_sigma: np.ndarray
    coefficients: np.ndarray
    coefficients_sigma: np.ndarray
    coefficients_normalised: np.ndarray
    coefficients_normalised_sigma: np.ndarray
    resolved: np.ndarray
    coefficient_resolved: np.ndarray
    total_friction_torque: float
    total_friction_torque_sigma: float
    total_fmep: float
    total_fmep_sigma: float
    prior_friction_torque_mean: np.ndarray
    weight: float
    chi2_reduced: float
    data_gain: np.ndarray
    source: str = "data"


@dataclass(frozen=True)
class CycleResult:
    """Everything the monitor knows about one cycle.

    index, t_start [s], rpm_mean, omega_mean [rad/s], load_torque [N m], load_power [W]
    imep (z,) Pa over each cylinder's own firing cycle (-360..+360 deg around its TDC; over the assembled cycle when
    the cycle before is not at hand, flagged no_previous_cycle), pmax (z,) Pa, pmax_angle (z,) rad after its TDC
    indicated_torque (z,) N m work mean; friction_balance N m: this cycle's T_fM = T_iM - T_LM - losses - dE/4pi
    coupling_loss N m: modelled mean dissipation of dampers/couplings/shaft (physics.md §12.4), excluded from friction
    grid (n,) rad crank angle; friction_torque (n,) N m total, from the smoothed coefficients with this cycle's
    pressure and speed; per cylinder on the monitor's time samples: friction_torque_cyl_time (z, n_t) N m at the
    flywheel angles time_angles (n_t,) rad; ``friction_torque_cyl`` (z, n) puts them on the grid when first asked
    for (a dashboard shows a few cycles a second; the monitor makes 12 or more)
    friction_torque_balance (n,) N m or None: direct rigid balance (paper 001 Eq. 26), rigid engines only
    speed_measured, speed_model (n,) rad/s flywheel speed (orders <= the identification limit)
    residual_harmonics (M,) complex rad/s: measured - model flywheel speed harmonics (order m/2)
    residual_rms rad/s, r_squared of the speed ripple; flags
    acceleration rad/s^2, indicated_window N m: over the 720 deg centred on cylinder 1's firing TDC (from the middle
    of the cycle before), the angle-averaged dw/dt and the engine's indicated torque; friction_balance pairs them
    with J at theta = 2 pi (NaN without the cycle before; core.monitor.identification.transient_balance)

    The traces (grid, friction_torque, friction_torque_cyl_time, time_angles, speed_measured, speed_model,
    friction_torque_balance) are None in the copy ``slim()`` makes for a long history: ~85 % of a result's memory.
    """

    index: int
    t_start: float
    rpm_mean: float
    omega_mean: float
    load_torque: float
    load_power: float
    imep: np.ndarray
    pmax: np.ndarray
    pmax_angle: np.ndarray
    indicated_torque: np.ndarray
    friction_balance: float
    coupling_loss: float
    cycle: FrictionEstimate
    smoothed: FrictionEstimate
    grid: np.ndarray | None
    friction_torque: np.ndarray | None
    friction_torque_cyl_time: np.ndarray | None
    time_angles: np.ndarray | None
    speed_measured: np.ndarray | None
    speed_model: np.ndarray | None
    residual_harmonics: np.ndarray
    residual_rms: float
    r_squared: float
    friction_torque_balance: np.ndarray | None = None
    flags: tuple[str, ...] = field(default=())
    acceleration: float = float("nan")
    indicated_window: float = float("nan")

    @cached_property
    def friction_torque_cyl(self) -> np.ndarray | None:
        """(z, n) N m per-cylinder friction torque on the crank-angle grid (None in a slim copy); the engine total
        ``friction_torque`` is their sum up to rounding."""
        if self.friction_torque_cyl_time is None or self.grid is None or self.time_angles is None:
            return None
        from frictionwatch.core.monitor.report_kernels import (
            rows_on_grid,  # numba kernels: loaded when a trace is first wanted
        )

        out = np.empty((self.friction_torque_cyl_time.shape[0], self.grid.shape[0]))
        rows_on_grid(self.grid, self.time_angles, self.friction_torque_cyl_time, out)
        return out

    def slim(self) -> CycleResult:
        """This result without its traces (every scalar, per-cylinder value and estimate kept): what a long
        history of cycles keeps (service.pipeline)."""
        if self.grid is None:
            return self
        fields = dict(self.__dict__)
        fields.pop("friction_torque_cyl", None)  # the grid traces, if asked for (cached_property)
        fields.update(dict.fromkeys(_TRACES))
        return CycleResult(**fields)

    # the per-cycle estimate under the names of the brief
    @property
    def n_cyl(self) -> int:
        return int(self.imep.shape[0])

    @property
    def friction_torque_mean(self) -> np.ndarray:
        return self.cycle.friction_torque_mean

    @property
    def friction_torque_mean_sigma(self) -> np.ndarray:
        return self.cycle.friction_torque_mean_sigma

    @property
    def fmep(self) -> np.ndarray:
        return self.cycle.fmep

    @property
    def coefficients(self) -> np.ndarray:
        return self.cycle.coefficients

    @property
    def resolved(self) -> np.ndarray:
        return self.cycle.resolved

    def to_json(self, smoothed: bool = True) -> dict:
        """JSON-able dict with the keys of the simulator's truth file (``fmep_bar``, ``cylinders`` with
        ``friction_torque_mean_nm``, ``fmep_bar``, ``imep_bar``, ``coefficients``) plus sigmas and flags.
        ``smoothed`` picks the accumulated estimate (default) or this cycle's own."""
        est = self.smoothed if smoothed else self.cycle
        cylinders = []
        for k in range(self.n_cyl):
            cylinders.append({
                "cylinder": k + 1,
                "friction_torque_mean_nm": _num(est.friction_torque_mean[k]),
                "friction_torque_sigma_nm": _num(est.friction_torque_mean_sigma[k]),
                "fmep_bar": _num(est.fmep[k] / PA_PER_BAR),
                "fmep_sigma_bar": _num(est.fmep_sigma[k] / PA_PER_BAR),
                "imep_bar": _num(self.imep[k] / PA_PER_BAR),
                "pmax_bar": _num(self.pmax[k] / PA_PER_BAR),
                "pmax_angle_deg": _num(math.degrees(self.pmax_angle[k])),
                "coefficients": [_num(v) for v in est.coefficients[k]],
                "coefficients_sigma": [_num(v) for v in est.coefficients_sigma[k]],
                "coefficients_normalised_nm": [_num(v) for v in est.coefficients_normalised[k]],
                "resolved": bool(est.resolved[k]),
                "data_weight": _num(est.data_gain[k]),
                "prior_friction_torque_mean_nm": _num(est.prior_friction_torque_mean[k]),
            })
        return {
            "cycle": int(self.index),
            "t_start_s": _num(self.t_start),
            "rpm": _num(self.rpm_mean),
            "load_torque_nm": _num(self.load_torque),
            "load_power_kw": _num(self.load_power / 1e3),
            "estimate": "smoothed" if smoothed else "cycle",
            "cycles_behind_estimate": _num(est.weight),
            "friction_source": est.source,
            "fmep_bar": _num(est.total_fmep / PA_PER_BAR),
            "fmep_sigma_bar": _num(est.total_fmep_sigma / PA_PER_BAR),
            "friction_torque_mean_nm": _num(est.total_friction_torque),
            "friction_torque_sigma_nm": _num(est.total_friction_torque_sigma),
            "friction_balance_nm": _num(self.friction_balance),
            "coupling_loss_nm": _num(self.coupling_loss),
            "imep_bar": _num(float(np.mean(self.imep)) / PA_PER_BAR),
            "residual_rms_rad_s": _num(self.residual_rms),
            "r_squared": _num(self.r_squared),
            "flags": list(self.flags),
            "cylinders": cylinders,
        }


_TRACES = ("grid", "friction_torque", "friction_torque_cyl_time", "time_angles", "speed_measured", "speed_model",
           "friction_torque_balance")


def _num(x: float) -> float | None:
    """A finite float, or None (unresolved / unknown)."""
    v = float(x)
    return v if math.isfinite(v) else None
