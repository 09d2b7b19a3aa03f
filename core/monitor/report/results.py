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
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from frictionwatch.core.model.engine import mep_per_torque
from frictionwatch.core.monitor.checks.pressure_trace import stood_in
from frictionwatch.core.monitor.checks.ring_pressure import RingIndicators
from frictionwatch.core.monitor.report.figure_status import FigureStatus, FrictionStatus, friction_status
from frictionwatch.core.monitor.teeth.tooth_fit import FreeEndSpeed

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
    load and no deceleration to balance (core.monitor.identify.identification.measured_or_withheld)
    calibration: the model's calibration status ("uncalibrated" or "commissioned", core.model.calibration);
    calibration_sigma (z,) N m, total_calibration_sigma N m: the part of the sigmas above that the calibration's
    remaining uncertainty (TDC, pressure gain, J) adds; it is the same in every cycle, so a change of a figure
    since commissioning has the sigma without it (``change_sigma``; None: not added, an estimate made by hand)
    pulled (z,) bool: cylinders the pull check (core.monitor.identify.pull_check) turned from measured into a share:
    the data lead their figure further than their own scatter allows (None: not checked)
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
    calibration: str = "uncalibrated"
    calibration_sigma: np.ndarray | None = None
    total_calibration_sigma: float = 0.0
    pulled: np.ndarray | None = None


def change_sigma(est: FrictionEstimate) -> np.ndarray:
    """(z,) N m: each cylinder's friction sigma without the calibration's part: the sigma of a change of its friction
    against an earlier figure of the same installation (a constant TDC or gain error cancels in the change). An
    estimate without the calibration's part (built by hand) gives its sigma as it is."""
    s = np.asarray(est.friction_torque_mean_sigma, dtype=np.float64)
    cal = getattr(est, "calibration_sigma", None)
    if cal is None:
        return s
    return np.sqrt(np.maximum(s * s - cal * cal, 0.0))


@dataclass(frozen=True)
class SensorHealth:
    """Sensor health of one cycle (core.monitor.checks.sensor_health): smoothed estimates, their 1-sigma, this cycle's own.

    tdc_offset (z,) rad: each cylinder's true firing TDC after the stated one (wheel + its own against the siblings);
    tdc_offset_siblings (z,) rad its own part (NaN below three cylinders); wheel_tdc_offset rad: the whole wheel
    pressure_gain (z,) reading / true, relative to the median sibling; pressure_offset (z,) Pa, likewise
    applied_tdc (z,) rad, applied_gain (z,), applied_offset (z,) Pa: the corrections this cycle's figures rest on
    friction_sigma N m (engine), friction_sigma_cyl (z,) N m: the sensors' remaining uncertainty carried into the
    friction sigmas; flags: ``sensor_<kind>_cyl<k>`` for a cylinder, ``sensor_tdc_offset`` for the wheel
    """

    tdc_offset: np.ndarray
    tdc_offset_sigma: np.ndarray
    tdc_offset_cycle: np.ndarray
    tdc_offset_siblings: np.ndarray
    wheel_tdc_offset: float
    wheel_tdc_offset_sigma: float
    wheel_tdc_offset_cycle: float
    pressure_gain: np.ndarray
    pressure_gain_sigma: np.ndarray
    pressure_gain_cycle: np.ndarray
    pressure_offset: np.ndarray
    pressure_offset_sigma: np.ndarray
    pressure_offset_cycle: np.ndarray
    applied_tdc: np.ndarray
    applied_gain: np.ndarray
    applied_offset: np.ndarray
    friction_sigma_cyl: np.ndarray
    friction_sigma: float
    flags: tuple[str, ...] = ()

    def to_json(self) -> dict:
        """degCA and bar; None where a figure is not identifiable."""
        deg = math.degrees
        cylinders = [{
            "cylinder": k + 1,
            "tdc_offset_deg": _num(deg(self.tdc_offset[k])),
            "tdc_offset_sigma_deg": _num(deg(self.tdc_offset_sigma[k])),
            "tdc_offset_cycle_deg": _num(deg(self.tdc_offset_cycle[k])),
            "pressure_gain": _num(self.pressure_gain[k]),
            "pressure_gain_sigma": _num(self.pressure_gain_sigma[k]),
            "pressure_offset_bar": _num(self.pressure_offset[k] / PA_PER_BAR),
            "pressure_offset_sigma_bar": _num(self.pressure_offset_sigma[k] / PA_PER_BAR),
            "corrected_tdc_deg": _num(deg(self.applied_tdc[k])),
            "corrected_gain": _num(self.applied_gain[k]),
            "corrected_offset_bar": _num(self.applied_offset[k] / PA_PER_BAR),
        } for k in range(self.tdc_offset.shape[0])]
        return {"wheel_tdc_offset_deg": _num(deg(self.wheel_tdc_offset)),
                "wheel_tdc_offset_sigma_deg": _num(deg(self.wheel_tdc_offset_sigma)),
                "friction_sigma_nm": _num(self.friction_sigma), "flags": list(self.flags), "cylinders": cylinders}


