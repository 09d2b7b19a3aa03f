"""Each pressure channel's gain and pegging against its siblings over a commissioning recording (issue 25).

Cylinders share the intake manifold, so over the compression stroke (after IVC, before combustion) their traces
differ by each channel's gain and pegging and by what differs in their trapped charge. The per-cycle comparison is
core.monitor.sensor_evidence.sibling_compare (the sensor-health stage's own); here it is averaged over the
recording. What a healthy set of cylinders differs by in charge is not a sensor error, so a channel's gain is
corrected only where it stands out of its siblings' own robust spread (1.4826 MAD across the channels) by
``SPREAD_SIGMAS``; a channel left uncorrected keeps its reading (and that spread) in its sigma. A gain common to
every channel cannot be seen by a sibling comparison: it stays what the caller states (core.model.calibration).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.sensor_evidence import sibling_compare
from frictionwatch.core.types import Cycle

COMPRESSION_WINDOW_DEG = (-100.0, -25.0)  # the sensor-health stage's (core.monitor.sensor_health.SensorHealthConfig)
# a channel is corrected when beyond this many robust spreads of its siblings and MIN_GAIN_ERROR: the sensor-health
# stage's spread_sigmas and its gain threshold (tuned there on bench/sensor_faults.py, not on the cases here)
SPREAD_SIGMAS = 3.0
MIN_GAIN_ERROR = 0.02
FLOOR_GAIN = 0.003  # what a sibling comparison cannot resolve whatever the cycle count (SensorHealthConfig.floor_gain)


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
    with the TDC correction found (tdc_correction_rad (z,): + = true TDC later than stated). None below three
    cylinders (two cannot say which one is off) or without cycles."""
    z = spec.n_cyl
    if z < 3 or not cycles:
        return None
    lead = -np.asarray(tdc_correction_rad, dtype=np.float64)
    rows = np.array([sibling_compare(spec, c.grid, np.asarray(c.pressure, dtype=np.float64), COMPRESSION_WINDOW_DEG,
                                     lead) for c in cycles])  # (n, 2, z)
    rows = rows[np.all(np.isfinite(rows), axis=(1, 2))]
    n = rows.shape[0]
    if n == 0:
        return None
    g, o = rows[:, 0, :], rows[:, 1, :]
    gain_err = g.mean(axis=0)
    sem = g.std(axis=0, ddof=1) / math.sqrt(n) if n > 1 else np.full(z, 0.01)
    spread = 1.4826 * float(np.median(np.abs(gain_err - np.median(gain_err))))
    corrected = (np.abs(gain_err) > max(SPREAD_SIGMAS * spread, MIN_GAIN_ERROR)) & (np.abs(gain_err) > 4.0 * sem)
    # what stays unknown: the mean's error and the floor; where not corrected, also the reading and the siblings'
    # spread (a real charge difference and a small gain error look alike)
    base = np.hypot(sem, FLOOR_GAIN)
    sigma = np.where(corrected, np.hypot(base, spread), np.sqrt(base**2 + gain_err**2 + spread**2))
    return SiblingGains(1.0 + gain_err, sigma, corrected, o.mean(axis=0), spread, n)


__all__ = ["SiblingGains", "sibling_gains"]
