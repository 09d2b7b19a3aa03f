"""Watching the pressure channels while the engine runs: each channel's gain and pegging against its siblings, window
by window, against what the model's calibration says (issue 25 item 3: a gain that drifts after commissioning is
flagged on its cylinder and withholds that cylinder's figures; never a confident figure on a wrong channel).

Every cycle adds its pressure to one of ``BLOCKS`` running block sums; every ``window`` cycles each block's mean
cycle is compared over the compression stroke (core.monitor.checks.sensor_evidence.sibling_compare via
core.monitor.calibration.pressure_gain.cycle_comparison: the comparison commissioning averages over its recording),
the blocks' comparisons give the window's statistics (pressure_gain.sibling_stats: mean, standard error from the
blocks' scatter, the siblings' robust spread), they decide the flags and the sums start again, as in the TDC watch
(core.monitor.calibration.tdc_watch). Per cycle that is one addition; a comparison per cycle (a few small
least-squares solves) had cost 0.26 ms on k9k and 0.47 ms on genset-v20 (h-gainwatch's figures, under load).

What is flagged (``sensor_pressure_gain_cyl<k>``, ``sensor_pressure_offset_cyl<k>``; the ``sensor_`` prefix withholds
that cylinder's figures, core.monitor.report.figure_status), only with three or more cylinders (two cannot say which one is
off; a one-cylinder engine has no sibling and no check):
- the minimum a reading must exceed, for both kinds of model: the sensor-health stage's thresholds
  (core.monitor.checks.sensor_health.SensorHealthConfig: gain 2 %, offset 0.2 bar, and ``spread_sigmas`` = 3 of the
  siblings' own robust spread; tuned there on bench/sensor_faults.py; here the spread of the siblings without the
  channel judged, ``sibling_spread``) and ``DRIFT_SIGMAS`` of the window's statistical sigma;
- commissioned model (its gain and pegging corrections applied, so every channel is expected at 1 and 0 against its
  siblings): a gain beyond ``DRIFT_SIGMAS`` of the window's statistical sigma and the calibration's per-channel
  ``gain_sigma`` together;
- uncalibrated model: a gain beyond what the assumed installation allows each channel (``Calibration.gain_sigma``,
  3 %) by the minimum above: the data contradict the assumption, and the channel stands out of its siblings.
A pegging offset has no calibration sigma (a constant offset does no work over the cycle; commissioning corrects
pegging beyond the same 0.2 bar, core.monitor.calibration.commission.PEGGING_MIN_PA): it is flagged beyond the
minimum alone. A flag holds until a window says otherwise.

The pistons are compared at the same position: ``lead`` is each throw's static twist ahead of the flywheel in the
monitor's model (the caller's spec already carries the model's TDC corrections in its firing angles).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.calibration.pressure_gain import (
    SiblingStats,
    SiblingSums,
    cycle_comparison,
    sibling_stats,
)
from frictionwatch.core.monitor.calibration.tdc import BLOCKS
from frictionwatch.core.monitor.calibration.tdc_watch import WINDOW_CYCLES
from frictionwatch.core.monitor.calibration.tdc_window import DRIFT_SIGMAS
from frictionwatch.core.monitor.checks.sensor_health import SensorHealthConfig
from frictionwatch.core.types import Cycle

_HEALTH = SensorHealthConfig()
MIN_GAIN = _HEALTH.gain  # 0.02: the sensor-health stage's gain threshold
MIN_OFFSET_PA = _HEALTH.offset_pa  # 0.2 bar: ... its pegging threshold
SPREAD_SIGMAS = _HEALTH.spread_sigmas  # 3: ... beyond the siblings' own robust spread
MIN_CYLINDERS = 3


@dataclass(frozen=True)
class PressureBlocks:
    """A window's cycles' pressure in ``BLOCKS`` running block sums (the gain and thermal-shock watches' evidence: each
    block's mean cycle is compared at the window's end). sums: BLOCKS arrays (z, n) (None before the first cycle; a
    cycle replaces its block's array by a new one, never writes into one: 9 against 19 us per genset-v20 cycle for
    copying all five), counts (BLOCKS,) the cycles in each; cycles seen in the window (a cycle with a NaN sample
    counts here, not in the sums), used: those in the sums, lead_sum (z,) their leads summed [rad]."""

    sums: tuple[np.ndarray, ...] | None = None
    counts: np.ndarray | None = None
    cycles: int = 0
    used: int = 0
    lead_sum: np.ndarray | float = 0.0

    def add(self, pressure: np.ndarray, lead: np.ndarray) -> PressureBlocks:
        """These blocks with one more cycle's ``pressure`` (z, n) and ``lead`` (z,) rad (module doc)."""
        p = np.asarray(pressure, dtype=np.float64)
        fresh = self.sums is None or len(self.sums) != BLOCKS or self.sums[0].shape != p.shape
        sums = (np.zeros(p.shape),) * BLOCKS if fresh else self.sums  # read only: a block is replaced, not written
        counts = np.zeros(BLOCKS) if fresh or self.counts is None else self.counts.copy()
        used, lead_sum = (0, 0.0) if fresh else (self.used, self.lead_sum)
        if math.isfinite(p.sum()):  # a NaN sample: the cycle counts in the window, not in the sums (NaN, inf propagate)
            b = self.cycles % BLOCKS
            sums = sums[:b] + (sums[b] + p,) + sums[b + 1:]
            counts[b] += 1
            used += 1
            lead_sum = lead_sum + np.asarray(lead, dtype=np.float64)
        return PressureBlocks(sums, counts, self.cycles + 1, used, lead_sum)

    def mean_cycles(self, cycle: Cycle) -> list[Cycle]:
        """Each filled block's mean cycle: ``cycle`` (the window's newest: its grid) with the block's mean pressure."""
        return [dataclasses.replace(cycle, pressure=self.sums[b] / self.counts[b]) for b in np.flatnonzero(self.counts)]

    def lead_mean(self, z: int) -> np.ndarray:
        """(z,) the used cycles' mean lead [rad]."""
        return np.broadcast_to(self.lead_sum / self.used, (z,))


