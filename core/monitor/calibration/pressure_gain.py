"""Each pressure channel's gain and pegging against its siblings over a commissioning recording (issue 25).

Cylinders share the intake manifold, so over the compression stroke (after IVC, before combustion) their traces
differ by each channel's gain and pegging and by what differs in their trapped charge. The per-cycle comparison is
core.monitor.checks.sensor_evidence.sibling_compare (the sensor-health stage's own); here it is averaged over the
recording. What a healthy set of cylinders differs by in charge is not a sensor error, so a channel's gain is
corrected only where it stands out of its siblings' own robust spread (1.4826 MAD across the channels) by
``SPREAD_SIGMAS``; a channel left uncorrected keeps its reading (and that spread) in its sigma. A gain common to
every channel cannot be seen by a sibling comparison: it stays what the caller states (core.model.calibration).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.checks.sensor_evidence import sibling_compare
from frictionwatch.core.types import Cycle

COMPRESSION_WINDOW_DEG = (-100.0, -25.0)  # the sensor-health stage's (core.monitor.checks.sensor_health.SensorHealthConfig)
# a channel is corrected when beyond this many robust spreads of its siblings and MIN_GAIN_ERROR: the sensor-health
# stage's spread_sigmas and its gain threshold (tuned there on bench/sensor_faults.py, not on the cases here)
SPREAD_SIGMAS = 3.0
MIN_GAIN_ERROR = 0.02
FLOOR_GAIN = 0.003  # what a sibling comparison cannot resolve whatever the cycle count (SensorHealthConfig.floor_gain)


@dataclass(frozen=True)
class SiblingSums:
    """Running sums of the per-cycle sibling comparison (core.monitor.checks.sensor_evidence.sibling_compare) of one
    engine's channels: n cycles, total (2, z) and squares (2, z) of [gain - 1, offset Pa]. The recording's
    comparison (``sibling_gains``) and the running watch (core.monitor.calibration.gain_watch) both add cycles here
    and read ``SiblingStats`` from it: one comparison, one statistic."""

    n: int
    total: np.ndarray
    squares: np.ndarray

    @staticmethod
    def empty(n_cyl: int) -> SiblingSums:
        return SiblingSums(0, np.zeros((2, n_cyl)), np.zeros((2, n_cyl)))

    def add(self, row: np.ndarray) -> SiblingSums:
        """With one cycle's (2, z) comparison; a row with a non-finite value is left out (a NaN sample)."""
        if not np.all(np.isfinite(row)):
            return self
        return SiblingSums(self.n + 1, self.total + row, self.squares + row * row)


@dataclass(frozen=True)
class SiblingStats:
    """mean (2, z) [gain - 1, offset Pa] of each channel against its siblings, sem (2, z) its standard error (the
    cycle-to-cycle scatter over sqrt(n); ``NO_SCATTER_SEM`` of gain for a single cycle), spread (2,) the siblings'
    robust spread (1.4826 MAD across the channels) of the mean gain and offset, n cycles."""

    mean: np.ndarray
    sem: np.ndarray
    spread: np.ndarray
    n: int


NO_SCATTER_SEM = np.array([0.01, 0.1e5])  # one cycle has no scatter: a standard error it cannot claim to beat


def cycle_comparison(spec: EngineSpec, cycle: Cycle, lead: np.ndarray) -> np.ndarray:
    """This cycle's (2, z) [gain - 1, offset Pa] against the siblings over COMPRESSION_WINDOW_DEG; lead (z,) rad
    how far each piston is ahead of the angle its pressure is sampled at (sensor_evidence.sibling_compare)."""
    return sibling_compare(spec, cycle.grid, np.asarray(cycle.pressure, dtype=np.float64), COMPRESSION_WINDOW_DEG,
                           np.asarray(lead, dtype=np.float64))


def sibling_stats(sums: SiblingSums) -> SiblingStats | None:
    """The statistics of ``sums`` (None without a cycle)."""
    n = sums.n
    if n == 0:
        return None
    mean = sums.total / n
    if n > 1:
        var = np.maximum(sums.squares - n * mean * mean, 0.0) / (n - 1)
        sem = np.sqrt(var / n)
    else:
        sem = np.broadcast_to(NO_SCATTER_SEM[:, None], mean.shape).copy()
    spread = 1.4826 * np.median(np.abs(mean - np.median(mean, axis=1, keepdims=True)), axis=1)
    return SiblingStats(mean, sem, spread, n)


@dataclass(frozen=True)
class SiblingGains:
    """gain (z,): each channel's reading / truth relative to its siblings' median (1 = as the siblings); gain_sigma
    (z,) its 1-sigma as commissioned (the mean's standard error, the floor, and for a channel not corrected its
    reading); corrected (z,) bool: beyond the siblings' spread (the correction to apply); offset_pa (z,) the
    pegging against the siblings [Pa]; spread: the siblings' robust spread of gain; n_cycles used."""

    gain: np.ndarray
    gain_sigma: np.ndarray
    corrected: np.ndarray
    offset_pa: np.ndarray
    spread: float
    n_cycles: int


def sibling_gains(spec: EngineSpec, cycles: Sequence[Cycle], tdc_correction_rad: np.ndarray) -> SiblingGains | None:
    """The channels' gains against their siblings over ``cycles`` (fired cycles of one engine), the pistons placed
    with the TDC correction found (tdc_correction_rad (z,): + = the piston's TDC later than the flywheel angle
    stated, i.e. the TDC correction less the throw's static twist ahead of the flywheel). None below three
    cylinders (two cannot say which one is off) or without cycles."""
    z = spec.n_cyl
    if z < 3 or not cycles:
        return None
    lead = -np.asarray(tdc_correction_rad, dtype=np.float64)
    sums = SiblingSums.empty(z)
    for c in cycles:
        sums = sums.add(cycle_comparison(spec, c, lead))
    stats = sibling_stats(sums)
    if stats is None:
        return None
    gain_err, sem, spread = stats.mean[0], stats.sem[0], float(stats.spread[0])
    corrected = (np.abs(gain_err) > max(SPREAD_SIGMAS * spread, MIN_GAIN_ERROR)) & (np.abs(gain_err) > 4.0 * sem)
    # what stays unknown: the mean's error and the floor; where not corrected, also the reading and the siblings'
    # spread (a real charge difference and a small gain error look alike)
    base = np.hypot(sem, FLOOR_GAIN)
    sigma = np.where(corrected, np.hypot(base, spread), np.sqrt(base**2 + gain_err**2 + spread**2))
    return SiblingGains(1.0 + gain_err, sigma, corrected, stats.mean[1], spread, stats.n)


__all__ = ["COMPRESSION_WINDOW_DEG", "FLOOR_GAIN", "MIN_GAIN_ERROR", "SPREAD_SIGMAS", "SiblingGains", "SiblingStats",
           "SiblingSums", "cycle_comparison", "sibling_gains", "sibling_stats"]
