"""The two small pieces of decision logic the alerts share (service.alerts): the hysteresis latch and the leak
statistics of the pressure indicators against the commissioning baseline. No physics."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from frictionwatch.service.alert_baseline import Band


class Latch:
    """Hysteresis of one statistic: ``step`` returns "raise" after ``k_on`` consecutive cycles with ``on``, "clear"
    after ``k_off`` consecutive cycles with ``off`` while raised, else None; ``since`` is the first cycle of the
    current run of ``on`` cycles (the evidence's start)."""

    __slots__ = ("active", "on_count", "off_count", "since")

    def __init__(self) -> None:
        self.active, self.on_count, self.off_count, self.since = False, 0, 0, -1

    def step(self, on: bool, off: bool, k_on: int, k_off: int, cycle: int) -> str | None:
        if not self.active:
            if on:
                self.since = cycle if self.on_count == 0 else self.since
                self.on_count += 1
                if self.on_count >= k_on:
                    self.active, self.off_count = True, 0
                    return "raise"
            else:
                self.on_count = 0
            return None
        self.off_count = self.off_count + 1 if off else 0
        if self.off_count >= k_off:
            self.active, self.on_count = False, 0
            return "clear"
        return None


@dataclass(frozen=True)
class LeakStatistics:
    """Per cylinder (z,): z_leak the leak signature's EWMA in standard errors (> 0: compression exponent down and
    expansion exponent up from commissioning), effect its size in exponent units (-dn_c + dn_e) / 2, z_ratio the
    compression ratio's EWMA change in standard errors (signed)."""

    z_leak: np.ndarray
    effect: np.ndarray
    z_ratio: np.ndarray


def leak_statistics(ewma: np.ndarray, baseline: Band, g: float) -> LeakStatistics:
    """From the EWMA (4, z) of the indicators' change from the mean of the baseline's load band they were compared
    with (rows as alert_baseline.INDICATORS), its factor g. The leak signature
    s = (-dn_c / sd_c + dn_e / sd_e) / sqrt(2) is scaled by its own per-cycle spread from the band's covariance (the two exponents' scatter is correlated: one trapped-mass error moves
    both) and by the EWMA's standard error per unit of spread, sqrt(g / (2 - g)), for independent cycles."""
    sd = baseline.sd
    w = np.zeros_like(ewma)
    w[1], w[2] = -1.0 / sd[1], 1.0 / sd[2]
    w /= np.sqrt(2.0)
    s = np.sum(w * ewma, axis=0)
    s_sd = np.sqrt(np.maximum(np.einsum("iz,zij,jz->z", w, baseline.cov, w), 1e-30))
    se = np.sqrt(g / (2.0 - g))
    return LeakStatistics(z_leak=s / (s_sd * se), effect=0.5 * (ewma[2] - ewma[1]),
                          z_ratio=ewma[0] / (np.maximum(sd[0], 1e-12) * se))