@dataclass(frozen=True)
class GainWatchState:
    """blocks: the current window's pressure (``PressureBlocks``); last: the newest window's statistics (over its
    blocks) or None; flags in force."""

    blocks: PressureBlocks
    last: SiblingStats | None
    flags: tuple[str, ...]

    @staticmethod
    def empty() -> GainWatchState:
        return GainWatchState(PressureBlocks(), None, ())


def watch_gains(spec: EngineSpec, cal: Calibration, state: GainWatchState, cycle: Cycle, lead: np.ndarray,
                window: int = WINDOW_CYCLES) -> GainWatchState:
    """``state`` with ``cycle`` (the pressure as the monitor gets it, its corrections applied) added; lead (z,) rad
    each piston ahead of the flywheel angle its pressure is sampled at (the static twist); at the end of a window
    the flags are decided (module doc). Below three cylinders nothing is compared and nothing flagged."""
    z = spec.n_cyl
    if z < MIN_CYLINDERS:
        return state
    blocks = state.blocks.add(cycle.pressure, lead)
    if blocks.cycles < window:
        return GainWatchState(blocks, state.last, state.flags)
    if blocks.used < window // 2:  # most of the window unusable: no verdict, the old one stands
        return GainWatchState(PressureBlocks(), state.last, state.flags)
    lead_mean = blocks.lead_mean(z)
    rows = SiblingSums.empty(z)
    for mean_cycle in blocks.mean_cycles(cycle):
        rows = rows.add(cycle_comparison(spec, mean_cycle, lead_mean))
    stats = sibling_stats(rows)
    if stats is None or stats.n < 2:
        return GainWatchState(PressureBlocks(), state.last, state.flags)
    return GainWatchState(PressureBlocks(), stats, gain_flags(cal, stats))


def gain_limits(cal: Calibration, stats: SiblingStats) -> tuple[np.ndarray, np.ndarray]:
    """(gain (z,), offset (z,) Pa): how far from 1 and 0 each channel may read against its siblings before it is
    flagged (module doc)."""
    sem_g, sem_o = stats.sem
    spread_g, spread_o = sibling_spread(stats.mean)
    min_g = np.maximum(MIN_GAIN, np.maximum(SPREAD_SIGMAS * spread_g, DRIFT_SIGMAS * sem_g))
    min_o = np.maximum(MIN_OFFSET_PA, np.maximum(SPREAD_SIGMAS * spread_o, DRIFT_SIGMAS * sem_o))
    if cal.commissioned:
        lim_g = np.maximum(DRIFT_SIGMAS * np.hypot(sem_g, cal.gain_sigma), min_g)
    else:
        lim_g = cal.gain_sigma + min_g
    return lim_g, min_o


def sibling_spread(mean: np.ndarray) -> np.ndarray:
    """(2, z): for each channel the robust spread (1.4826 MAD) of its siblings' readings without its own, gain and
    offset. Leaving the channel out matters on three cylinders: there the spread of all three is the distance of
    one healthy channel from the median, which a faulty third one moves (maruti, a channel at 0.94: the healthy
    pair read +1.1 and +0.1 %, the spread of all three 1.5 %, of the pair 0.7 %; bench/sensor_flags.py --faults)."""
    z = mean.shape[1]
    out = np.empty_like(mean)
    for k in range(z):
        others = np.delete(mean, k, axis=1)
        out[:, k] = 1.4826 * np.median(np.abs(others - np.median(others, axis=1, keepdims=True)), axis=1)
    return out


def gain_flags(cal: Calibration, stats: SiblingStats) -> tuple[str, ...]:
    """The flags one window's statistics raise against the calibration (module doc); gain before offset, each in
    cylinder order."""
    z = stats.mean.shape[1]
    if z < MIN_CYLINDERS or not np.all(np.isfinite(stats.mean)):
        return ()
    lim_g, lim_o = gain_limits(cal, stats)
    gain, offset = stats.mean
    return tuple([f"sensor_pressure_gain_cyl{k + 1}" for k in range(z) if abs(gain[k]) > lim_g[k]]
                 + [f"sensor_pressure_offset_cyl{k + 1}" for k in range(z) if abs(offset[k]) > lim_o[k]])


__all__ = ["GainWatchState", "MIN_GAIN", "MIN_OFFSET_PA", "SPREAD_SIGMAS", "PressureBlocks", "gain_flags", "gain_limits",
           "sibling_spread", "watch_gains"]

