"""Change detection on the friction estimates: a two-sided CUSUM per cylinder on the innovation between this cycle's
own estimate and the smoothed one (issue 16: a change mid-run must be flagged and followed, not averaged).

The innovation u_k = T_cycle,k - T_smoothed,k [N m] is cylinder k's friction from this cycle's equations (plus the
priors) minus the accumulated estimate, both at this cycle's operating point (the rows turn the parameters into
torques, so a load or speed change that the model explains moves both alike). It is standardised by its own running
mean and spread (EWMA, ``memory``): the posterior sigmas of a single cycle are not its scatter (the noise model and
the share prior make them so), so the detector learns what a healthy innovation looks like, then accumulates

    S+ = max(0, S+ + z - k),   S- = max(0, S- - z - k),   alarm when S+ or S- > h

with z clipped to +-``clip`` (one odd cycle, a misfire, moves a sum by at most clip - k). An alarm names the cylinder
with the largest sum; then the sums restart after ``quiet`` cycles, and the caller discounts the accumulated
equations (Accumulator.discounted) to ``reset_weight`` cycles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from frictionwatch.core.monitor.identify.accumulate import Posterior


@dataclass(frozen=True)
class ChangeSettings:
    """k, h: CUSUM reference value and decision threshold (in innovation sigmas); memory: EWMA factor of the
    innovation's mean and variance (its mean absorbs slow drifts, such as the estimate still converging: a step is
    what is detected); warmup: innovations before the first decision; clip: |z| limit; reset_weight: effective
    cycles the accumulated equations keep after a detected change; quiet: cycles after an alarm without a decision
    (the discounted estimate settles on the new state, and every cylinder's innovation moves while it does)."""

    k: float = 0.5
    h: float = 10.0
    memory: float = 1.0 - 1.0 / 200.0
    warmup: int = 100
    clip: float = 4.0
    reset_weight: float = 30.0
    quiet: int = 60


@dataclass(frozen=True)
class ChangeDetector:
    """Running mean and variance of each cylinder's innovation (z,), the CUSUM sums (2, z), innovations seen, and
    the cycles left without a decision after an alarm."""

    mean: np.ndarray
    var: np.ndarray
    sums: np.ndarray
    count: int
    quiet: int = 0

    @staticmethod
    def empty(n: int) -> ChangeDetector:
        return ChangeDetector(np.zeros(n), np.zeros(n), np.zeros((2, n)), 0)


def cylinder_friction(post: Posterior, rows: np.ndarray) -> np.ndarray:
    """(z,) per-cylinder friction torques rows (z, p_f) @ the leading p_f parameters [N m]."""
    return rows @ post.params[:rows.shape[1]]


def detect_change(detector: ChangeDetector | None, cycle: Posterior, smoothed: Posterior, rows: np.ndarray,
                  settings: ChangeSettings) -> tuple[ChangeDetector, np.ndarray]:
    """One cycle of the detector: the new detector and the alarm per cylinder (z,) bool."""
    u = cylinder_friction(cycle, rows) - cylinder_friction(smoothed, rows)
    z_cyl = u.shape[0]
    det = ChangeDetector.empty(z_cyl) if detector is None else detector
    none = np.zeros(z_cyl, dtype=bool)
    if not np.all(np.isfinite(u)):
        return det, none
    n = det.count + 1
    g = max(1.0 - settings.memory, 1.0 / n)
    sd = np.sqrt(det.var)
    ready = det.count >= settings.warmup and np.all(sd > 0)
    zs = np.clip((u - det.mean) / np.where(sd > 0, sd, 1.0), -settings.clip, settings.clip) if ready else None
    # the statistics learn from the clipped innovation, so one wild cycle does not inflate the scale
    d = (zs * sd if zs is not None else u - det.mean)
    mean = det.mean + g * d
    var = (1.0 - g) * (det.var + g * d * d) if n > 1 else np.zeros(z_cyl)
    if zs is None or det.quiet > 0:
        return ChangeDetector(mean, var, det.sums, n, max(det.quiet - 1, 0)), none
    sums = np.stack([np.maximum(0.0, det.sums[0] + zs - settings.k), np.maximum(0.0, det.sums[1] - zs - settings.k)])
    over = sums.max(axis=0)
    if not np.any(over > settings.h):
        return ChangeDetector(mean, var, sums, n), none
    alarm = over == over.max()  # the cylinder that changed most; the others' sums move with the shared estimate
    return ChangeDetector(mean, var, np.zeros((2, z_cyl)), n, settings.quiet), alarm