@dataclass(frozen=True)
class ChainSample:
    """One cycle's input and output of the drive train, for its identification from both wheels
    (core.monitor.calibration.drive_train, which passes the torques through other chains).

    torque (N, M) complex [N m]: the node torque harmonics the balance put through the chain (known torques and
    friction at the cycle's parameters); flywheel (M,) complex [rad/s]: the measured flywheel speed harmonics, referred
    to the window's first edge (the free end's: ``CycleResult.free_end.harmonics_at(0)``); flywheel_patterns
    (M, n_nuisance) complex: its in-band tooth-error patterns through its fit (what they leak into half orders)."""

    torque: np.ndarray
    flywheel: np.ndarray
    flywheel_patterns: np.ndarray


@dataclass(frozen=True)
class CycleResult:
    """Everything the monitor knows about one cycle.

    index, t_start [s], rpm_mean, omega_mean [rad/s], load_torque [N m], load_power [W]
    imep (z,) Pa over each cylinder's own firing cycle (-360..+360 deg around its TDC; over the assembled cycle when
    the cycle before is not at hand, flagged no_previous_cycle), pmax (z,) Pa, pmax_angle (z,) rad after its TDC
    indicated_torque (z,) N m work mean; displacement_cyl m^3 one cylinder's swept volume (every FMEP of the
    documents is its torque times ``mep_per_nm``: 4 pi / V_d, core.model.engine.mep_per_torque); friction_balance N m: this cycle's T_fM = T_iM - T_LM - losses - dE/4pi
    coupling_loss N m: modelled mean dissipation of dampers/couplings/shaft (physics.md §12.4), excluded from friction
    grid (n,) rad crank angle; friction_torque (n,) N m total, from the smoothed coefficients with this cycle's
    pressure and speed; per cylinder on the monitor's time samples: friction_torque_cyl_time (z, n_t) N m at the
    flywheel angles time_angles (n_t,) rad; ``friction_torque_cyl`` (z, n) puts them on the grid when first asked
    for (a dashboard shows a few cycles a second; the monitor makes 12 or more)
    friction_torque_balance (n,) N m or None: direct rigid balance (paper 001 Eq. 26), rigid engines only
    speed_measured, speed_model (n,) rad/s flywheel speed (orders <= the identification limit)
    residual_harmonics (M,) complex rad/s: measured - model flywheel speed harmonics (order m/2)
    residual_rms rad/s, r_squared of the speed ripple; flags; sensor_health (SensorHealth, None with the stage off):
    TDC, pressure gain and pegging estimates, the corrections ``imep`` and the friction rest on, their sigmas
    acceleration rad/s^2, indicated_window N m: of this cycle and the one before (a triangular weight centred on
    cylinder 1's firing TDC between them), the change of their angle-averaged kinetic energy / 4 pi over J at
    theta = 2 pi and the engine's indicated torque; friction_balance pairs them with J(2 pi) (NaN without the cycle
    before; core.monitor.balance.mean_balance.transient_balance)
    ring: the pressure-based ring indicators of every cylinder (core.monitor.checks.ring_pressure; service.alerts)

    The traces (grid, friction_torque, friction_torque_cyl_time, time_angles, speed_measured, speed_model,
    friction_torque_balance) are None in the copy ``slim()`` makes for a long history: ~85 % of a result's memory;
    so are the drive train identification's inputs (``chain``, the free end's ``pattern_harmonics``).
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
    displacement_cyl: float
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
    sensor_health: SensorHealth | None = None
    acceleration: float = float("nan")
    indicated_window: float = float("nan")
    ring: RingIndicators | None = None
    free_end: FreeEndSpeed | None = None  # the second wheel's speed of this cycle (core.monitor.teeth.tooth_fit)
    chain: ChainSample | None = None  # with a second wheel: what the drive train's identification needs
    # (M,) rad/s the spread of residual_harmonics (Re and Im variances summed) that the tooth nuisances' posterior
    # still carries (core.monitor.teeth.pattern_spread); None unless MonitorConfig.nuisance_spread
    residual_pattern_sigma: np.ndarray | None = None

    @cached_property
    def friction_torque_cyl(self) -> np.ndarray | None:
        """(z, n) N m per-cylinder friction torque on the crank-angle grid (None in a slim copy); the engine total
        ``friction_torque`` is their sum up to rounding."""
        if self.friction_torque_cyl_time is None or self.grid is None or self.time_angles is None:
            return None
        from frictionwatch.core.monitor.report.grid_rows import (
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
        if self.free_end is not None and self.free_end.pattern_harmonics is not None:  # the identification's, too
            fields["free_end"] = replace(self.free_end, pattern_harmonics=None)
        return CycleResult(**fields)

    # the per-cycle estimate under the names of the brief
    @property
    def n_cyl(self) -> int:
        return int(self.imep.shape[0])

    @property
    def friction_torque_mean(self) -> np.ndarray:
        return self.cycle.friction_torque_mean

    def pressure_figures(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(imep [Pa], pmax [Pa], pmax_angle [rad]) of each cylinder as measured: NaN where the pressure-trace check
        put the siblings' mean in place of a channel that is no cylinder's pressure (``stood_in``). ``imep`` and
        ``pmax`` keep the stand-in, which the balance needs; a report shows a cylinder's own figure only from this
        (design note 153)."""
        fake = stood_in(self.flags, self.n_cyl)
        if not fake.any():
            return self.imep, self.pmax, self.pmax_angle
        return (np.where(fake, np.nan, self.imep), np.where(fake, np.nan, self.pmax),
                np.where(fake, np.nan, self.pmax_angle))

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

    def to_json(self, smoothed: bool = True, status: FrictionStatus | None = None,
                window: dict | None = None) -> dict:
        """This cycle as a JSON-able dict in engineering units (docs/results.md, "the cycle document"); per-cylinder
        keys as in the simulator's truth file where they mean the same quantity.

        ``smoothed`` picks the accumulated estimate (default) or this cycle's own. ``status`` (default: from this
        cycle's flags alone, core.monitor.report.figure_status) says what each friction figure is; ``window`` the cycles
        the estimate stands for (default: what this result knows: its index and accumulated weight). The flat
        friction keys hold a value only where it is measured; the ``friction`` block of each figure holds what is
        shown, with its status. Extend by adding keys to the returned dict."""
        est = self.smoothed if smoothed else self.cycle
        st = status if status is not None else friction_status(est, self.flags)
        if window is None:
            window = ({"first_cycle": None, "last_cycle": int(self.index), "effective_cycles": _num(est.weight),
                       "centre_cycle": None, "forgetting": None} if smoothed else
                      {"first_cycle": int(self.index), "last_cycle": int(self.index), "effective_cycles": 1.0,
                       "centre_cycle": float(self.index), "forgetting": None})
        mep_per_nm = self.mep_per_nm()  # Pa per N m of one cylinder: 4 pi / V_d
        z = self.n_cyl
        pressure = self.pressure_figures()
        total = _figure(st.engine, window, est.total_friction_torque, est.total_friction_torque_sigma,
                        self.mep_per_nm(engine=True), est.calibration, est.total_calibration_sigma)
        doc = {
            "cycle": int(self.index),
            "t_start_s": _num(self.t_start),
            "rpm": _num(self.rpm_mean),
            "load_torque_nm": _num(self.load_torque),
            "load_power_kw": _num(self.load_power / 1e3),
            "estimate": "smoothed" if smoothed else "cycle",
            **_measured_only(total),
            "friction": total,
            "friction_balance_nm": _num(self.friction_balance),
            "coupling_loss_nm": _num(self.coupling_loss),
            "imep_bar": _num(float(np.mean(self.imep)) / PA_PER_BAR),
            "residual_rms_rad_s": _num(self.residual_rms),
            "r_squared": _num(self.r_squared),
            "chi2_reduced": _num(est.chi2_reduced),
            "flags": list(self.flags),
            "cylinders": [self._cylinder_json(k, est, st.cylinders[k], window, mep_per_nm, pressure)
                          for k in range(z)],
            "sensor_health": self.sensor_health.to_json() if self.sensor_health is not None else None,
        }
        return doc

    def measured_fmep_bar(self) -> tuple[float, list[float]]:
        """The smoothed engine FMEP and each cylinder's [bar] where that figure's status is "measured" (this cycle's
        flags, core.monitor.report.figure_status), NaN elsewhere: the ``fmep_bar`` of ``to_json()``'s measured
        figures, by the same arithmetic, without making the document (a gauge reads them every cycle)."""
        est = self.smoothed
        st = friction_status(est, self.flags)

        def fmep(torque: float, mep_per_nm: float) -> float:  # _figure's fmep_bar, None as NaN
            t = _num(torque)
            v = None if t is None else _num(t * mep_per_nm / PA_PER_BAR)
            return math.nan if v is None else v

        mep = self.mep_per_nm()
        engine = (fmep(est.total_friction_torque, self.mep_per_nm(engine=True)) if st.engine.status == "measured"
                  else math.nan)
        return engine, [fmep(est.friction_torque_mean[k], mep) if c.status == "measured" else math.nan
                        for k, c in enumerate(st.cylinders)]

    def _cylinder_json(self, k: int, est: FrictionEstimate, status: FigureStatus, window: dict,
                       mep_per_nm: float, pressure: tuple[np.ndarray, np.ndarray, np.ndarray]) -> dict:
        if status.status == "share":
            shown, sigma = est.prior_friction_torque_mean[k], est.friction_torque_mean_sigma[k]
        else:
            shown, sigma = est.friction_torque_mean[k], est.friction_torque_mean_sigma[k]
        cal_sigma = float("nan") if est.calibration_sigma is None else est.calibration_sigma[k]
        fig = _figure(status, window, shown, sigma, mep_per_nm, est.calibration, cal_sigma)
        return {
            "cylinder": k + 1,
            **_measured_only(fig),
            "friction": fig,
            "share_friction_torque_mean_nm": _num(est.prior_friction_torque_mean[k]),
            "imep_bar": _num(pressure[0][k] / PA_PER_BAR),  # None where the siblings' mean stands in (flagged)
            "pmax_bar": _num(pressure[1][k] / PA_PER_BAR),
            "pmax_angle_deg": _num(math.degrees(pressure[2][k])),
            "coefficients": [_num(v) for v in est.coefficients[k]],
            "coefficients_sigma": [_num(v) for v in est.coefficients_sigma[k]],
            "coefficients_normalised": [_num(v) for v in est.coefficients_normalised[k]],
            "coefficients_normalised_sigma": [_num(v) for v in est.coefficients_normalised_sigma[k]],
        }

    def mep_per_nm(self, engine: bool = False) -> float:
        """4 pi / V_d [Pa per N m]: of one cylinder, or of the engine (its total displacement) with ``engine``.

        Not the ratio of a cycle's IMEP to its indicated torque: the IMEP is over each cylinder's own 720 deg centred
        on its firing TDC and the indicated torque over the assembled cycle, so that ratio moves with the cycle's
        cyclic variation (-4.9 % on a genset-v20 log with a misfiring cylinder, whose FMEP it made read -3.5 % against
        the truth where its torque read +1.5 %)."""
        return mep_per_torque(self.displacement_cyl * (self.n_cyl if engine else 1))


