"""import-daq's checks of what the user states against what the file's own pressure says (issue 25): the wiring of
the DAQ reader (drivers.daq.raw) with the physics of core.monitor.calibration.pressure_regime.

TDC: the file's TDC-centred cycles go to the ROHR fit, starting from the pressure peak and re-centred on each answer
until it moves by less than ``CONVERGED_DEG``; where a file has motored and fired cycles, the motored estimate is
used and the fired one reported beside it. Self-calibration (p at intake BDC = 1 bar) holds at wide-open throttle
only: above ``THROTTLED_RATIO`` of the pumping ratio the BDC assumption is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.calibration.pressure_regime import (
    GRID_DEG,
    MIN_CYCLES,
    PUMPING_GRID_DEG,
    fired_cycles,
    tdc_estimates,
)
from frictionwatch.core.monitor.calibration.pressure_regime import pumping_ratio as cycles_pumping_ratio
from frictionwatch.core.monitor.calibration.tdc import TdcEstimate
from frictionwatch.drivers.daq.raw import DaqResult, DaqTrace, pressure_peak_deg, process_daq

FIRED_PEAK_AFTER_TDC_DEG = 15.0  # first guess of where a fired peak lies after TDC (refined by the fit)
CONVERGED_DEG = 0.01
MAX_PASSES = 6
WARN_DEG = 0.3  # a stated TDC this far from the data's is a warning
# a stated TDC this far from the data's (and REFUSE_SIGMAS of its sigma) is refused: beyond where the pressure peak
# of any cycle can lie for that TDC (a motored peak lies 0.4-1.3 deg before TDC, a fired one after it)
REFUSE_DEG = 5.0
REFUSE_SIGMAS = 5.0
THROTTLED_RATIO = 1.8  # exhaust / intake mid-stroke pressure above which p(intake BDC) = 1 bar is refused


@dataclass(frozen=True)
class DaqTdc:
    """The file's TDC [deg after tooth 0] from its pressure, with its 1 sigma and the estimate(s) behind it."""

    tdc_deg: float
    sigma_deg: float
    method: str
    estimate: TdcEstimate
    fired_cycles: int
    motored_cycles: int
    other: TdcEstimate | None = None  # the fired estimate where the motored one was used

    def describe(self) -> str:
        text = (f"TDC {self.tdc_deg:.2f} deg +- {self.sigma_deg:.2f} (1 sigma) from the pressure, method "
                f"{self.method}, {self.estimate.n_cycles} cycles ({self.motored_cycles} motored, {self.fired_cycles} "
                "fired)")
        if self.other is not None:
            text += (f"; the fired cycles say {self.tdc_deg - self.estimate.offset_deg + self.other.offset_deg:.2f}"
                     f" +- {self.other.sigma_deg:.2f}")
        return text


def local_cycles(res: DaqResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pressure (m, n) on GRID_DEG about each complete cycle's TDC [Pa], crank speed (m,) [rad/s], fired (m,))."""
    keep = res.complete_cycles()
    if not keep:
        return np.zeros((0, GRID_DEG.shape[0])), np.zeros(0), np.zeros(0, dtype=bool)
    p = np.array([res.cycle_on_grid(k, GRID_DEG) for k in keep])
    ticks = res.tdc_ticks().astype(np.float64)
    tick_hz = res.edges.tick_hz
    period = np.array([(ticks[min(k + 1, ticks.shape[0] - 1)] - ticks[max(k - 1, 0)])
                       / max(min(k + 1, ticks.shape[0] - 1) - max(k - 1, 0), 1) for k in keep]) / tick_hz
    omega = 4.0 * math.pi / period
    return p, omega, fired_cycles(p, GRID_DEG)


def find_tdc(trace: DaqTrace, spec: EngineSpec, wheel: str, start_deg: float | None = None, **calibration
             ) -> tuple[DaqTdc | None, str]:
    """The file's TDC from its pressure, starting at ``start_deg`` (or the pressure peak), and, when it cannot be
    found, None and the reason. ``calibration``: process_daq's gain and pegging options."""
    if start_deg is None:
        peak, n_peaks = pressure_peak_deg(trace, wheel)
        if not n_peaks:
            return None, "no pressure peak in two consecutive verified revolutions"
        guess = peak
    else:
        guess = start_deg
    regime_guessed = start_deg is not None
    for _ in range(MAX_PASSES):
        res = process_daq(trace, spec, wheel=wheel, tdc_deg=guess % 360.0, **calibration)
        p, omega, fired = local_cycles(res)
        if p.shape[0] < MIN_CYCLES:
            return None, f"{p.shape[0]} complete cycles at TDC {guess:.1f} deg (need {MIN_CYCLES})"
        if not regime_guessed:  # from the peak: a fired peak lies after TDC
            regime_guessed = True
            if np.count_nonzero(fired) > fired.shape[0] // 2:
                guess -= FIRED_PEAK_AFTER_TDC_DEG
                continue
        motored, burnt = tdc_estimates(p, omega, fired, spec, GRID_DEG)
        use = motored if motored is not None else burnt
        if use is None:
            return None, (f"the TDC fit failed on {np.count_nonzero(~fired)} motored and {np.count_nonzero(fired)} "
                          "fired cycles")
        guess += use.offset_deg
        if abs(use.offset_deg) < max(CONVERGED_DEG, 0.1 * use.sigma_deg):
            break
    else:
        return None, f"the TDC fit did not settle in {MAX_PASSES} passes (last step {use.offset_deg:+.2f} deg)"
    found = DaqTdc(guess % 360.0, use.sigma_deg, use.method, use, int(np.count_nonzero(fired)),
                   int(np.count_nonzero(~fired)), burnt if use is motored else None)
    return found, ""


def pumping_ratio(res: DaqResult) -> float:
    """The file's pumping ratio (core.monitor.calibration.pressure_regime.pumping_ratio) over its complete cycles."""
    keep = res.complete_cycles()
    if not keep:
        return math.nan
    return cycles_pumping_ratio(np.array([res.cycle_on_grid(k, PUMPING_GRID_DEG) for k in keep]), PUMPING_GRID_DEG)
