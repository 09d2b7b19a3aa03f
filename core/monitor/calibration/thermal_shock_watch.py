"""Watching each pressure channel's expansion stroke for thermal shock, window by window against its siblings
(design note 156).

A piezoelectric sensor whose diaphragm the flame heats reads low after combustion, most some 30-70 deg after TDC,
and recovers over the rest of the expansion and the exhaust (core.model.thermal_shock gives the physics). Its
compression stroke is right, so neither the gain watch (core.monitor.calibration.gain_watch) nor commissioning sees
it, and over the expansion its error is a nearly constant fraction of the pressure (the error and the pressure fall
together): to first order the channel reads like a cylinder that burns a little less fuel. What it changes is the
expansion's bend: the slope of ln p on -ln V (the apparent polytropic exponent) rises over the early part, where the
error grows relative to the falling pressure, and falls over the late part, where it recovers. So per cylinder

    bend = n(late window) - n(early window)        windows LATE_DEG and EARLY_DEG before EVO

which a channel's gain leaves exactly as it is (a constant in ln p), and a pegging offset moves (an offset weighs more
where p is lower): each channel's pegging against its siblings, read on the same mean cycle over the compression
(core.monitor.calibration.pressure_gain.cycle_comparison, the gain watch's comparison), is taken off first.
Both windows are read where each cylinder's own throw is at the window's angle: the monitor's throw motion (static
twist and its harmonics, core.monitor.checks.ring_pressure.ThrowMotion) averaged over the window's cycles; the
static twist alone where there is none (a rigid shaft line). With the static twist alone, healthy k9k-4cyl at 4000
rpm full load (seed 1) read cylinder 1 (the free end) at -0.014 and flagged it: the twist's harmonics move its
throw -0.09..+0.17 deg against the wheel over the compression window, which the pegging fit took for 0.09 bar
(design note 165). A common
change (load, speed, the engine's heat transfer) moves every cylinder's bend alike; what is compared is a cylinder's
bend minus its siblings' median. Simulated, seed 5, k9k-4cyl 1700 rpm full load, 24 cycles: healthy cylinders'
bends +0.017..+0.024 (dev within 0.004); one cylinder shocked 0.2 bar -> dev -0.010, 0.5 bar -> -0.031. A shock in
every cylinder alike cancels here and is not seen (the note's table says what that leaves in the friction figure).

As the gain watch: every cycle adds its pressure to one of ``BLOCKS`` block sums; every ``window`` cycles each
block's mean cycle gives each cylinder's dev, the blocks give its mean and standard error, and a cylinder is flagged
``sensor_thermal_shock_cyl<k>`` (the ``sensor_`` prefix withholds its figures, core.monitor.report.figure_status)
when its dev is below -max(``MIN_BEND``, ``DRIFT_SIGMAS`` x its standard error, ``SPREAD_SIGMAS`` x the robust
spread of its siblings' devs); only with three or more cylinders. A flag holds until a window says otherwise.

No verdict on a cylinder whose throws a flagged TDC offset moves (``judged_cylinders``: none under the wheel's
``sensor_tdc_offset``, only cylinder k under its own ``sensor_tdc_offset_cyl<k>``; the window's reading is kept and
``not_judged`` says why): the watch reads every channel at the model's phases and each throw where the model's throw
motion puts it, and a TDC flag says the model's phases are wrong, its motion too (made from the gas torque at those
phases). Beside a real 1.5-deg TDC offset on
cylinder 2 (k9k-4cyl 2400 rpm, load steps) the motion read cylinder 3 as shocked (design notes 165, 167). The
verdict is given on the cycle after its window, when the TDC watch (which reads cycles in pairs) has read the same.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.kinematics import kinematics
from frictionwatch.core.monitor.calibration.gain_watch import SPREAD_SIGMAS, PressureBlocks
from frictionwatch.core.monitor.calibration.pressure_gain import COMPRESSION_WINDOW_DEG, cycle_comparison
from frictionwatch.core.monitor.calibration.tdc_watch import WINDOW_CYCLES
from frictionwatch.core.monitor.calibration.tdc_window import DRIFT_SIGMAS
from frictionwatch.core.monitor.checks.ring_pressure import ThrowMotion, throw_lag_reference
from frictionwatch.core.monitor.checks.sensor_evidence import compression_angles
from frictionwatch.core.types import Cycle

FOUR_PI = 4.0 * np.pi
# the windows [deg before EVO]: the late one ends 10 deg before EVO (the valve's opening ramp), each spans ~35 deg,
# the early one starts 80 deg before EVO (50 deg after TDC at EVO 130: the burn is over on every preset by then)
EARLY_DEG = (80.0, 45.0)
LATE_DEG = (45.0, 10.0)
STEP_DEG = 1.0
# the least dev flagged: tuned on k9k-4cyl 1700 rpm full load, seed 5 (healthy devs within 0.004, a 0.2 bar shock
# -0.010); tested on maruti-3cyl and genset-v20 and other seeds and loads (bench/thermal_shock_coverage.py), and
# unchanged by note 165: tested on its 56 healthy logs, seeds 1-2, and its shocks (bench/thermal_shock_false_flags.py)
MIN_BEND = 0.007
MIN_CYLINDERS = 3
# the TDC flags (the TDC watch's, core.monitor.calibration.tdc_window, and the sensor-health check's): while one is in
# force the cylinders whose throws it moves get no verdict (module doc), and the reading says why
TDC_FLAG = "sensor_tdc_offset"
SHOCK_FLAG = "sensor_thermal_shock_cyl"  # this watch's flag of cylinder <k>
NOT_JUDGED_TDC = "not judged: a TDC offset is flagged"


def judged_cylinders(flags: tuple[str, ...], n_cyl: int) -> np.ndarray:
    """(n_cyl,) bool: the cylinders whose shock the watch may judge under ``flags`` (a cycle's, so far). None under
    the wheel's TDC flag (every throw's motion is off); under cylinder k's own, k only: its siblings' throws are read
    where a model with k's TDC wrong puts them (design note 167: k9k 2400 rpm, cylinder 2 1.5 deg off, flagged
    cylinder 3), while a shocked sensor on k is itself one cause of k's TDC flag (the TDC watch read 6 of note 156's
    24 one-cylinder shocks so) and k's own reading is not moved by its own TDC more than a TDC fault's own evidence."""
    if TDC_FLAG in flags:
        return np.zeros(n_cyl, dtype=bool)
    own = [f[len(TDC_FLAG) + 4:] for f in flags if f.startswith(TDC_FLAG + "_cyl")]
    if not own:
        return np.ones(n_cyl, dtype=bool)
    mask = np.zeros(n_cyl, dtype=bool)
    for k in own:
        if k.isdigit() and 1 <= int(k) <= n_cyl:
            mask[int(k) - 1] = True
    return mask


def judged_flags(flags: tuple[str, ...], mask: np.ndarray) -> tuple[str, ...]:
    """``flags`` less this watch's ``sensor_thermal_shock_cyl<k>`` on the cylinders ``mask`` does not let it judge."""
    return tuple(f for f in flags if not f.startswith(SHOCK_FLAG) or mask[int(f[len(SHOCK_FLAG):]) - 1])