VALUED_STATUSES = ("measured", "share", "prior")  # the statuses whose figure shows a value (the others: None)


def _figure(status: FigureStatus, window: dict, torque: float, sigma: float, mep_per_nm: float,
            calibration: str = "uncalibrated", calibration_sigma: float = float("nan")) -> dict:
    """One friction figure as shown: its status, reason, data weight, window and value (None where the status has
    no value: unresolved, withheld); calibration: the model's calibration status, calibration_sigma [N m] the part
    of the sigma the calibration's remaining uncertainty adds (core.model.calibration)."""
    has_value = status.status in VALUED_STATUSES
    t = _num(torque) if has_value else None
    s = _num(sigma) if has_value else None
    return {
        "calibration": calibration,
        "calibration_sigma_nm": _num(calibration_sigma) if has_value else None,
        "status": status.status,
        "reason": status.reason,
        "data_weight": status.data_weight,
        "window": dict(window),
        "friction_torque_mean_nm": t,
        "friction_torque_sigma_nm": s,
        "fmep_bar": None if t is None else _num(t * mep_per_nm / PA_PER_BAR),
        "fmep_sigma_bar": None if s is None else _num(s * mep_per_nm / PA_PER_BAR),
    }


def _measured_only(figure: dict) -> dict:
    """The flat keys of a figure (the truth file's names): its value where measured, None otherwise."""
    keys = ("friction_torque_mean_nm", "friction_torque_sigma_nm", "fmep_bar", "fmep_sigma_bar")
    measured = figure["status"] == "measured"
    return {key: figure[key] if measured else None for key in keys}


_TRACES = ("grid", "friction_torque", "friction_torque_cyl_time", "time_angles", "speed_measured", "speed_model",
           "friction_torque_balance", "chain")


def _num(x: float) -> float | None:
    """A finite float, or None (unresolved / unknown)."""
    v = float(x)
    return v if math.isfinite(v) else None
