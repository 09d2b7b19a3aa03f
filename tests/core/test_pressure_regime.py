"""core.monitor.calibration.pressure_regime: fired or motored from the pressure's asymmetry about TDC, and the pumping
ratio the sensor gain cancels from (made-up cycles with known answers; the real-engine checks are in
tests/realdata/test_tue_tdc.py and tests/service/test_cli*.py and tests/realdata)."""

from __future__ import annotations

import numpy as np
from frictionwatch.core.monitor.calibration.pressure_regime import (
    GRID_DEG,
    PUMPING_GRID_DEG,
    fired_cycles,
    pumping_ratio,
)
from numpy.testing import assert_allclose


def _compression(grid_deg: np.ndarray, burn: float) -> np.ndarray:
    """A symmetric compression peak of 30 bar at TDC plus a burn bump of ``burn`` bar centred 20 deg after it."""
    p = 1e5 + 29e5 * np.exp(-0.5 * (grid_deg / 40.0) ** 2)
    return p + burn * 1e5 * np.exp(-0.5 * ((grid_deg - 50.0) / 30.0) ** 2)


def test_burnt_cycles_are_told_from_motored_ones():
    p = np.stack([_compression(GRID_DEG, b) for b in (0.0, 0.5, 20.0, 40.0)])
    p[0] *= np.where(GRID_DEG > 0, 0.95, 1.0)  # motored: heat and mass lost after TDC
    assert fired_cycles(p).tolist() == [False, False, True, True]


def test_the_pumping_ratio_is_the_exhaust_over_the_intake_stroke_and_the_gain_cancels():
    g = PUMPING_GRID_DEG
    p = np.where((g >= 180.0) | (g <= -360.0), 1.05e5, np.where(g <= -180.0, 0.42e5, 10e5))  # exhaust, intake
    cycles = np.stack([p, p * 1.01])
    assert_allclose(pumping_ratio(cycles), 1.05 / 0.42, rtol=1e-12)
    assert_allclose(pumping_ratio(1.3 * cycles), 1.05 / 0.42, rtol=1e-12)  # a gain error cancels
    assert np.isnan(pumping_ratio(np.zeros((2, g.shape[0]))))  # no positive intake pressure: no ratio
