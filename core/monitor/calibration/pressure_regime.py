"""What a file's own pressure says about its cycles before any model runs: which cycles burnt, whether the engine was
throttled, and its TDC from cycles put on a local grid about the stated TDC (import-daq's checks, issue 25; the
wiring with the DAQ reader is service/daq_tdc.py).

Fired or motored: by the asymmetry of the pressure about TDC (``FIRED_ASYMMETRY``). TDC: the motored cycles'
estimate where a file has some (it does not depend on where combustion ends; on the TU/e engine it moves by 0.15 deg
for a 1.7x change of the wall heat against about 0.4 deg for the fired one), the fired one beside it.

Throttled: a throttled engine draws its charge well below the exhaust pressure, which stays near 1 bar whatever the
throttle; the mean pressure over the middle of the exhaust stroke against that over the middle of the intake stroke,
both pegged by the same zero, is a ratio the gain cancels from (``pumping_ratio``).
"""

from __future__ import annotations

import math

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.calibration.tdc import TdcEstimate, tdc_from_pressure

GRID_DEG = np.arange(-180.0, 180.0, 0.5)  # the local grid the cycles are put on for the fit [deg from TDC]
# mean p(+60..+100 deg) / p(-100..-60 deg) above which a cycle burnt (motored: below 1, heat and mass lost); wide
# of TDC so that a first guess 25 deg off (a fired peak) still tells the two apart
FIRED_ASYMMETRY = 1.15
MIN_CYCLES = 3
PUMPING_GRID_DEG = np.arange(-360.0, 360.0, 1.0)  # the whole cycle about firing TDC, for pumping_ratio


def fired_cycles(p: np.ndarray, grid_deg: np.ndarray = GRID_DEG) -> np.ndarray:
    """(m,) bool: which of the cycles ``p`` (m, n) [Pa] on ``grid_deg`` (n,) [deg from TDC] burnt."""
    after = (grid_deg >= 60.0) & (grid_deg <= 100.0)
    before = (grid_deg >= -100.0) & (grid_deg <= -60.0)
    return p[:, after].mean(axis=1) > FIRED_ASYMMETRY * p[:, before].mean(axis=1)


def tdc_estimates(p: np.ndarray, omega: np.ndarray, fired: np.ndarray, spec: EngineSpec,
                  grid_deg: np.ndarray = GRID_DEG) -> tuple[TdcEstimate | None, TdcEstimate | None]:
    """(motored, fired) TDC estimates from the local cycles ``p`` (m, n) [Pa] on ``grid_deg`` at crank speeds
    ``omega`` (m,) [rad/s]; None where fewer than MIN_CYCLES of that regime or the fit fails."""

    def one(sel: np.ndarray, motored: bool) -> TdcEstimate | None:
        if np.count_nonzero(sel) < MIN_CYCLES:
            return None
        try:
            return tdc_from_pressure(p[sel], np.radians(grid_deg), spec, float(np.mean(omega[sel])), motored)
        except ValueError:
            return None

    return one(~fired, True), one(fired, False)


def pumping_ratio(p: np.ndarray, grid_deg: np.ndarray = PUMPING_GRID_DEG) -> float:
    """Median over cycles ``p`` (m, n) [Pa] on ``grid_deg`` (n,) [deg from firing TDC, -360..360] of the mean
    pressure over the exhaust stroke's middle (220..320 deg) over that of the intake stroke's (-320..-220 deg): ~1 at
    wide-open throttle, the manifold depression's inverse when throttled; the gain cancels."""
    exhaust = (grid_deg >= 220.0) & (grid_deg <= 320.0)
    intake = (grid_deg >= -320.0) & (grid_deg <= -220.0)
    low = p[:, intake].mean(axis=1)
    ok = low > 0
    return float(np.median(p[ok][:, exhaust].mean(axis=1) / low[ok])) if np.any(ok) else math.nan


__all__ = ["FIRED_ASYMMETRY", "GRID_DEG", "MIN_CYCLES", "PUMPING_GRID_DEG", "fired_cycles", "pumping_ratio",
           "tdc_estimates"]
