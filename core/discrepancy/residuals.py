"""The model's disagreement with the measurement, cycle by cycle: run the monitor with a model's view over cycles and
keep what it could not explain.

Per analysed cycle: the flywheel-speed residual harmonics (measured - model, engine order m/2, complex rad/s), the
mean torque-balance residual (the measured friction T_fM of the balance minus the model's mean friction, N m), and
the residual speed on a coarse crank-angle grid (for localisation and plots). These are the *features* the
workflow fits: a missing effect shows as a residual that repeats from cycle to cycle (coherent), noise does not.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.view import Reference
from frictionwatch.core.monitor.balance.mean_balance import mid_cycle_inertia, shaft_load
from frictionwatch.core.monitor.calibration.tdc_memo import TdcFitMemo
from frictionwatch.core.monitor.calibration.thermal_shock_watch import judged_cylinders, judged_flags
from frictionwatch.core.monitor.pipeline import STAGES, CyclePipeline, TdcWatch
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.types import Cycle

ANGLE_POINTS = 144  # residual speed kept on a 5 deg grid
# A log that steps between loads (or speeds) is several operating points, and a missing effect's residual differs
# between them (a load-dependent friction law's sign may even flip): pooled, the coherent mean averages it away
# while the between-point spread reads as noise (a k9k log stepping 0.8 <-> 0.45: the gap read 0, healthy and with
# a Stribeck ring or a load-dependent bearing law alike). Cycles are grouped where the sorted per-cycle loads (or
# speeds) jump by more than this fraction of the log's median: a design choice (an operating point another by 5 % of
# load or 2 % of speed, well above a steady log's per-cycle scatter of the measured load power), not tuned on a case
GROUP_LOAD_STEP = 0.05
GROUP_SPEED_STEP = 0.02
GROUP_NOISE = 8.0  # and by more than 8 sigma of the cycle-to-cycle scatter: noise alone never splits a steady log
PINNED_SIGMA = 1e-4  # prior sigma of every friction scale: the model's coefficients are used as they are


def pinned_config(config: MonitorConfig | None = None) -> MonitorConfig:
    """The friction scales pinned to the model; equations accumulated from the third cycle: with the friction pinned
    only the in-band tooth nuisance is learned from them, and until it is the residual carries the wheel's pattern
    (measured, k9k 2500 rpm: the held-out gap of the true model 59 over cycles 12-36 with the default 20-cycle
    warm-up, 2.2 with 2, its floor); each cycle's result carries what the nuisances' remaining uncertainty puts into
    its residual (MonitorConfig.nuisance_spread: Residuals.pattern_sigma, design note 118)."""
    return dataclasses.replace(config or MonitorConfig(), parameter_sigma=PINNED_SIGMA, sibling_spread=0.0,
                               warmup_cycles=2, nuisance_spread=True)


@dataclass(frozen=True)
class Residuals:
    """N analysed cycles. index (N,) cycle numbers; omega (N,) rad/s; load (N,) N m; harmonics (N, M) complex rad/s;
    balance (N,) N m (NaN without the cycle before); speed (N, ANGLE_POINTS) rad/s residual on ``angles`` (rad);
    rejected: cycles the monitor refused; measured (N, M) rad/s the amplitude of the measured speed at each engine order
    in each cycle: the engine's own speed fluctuation, the scale of the model-error floor
    (core.discrepancy.features.speed_floor_rpm); tdc_deg, tdc_sigma_deg (z,) each cylinder's TDC offset from its
    pressure at the end of the run (the pipeline's TDC watch, core.monitor.calibration.tdc_watch; NaN where no window
    closed) [deg, + = TDC later than the model says]."""

    index: np.ndarray
    omega: np.ndarray
    load: np.ndarray
    harmonics: np.ndarray
    balance: np.ndarray
    speed: np.ndarray
    angles: np.ndarray
    rejected: int = 0
    measured: np.ndarray | None = None
    tdc_deg: np.ndarray | None = None
    tdc_sigma_deg: np.ndarray | None = None
    friction: np.ndarray | None = None  # (N,) N m the engine's friction the mean balance measured in each cycle
    # each cylinder's pegging read from its pressure (the TDC watch's, what to add to the pressure against the run's
    # model) and its sigma [Pa] (sampling, wall heat and a loss the model lacks, as the TDC's); NaN where none
    pegging_pa: np.ndarray | None = None
    pegging_sigma_pa: np.ndarray | None = None
    # (N, z) whether the monitor's condition check called cylinder k's burn in cycle i a misfire (misfire_cyl<k>:
    # unburned or partial while a sibling burned, core.monitor.checks.condition); False in a motored cycle
    misfired: np.ndarray | None = None
    motored: np.ndarray | None = None  # (N,) the monitor called the cycle motored (no cylinder burned)
    # (N, z) whether the condition check called cylinder k's compression a leak in cycle i (blow_by_cyl<k> or
    # ring_wear_cyl<k>: compression rise, peak and work below the siblings' over its window); (N, z) its ln
    # compression pressure against the siblings' (the ring indicators' compression_ratio; NaN without them)
    leak_flagged: np.ndarray | None = None
    compression_ln: np.ndarray | None = None
    # (N,) the operating point each cycle ran at (operating_groups over the whole run: the same cycles fall in the
    # same group in every model's run, since speed and load are the measurement's); None: one group
    group: np.ndarray | None = None
    between_points: int = 0  # cycles left out as a load step's (operating_groups: -1)
    # (N,) N m the balance's kinetic term J(2 pi) x the window's angle-averaged dw/dt (what the monitor subtracted
    # from indicated - load - coupling loss; NaN without the cycle before): the balance's own error grows with it
    # (features.balance_point_floor_nm, design note 68)
    kinetic: np.ndarray | None = None
    # (N, M) rad/s the spread of each residual harmonic that the in-band tooth nuisances' posterior still carried in
    # that cycle (CycleResult.residual_pattern_sigma; None: not asked for): a coherent part of the residual the
    # pattern's unconverged estimate can explain (core.discrepancy.features.order_table, design note 118)
    pattern_sigma: np.ndarray | None = None
    # the monitor's per-run reading of its pressure sensors: each ``sensor_*`` flag -> the analysed cycles it stood
    # in over the whole run (not cut by ``take``: what the monitor says of the sensors having read the log;
    # core.discrepancy.sensor_faults)
    sensor_flag_cycles: dict | None = None

    @property
    def n_cycles(self) -> int:
        return int(self.index.shape[0])

    def take(self, mask: np.ndarray) -> Residuals:
        return dataclasses.replace(self, index=self.index[mask], omega=self.omega[mask], load=self.load[mask],
                                   harmonics=self.harmonics[mask], balance=self.balance[mask], speed=self.speed[mask],
                                   measured=None if self.measured is None else self.measured[mask],
                                   friction=None if self.friction is None else self.friction[mask],
                                   misfired=None if self.misfired is None else self.misfired[mask],
                                   motored=None if self.motored is None else self.motored[mask],
                                   leak_flagged=None if self.leak_flagged is None else self.leak_flagged[mask],
                                   compression_ln=None if self.compression_ln is None else self.compression_ln[mask],
                                   group=None if self.group is None else self.group[mask],
                                   kinetic=None if self.kinetic is None else self.kinetic[mask],
                                   pattern_sigma=None if self.pattern_sigma is None else self.pattern_sigma[mask])

    def features(self) -> np.ndarray:
        """(N, 2M + 1) real features: Re and Im of each residual harmonic, then the balance residual (0 where NaN:
        the first cycle has no balance)."""
        return np.column_stack([self.harmonics.real, self.harmonics.imag, np.nan_to_num(self.balance)])


def _clusters(x: np.ndarray, step: float) -> tuple[np.ndarray, float]:
    """(N,) labels of ``x`` split where its sorted values jump by more than ``step``, or than GROUP_NOISE x its own
    cycle-to-cycle scatter (from successive differences in time, which a few steps hardly move), the larger; and
    that threshold."""
    noise = 1.4826 * float(np.median(np.abs(np.diff(x)))) / np.sqrt(2.0) if x.shape[0] > 2 else 0.0
    threshold = max(step, GROUP_NOISE * noise)
    order = np.argsort(x, kind="stable")
    labels = np.empty(x.shape[0], dtype=np.int64)
    labels[order] = np.concatenate([[0], np.cumsum(np.diff(x[order]) > threshold)])
    return labels, threshold


def operating_groups(omega: np.ndarray, load: np.ndarray, torque_scale: float) -> np.ndarray:
    """(N,) a label per cycle (in time order), one per operating point: cycles whose sorted speeds or loads are
    separated by a jump of more than GROUP_SPEED_STEP of the median speed / GROUP_LOAD_STEP of ``torque_scale`` (the
    engine's indicated torque, load + friction: at zero load a step is one of the friction's size, never of the load's
    noise) and of their own scatter; a ramp without such a jump stays one group. -1: between points, both cycles of
    a load jump that large from one cycle to the next (a step within a cycle makes two: before and after its
    intermediate load), and the cycle after those (the speed still settling): its residual is the step's, not the
    model's (k9k: 8 rpm at order 0.5 in the step's cycle, 0.6 in the next, noise 0.07). A cycle whose speed or load
    is not finite (unknown point) is put at 0, a group of its own where the others run."""
    omega, load = np.nan_to_num(omega, posinf=0.0, neginf=0.0), np.nan_to_num(load, posinf=0.0, neginf=0.0)
    if omega.shape[0] < 2:
        return np.zeros(omega.shape[0], dtype=np.int64)
    by_speed, _ = _clusters(omega, GROUP_SPEED_STEP * abs(float(np.median(omega))))
    by_load, load_step = _clusters(load, GROUP_LOAD_STEP * abs(torque_scale))
    labels = np.unique(by_speed * (by_load.max() + 1) + by_load, return_inverse=True)[1].astype(np.int64)
    jump = np.abs(np.diff(load)) > load_step
    step = np.r_[False, jump] | np.r_[jump, False]
    labels[step | np.r_[False, step[:-1]]] = -1
    return labels


def run_model(model: EngineModel, ref: Reference, config: MonitorConfig, cycles: Sequence[Cycle],
              tdc_memo: TdcFitMemo | None = None) -> Residuals:
    """The product's pipeline (core.monitor.pipeline) over ``cycles`` in order with ``model`` (its view sized at
    ``ref``) and ``config``; refused cycles are counted, not raised. ``tdc_memo``: the TDC watch's fits remembered
    across the runs of one log (core.monitor.calibration.tdc_memo; None: each fitted afresh)."""
    angles = np.linspace(0.0, 4.0 * np.pi, ANGLE_POINTS, endpoint=False)
    rows: list[tuple] = []
    rejected = 0
    z = model.spec.n_cyl
    # the TDC watch reads every cylinder once, over the whole log (close_windows below): serving, it fits four of a
    # large engine's cylinders per 100-cycle window in turn, so a 120-cycle log read four of genset-v20's twenty, and
    # a log shorter than 100 cycles none
    fit = None if tdc_memo is None else tdc_memo.fit
    stages = tuple(dataclasses.replace(s, per_window=z, window=len(cycles) + 1, fit=fit) if isinstance(s, TdcWatch)
                   else s for s in STAGES)
    pipe = CyclePipeline(model, config, ref, stages=stages)
    misfire_flags = [f"misfire_cyl{k + 1}" for k in range(z)]  # the condition check's, made once per run
    leak_flags = [(f"blow_by_cyl{k + 1}", f"ring_wear_cyl{k + 1}") for k in range(z)]
    no_ring = np.full(z, np.nan)
    inertia = mid_cycle_inertia(model.spec)  # the transient balance's J (core.monitor.identify.identification)
    sensor_flags: dict[str, int] = {}
    for cycle in cycles:
        r = pipe.process(cycle).result
        if r is None:
            rejected += 1
            continue
        for f in r.flags:
            if f.startswith("sensor_"):
                sensor_flags[f] = sensor_flags.get(f, 0) + 1
        friction = float(np.mean(r.friction_torque)) if r.friction_torque is not None else math.nan
        resid = np.interp(angles, r.grid, r.speed_measured - r.speed_model, period=4.0 * np.pi)
        m = r.residual_harmonics.shape[0]
        measured = 2.0 * np.abs(np.fft.rfft(r.speed_measured)[1:m + 1]) / r.speed_measured.shape[0]
        misfired = np.array([f in r.flags for f in misfire_flags])
        leaking = np.array([a in r.flags or b in r.flags for a, b in leak_flags])
        ring = r.ring.compression_ratio if r.ring is not None else no_ring
        rows.append((r.index, r.omega_mean, r.load_torque, r.residual_harmonics, r.friction_balance - friction, resid,
                     measured, r.friction_balance, misfired, "motored" in r.flags, inertia * r.acceleration, leaking,
                     ring, r.residual_pattern_sigma))
    if not rows:
        raise ValueError(f"the monitor analysed none of the {len(cycles)} cycles")
    pipe.close_windows()  # the pressure's reading of the whole log
    # the thermal-shock watch judges no cylinder whose throws a flagged TDC offset moves (judged_cylinders); here the
    # TDC watch reads once, at the log's end, so the watch's verdicts saw no TDC flag: the same rule, on the log
    kept = judged_flags(tuple(sensor_flags), judged_cylinders(tuple(pipe.stages["tdc_watch"].flags), z))
    sensor_flags = {f: sensor_flags[f] for f in kept}
    omega, load, friction = (np.array([r[i] for r in rows]) for i in (1, 2, 7))
    indicated = load + friction
    scale = float(np.median(np.abs(indicated[np.isfinite(indicated)]))) if np.isfinite(indicated).any() else 0.0
    group = operating_groups(omega, load, scale)
    res = Residuals(index=np.array([r[0] for r in rows]), omega=omega, load=load, group=group,
                     harmonics=np.array([r[3] for r in rows]),
                     balance=np.array([r[4] for r in rows]), speed=np.array([r[5] for r in rows]), angles=angles,
                     rejected=rejected, measured=np.array([r[6] for r in rows]),
                     friction=friction, misfired=np.array([r[8] for r in rows]),
                     motored=np.array([r[9] for r in rows]), kinetic=np.array([r[10] for r in rows]),
                     leak_flagged=np.array([r[11] for r in rows]),
                     compression_ln=np.array([r[12] for r in rows]),
                     pattern_sigma=None if any(r[13] is None for r in rows) else np.array([r[13] for r in rows]),
                     sensor_flag_cycles=sensor_flags, **_tdc_reading(pipe))
    # the cycles of a load step are no operating point's: left out of every figure, and counted
    return dataclasses.replace(res.take(group >= 0), between_points=int(np.sum(group < 0)))


def _tdc_reading(pipe: CyclePipeline) -> dict:
    """The TDC watch's newest per-cylinder offsets and sigmas [deg] and peggings and their sampling sigmas [Pa] (NaN
    where it has none)."""
    last = pipe.stages["tdc_watch"].last
    z = pipe.spec.n_cyl
    if last is None:
        last = (None,) * z

    def each(value) -> np.ndarray:
        return np.array([value(e) if e is not None else np.nan for e in last], dtype=np.float64)

    return {"tdc_deg": each(lambda e: np.degrees(e.offset_rad)), "tdc_sigma_deg": each(lambda e: np.degrees(e.sigma_rad)),
            "pegging_pa": each(lambda e: e.pegging_pa),
            "pegging_sigma_pa": each(lambda e: math.hypot(*(e.evidence.get(f"pegging_{part}_pa", np.nan) for part in
                                                             ("statistical", "heat_loss", "constant_loss"))))}


def mean_load(cycles: Sequence[Cycle], omega: float, efficiency: float = 1.0) -> float:
    """The log's median load torque [N m] as the monitor reads it (the torque, else the power over the generator's
    ``efficiency`` and the speed: ``shaft_load``); NaN where neither is measured."""
    loads = np.array([shaft_load(c.load_torque, c.load_power, omega, efficiency)[0] for c in cycles])
    loads = loads[np.isfinite(loads)]
    return float(np.median(loads)) if loads.size else float("nan")


__all__ = ["ANGLE_POINTS", "GROUP_LOAD_STEP", "GROUP_NOISE", "GROUP_SPEED_STEP", "PINNED_SIGMA", "Residuals", "mean_load",
           "operating_groups",
           "pinned_config", "run_model"]
