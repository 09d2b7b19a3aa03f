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
(core.monitor.calibration.pressure_gain.cycle_comparison, the gain watch's comparison), is taken off first. A common
change (load, speed, the engine's heat transfer) moves every cylinder's bend alike; what is compared is a cylinder's
bend minus its siblings' median. Simulated, seed 5, k9k-4cyl 1700 rpm full load, 24 cycles: healthy cylinders'
bends +0.017..+0.024 (dev within 0.004); one cylinder shocked 0.2 bar -> dev -0.010, 0.5 bar -> -0.031. A shock in
every cylinder alike cancels here and is not seen (the note's table says what that leaves in the friction figure).

As the gain watch: every cycle adds its pressure to one of ``BLOCKS`` block sums; every ``window`` cycles each
block's mean cycle gives each cylinder's dev, the blocks give its mean and standard error, and a cylinder is flagged
``sensor_thermal_shock_cyl<k>`` (the ``sensor_`` prefix withholds its figures, core.monitor.report.figure_status)
when its dev is below -max(``MIN_BEND``, ``DRIFT_SIGMAS`` x its standard error, ``SPREAD_SIGMAS`` x the robust
spread of its siblings' devs); only with three or more cylinders. A flag holds until a window says otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.kinematics import kinematics
from frictionwatch.core.monitor.calibration.gain_watch import SPREAD_SIGMAS, PressureBlocks
from frictionwatch.core.monitor.calibration.pressure_gain import cycle_comparison
from frictionwatch.core.monitor.calibration.tdc_watch import WINDOW_CYCLES
from frictionwatch.core.monitor.calibration.tdc_window import DRIFT_SIGMAS
from frictionwatch.core.types import Cycle

FOUR_PI = 4.0 * np.pi
# the windows [deg before EVO]: the late one ends 10 deg before EVO (the valve's opening ramp), each spans ~35 deg,
# the early one starts 80 deg before EVO (50 deg after TDC at EVO 130: the burn is over on every preset by then)
EARLY_DEG = (80.0, 45.0)
LATE_DEG = (45.0, 10.0)
STEP_DEG = 1.0
# the least dev flagged: tuned on k9k-4cyl 1700 rpm full load, seed 5 (healthy devs within 0.004, a 0.2 bar shock
# -0.010); tested on maruti-3cyl and genset-v20 and other seeds and loads (bench/thermal_shock_coverage.py)
MIN_BEND = 0.007
MIN_CYLINDERS = 3


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
    where its piston is (``lead`` (z,) rad ahead of the flywheel angle the pressure is sampled at); NaN where the
    pressure is not positive in a window."""
    angles, weights = bend_tables(spec)
    z, n = pressure.shape
    h = FOUR_PI / n
    u = np.mod(angles[None, :] + spec.firing_angles[:, None] - lead[:, None] - grid[0], FOUR_PI) / h
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
    (gain_watch.PressureBlocks); last: the newest window's reading or None; flags in force."""

    blocks: PressureBlocks
    last: BendStats | None
    flags: tuple[str, ...]

    @staticmethod
    def empty() -> ThermalShockWatchState:
        return ThermalShockWatchState(PressureBlocks(), None, ())


def watch_expansion(spec: EngineSpec, state: ThermalShockWatchState, cycle: Cycle, lead: np.ndarray,
                    window: int = WINDOW_CYCLES) -> ThermalShockWatchState:
    """``state`` with ``cycle`` (the pressure as the monitor gets it) added; at the end of a window the flags are
    decided (module doc). Below three cylinders nothing is compared and nothing flagged."""
    z = spec.n_cyl
    if z < MIN_CYLINDERS:
        return state
    blocks = state.blocks.add(cycle.pressure, lead)
    if blocks.cycles < window:
        return ThermalShockWatchState(blocks, state.last, state.flags)
    if blocks.used < window // 2:  # most of the window unusable: no verdict, the old one stands
        return ThermalShockWatchState(PressureBlocks(), state.last, state.flags)
    lead_mean = blocks.lead_mean(z)
    devs = []
    for mean_cycle in blocks.mean_cycles(cycle):
        offset = cycle_comparison(spec, mean_cycle, lead_mean)[1]
        bend = expansion_bend(spec, mean_cycle.grid, mean_cycle.pressure, offset, lead_mean)
        devs.append(bend - np.median(bend))
    stats = bend_stats(np.array(devs))
    if stats is None:
        return ThermalShockWatchState(PressureBlocks(), state.last, state.flags)
    return ThermalShockWatchState(PressureBlocks(), stats, shock_flags(stats))


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
    return tuple(f"sensor_thermal_shock_cyl{k + 1}" for k in range(stats.dev.shape[0])
                 if stats.dev[k] < -stats.limit[k])


__all__ = ["EARLY_DEG", "LATE_DEG", "MIN_BEND", "BendStats", "ThermalShockWatchState", "bend_stats", "bend_tables",
           "expansion_bend", "shock_flags", "watch_expansion"]