def bend_tables(spec: EngineSpec) -> tuple[np.ndarray, np.ndarray]:
    """(angles (L,) rad from firing TDC, weights (L,)): bend = weights . ln p at those angles (the difference of the
    two windows' least-squares slopes of ln p on -ln V, each a fixed linear combination of its samples)."""
    evo = spec.combustion.evo_deg
    parts, weights = [], []
    for (a, b), sign in ((EARLY_DEG, -1.0), (LATE_DEG, 1.0)):
        deg = np.arange(evo - a, evo - b + 1e-9, STEP_DEG)
        x, _, _ = kinematics(np.radians(deg), spec.kinematics_params())
        lv = -np.log(spec.clearance_volume + spec.piston_area * x)
        lv -= lv.mean()
        parts.append(np.radians(deg))
        weights.append(sign * lv / np.sum(lv * lv))  # n = slope of ln p on -ln V = sum(lv ln p) / sum(lv^2)
    return np.concatenate(parts), np.concatenate(weights)


def expansion_bend(spec: EngineSpec, grid: np.ndarray, pressure: np.ndarray, offset: np.ndarray,
                   lead: np.ndarray) -> np.ndarray:
    """(z,) each cylinder's bend (module doc) of ``pressure`` (z, n) on ``grid`` less its ``offset`` (z,) Pa, read
    where its piston is (``lead`` (z,) rad ahead of the flywheel angle the pressure is sampled at, or (z, L) at each
    of ``bend_tables``' angles); NaN where the pressure is not positive in a window."""
    angles, weights = bend_tables(spec)
    z, n = pressure.shape
    h = FOUR_PI / n
    u = np.mod(angles[None, :] + spec.firing_angles[:, None] - np.reshape(lead, (z, -1)) - grid[0], FOUR_PI) / h
    i0 = np.floor(u).astype(np.int64)
    f = u - i0
    rows = np.arange(z)[:, None]
    p = pressure[rows, i0 % n] * (1.0 - f) + pressure[rows, (i0 + 1) % n] * f - offset[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        lnp = np.where(p > 0.0, np.log(np.where(p > 0.0, p, 1.0)), np.nan)
    return lnp @ weights


@dataclass(frozen=True)
class BendStats:
    """One window's reading: dev (z,) each cylinder's bend minus its siblings' median, mean over the blocks; sem (z,)
    its standard error (the blocks' scatter); spread (z,) the robust spread (1.4826 MAD) of the other cylinders'
    devs; limit (z,) how far below 0 a dev may read before it is flagged; blocks used."""

    dev: np.ndarray
    sem: np.ndarray
    spread: np.ndarray
    limit: np.ndarray
    blocks: int


@dataclass(frozen=True)
class ThermalShockWatchState:
    """As core.monitor.calibration.gain_watch.GainWatchState: blocks, the window's pressure
    (gain_watch.PressureBlocks); last: the newest window's reading or None; flags in force; motion: the throw
    motions of the window's summed cycles that had one, summed (``add_motion``), or None; motion_cycles: how many;
    not_judged: why the newest window's reading gave no verdict (``NOT_JUDGED_TDC``), or ''; due: the newest
    window is read and its verdict is given on the next cycle (``watch_expansion``)."""

    blocks: PressureBlocks
    last: BendStats | None
    flags: tuple[str, ...]
    motion: ThrowMotion | None = None
    motion_cycles: int = 0
    not_judged: str = ""
    due: bool = False

    @staticmethod
    def empty() -> ThermalShockWatchState:
        return ThermalShockWatchState(PressureBlocks(), None, ())


def add_motion(total: ThrowMotion | None, count: int, motion: ThrowMotion) -> tuple[ThrowMotion, int]:
    """(the sum, count) with ``motion`` added, its harmonics turned to the flywheel angle 0 (theta_start 0: cycles
    that start at different edges add alike); a sum of another harmonic count is restarted from this one."""
    orders = np.arange(1, motion.relative.shape[1] + 1)
    here = ThrowMotion(np.asarray(motion.static, dtype=np.float64),
                       motion.relative * np.exp(-0.5j * orders * motion.theta_start)[None, :], 0.0)
    if total is None or total.relative.shape != here.relative.shape:
        return here, 1
    return ThrowMotion(total.static + here.static, total.relative + here.relative, 0.0), count + 1


def window_leads(spec: EngineSpec, blocks: PressureBlocks, motion: ThrowMotion | None,
                 count: int) -> tuple[np.ndarray, np.ndarray]:
    """((z, Lc), (z, Le)) rad each throw ahead of the flywheel at the compression window's samples and at
    ``bend_tables``' angles: the window's mean throw motion, or its mean static twist where it had none."""
    z = spec.n_cyl
    comp = compression_angles(spec, COMPRESSION_WINDOW_DEG)[None, :] + spec.firing_angles[:, None]
    expa = bend_tables(spec)[0][None, :] + spec.firing_angles[:, None]
    if motion is None or count == 0:
        lead = np.asarray(blocks.lead_mean(z), dtype=np.float64)[:, None]
        return np.broadcast_to(lead, comp.shape), np.broadcast_to(lead, expa.shape)
    mean = ThrowMotion(motion.static / count, motion.relative / count, 0.0)
    return throw_lag_reference(mean, comp), throw_lag_reference(mean, expa)


def watch_expansion(spec: EngineSpec, state: ThermalShockWatchState, cycle: Cycle, lead: np.ndarray,
                    window: int = WINDOW_CYCLES, motion: ThrowMotion | None = None,
                    judged: np.ndarray | None = None) -> ThermalShockWatchState:
    """``state`` with ``cycle`` (the pressure as the monitor gets it) added, ``lead`` (z,) rad its throws' static
    twist and ``motion`` their motion in it (None: the static twist only); at the end of a window its pressure is
    read, and its verdict given on the next cycle (the TDC watch reads cycles in pairs: its window of the same cycles
    closes one cycle later) on the cylinders ``judged`` (z,) bool lets it judge (``judged_cylinders`` of the TDC
    flags in force on that cycle; None: all); a cylinder withheld gets no flag, and ``not_judged`` says why (module
    doc). Below three cylinders nothing is compared and nothing flagged."""
    z = spec.n_cyl
    if z < MIN_CYLINDERS:
        return state
    if state.due:  # the newest window's verdict, given on the cycle after it: the TDC watch has read its cycles
        mask = np.ones(z, dtype=bool) if judged is None else judged
        flags, why = judged_flags(shock_flags(state.last), mask), "" if mask.all() else NOT_JUDGED_TDC
        state = ThermalShockWatchState(state.blocks, state.last, flags, state.motion, state.motion_cycles, why)
    blocks = state.blocks.add(cycle.pressure, lead)
    restarted = blocks.used < state.blocks.used  # the blocks began again (a cycle on another grid)
    total, count = (None, 0) if restarted else (state.motion, state.motion_cycles)
    if motion is not None and blocks.used > (0 if restarted else state.blocks.used):  # summed: its motion too
        total, count = add_motion(total, count, motion)
    if blocks.cycles < window:
        return ThermalShockWatchState(blocks, state.last, state.flags, total, count, state.not_judged)
    if blocks.used < window // 2:  # most of the window unusable: no verdict, the old one stands
        return ThermalShockWatchState(PressureBlocks(), state.last, state.flags, not_judged=state.not_judged)
    comp_lead, bend_lead = window_leads(spec, blocks, total, count)
    devs = []
    for mean_cycle in blocks.mean_cycles(cycle):
        offset = cycle_comparison(spec, mean_cycle, comp_lead)[1]
        bend = expansion_bend(spec, mean_cycle.grid, mean_cycle.pressure, offset, bend_lead)
        devs.append(bend - np.median(bend))
    stats = bend_stats(np.array(devs))
    if stats is None:
        return ThermalShockWatchState(PressureBlocks(), state.last, state.flags, not_judged=state.not_judged)
    return ThermalShockWatchState(PressureBlocks(), stats, state.flags, not_judged=state.not_judged, due=True)


def bend_stats(devs: np.ndarray) -> BendStats | None:
    """The window's reading from its blocks' devs (B, z); None below two blocks or with a NaN."""
    if devs.shape[0] < 2 or not np.all(np.isfinite(devs)):
        return None
    mean = devs.mean(axis=0)
    sem = devs.std(axis=0, ddof=1) / math.sqrt(devs.shape[0])
    z = mean.shape[0]
    spread = np.empty(z)
    for k in range(z):
        others = np.delete(mean, k)
        spread[k] = 1.4826 * np.median(np.abs(others - np.median(others)))
    limit = np.maximum(MIN_BEND, np.maximum(DRIFT_SIGMAS * sem, SPREAD_SIGMAS * spread))
    return BendStats(mean, sem, spread, limit, devs.shape[0])


def shock_flags(stats: BendStats) -> tuple[str, ...]:
    """``sensor_thermal_shock_cyl<k>`` for each cylinder whose dev reads below -limit, in cylinder order."""
    return tuple(f"{SHOCK_FLAG}{k + 1}" for k in range(stats.dev.shape[0])
                 if stats.dev[k] < -stats.limit[k])


__all__ = ["EARLY_DEG", "LATE_DEG", "MIN_BEND", "NOT_JUDGED_TDC", "SHOCK_FLAG", "TDC_FLAG", "BendStats", "ThermalShockWatchState", "add_motion", "bend_stats",
           "bend_tables", "expansion_bend", "judged_cylinders", "judged_flags", "shock_flags",
           "watch_expansion", "window_leads"]
