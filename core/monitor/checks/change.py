"""Change detection on the friction estimates: a two-sided CUSUM per cylinder on the innovation between this cycle's
own estimate and the smoothed one (issue 16: a change mid-run must be flagged and followed, not averaged).

The innovation u_k = T_cycle,k - T_smoothed,k [N m] is cylinder k's friction from this cycle's equations (plus the
priors) minus the accumulated estimate, both at this cycle's operating point (the rows turn the parameters into
torques, so a load or speed change that the model explains moves both alike). It is standardised by its own running
mean and spread (EWMA, ``memory``): the posterior sigmas of a single cycle are not its scatter (the noise model and
the share prior make them so), so the detector learns what a healthy innovation looks like, then accumulates

    S+ = max(0, S+ + z - k),   S- = max(0, S- - z - k),   alarm when S+ or S- > h

with z clipped to +-``clip`` (one odd cycle, a misfire, moves a sum by at most clip - k) and the scale at least
``rel_floor`` x the smoothed figure (ChangeSettings). The running mean follows the smoothed estimate's own motion
(``follow_smoothed``): each cycle it moves by minus rows @ (p_t - p_t-1), the smoothed parameters' change at this
cycle's rows, so the reference's drift while it learns (a trend the EWMA lags, not a change of the engine) does not
reach the sums (design notes 76, 151). An alarm names the cylinder
with the largest sum; then the sums restart after ``quiet`` cycles, and the caller discounts the accumulated
equations (Accumulator.discounted) to ``reset_weight`` cycles.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np
from frictionwatch.core.monitor.identify.posterior import Posterior
from frictionwatch.core.tuned import MONITOR_RECORD, read_tuned

_TUNED = read_tuned(MONITOR_RECORD)  # the innovation's floor with its provenance (core.tuned)


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
    # the innovation's scale is at least rel_floor x the smoothed figure (each cylinder's): the smoothed per-cylinder
    # estimate itself moves by a few % while it learns (genset-v20: a slow wander the 200-cycle mean does not
    # absorb, 50-cycle block means ~2x an independent cycle's), and with the transient balance's per-cycle scatter
    # down 3x (design note 69) that wander raised ~10 false alarms in 1,000 healthy cycles, each discounting the
    # accumulator to 30 cycles. Tuned on genset-v20 1500 rpm 1.0 seed 3 (bench.calibrate_change_floor); validated
    # on seed 1 (tests/core/test_monitor_accuracy.py) and on maruti/k9k (tests/core/test_condition.py)
    rel_floor: float = _TUNED["CHANGE_INNOVATION_REL_FLOOR"].value


@dataclass(frozen=True)
class ChangeDetector:
    """Running mean and variance of each cylinder's innovation (z,), the CUSUM sums (2, z), innovations seen, the
    cycles left without a decision after an alarm, and the smoothed friction parameters (p_f,) the mean last
    followed (None before the first cycle)."""

    mean: np.ndarray
    var: np.ndarray
    sums: np.ndarray
    count: int
    quiet: int = 0
    followed: np.ndarray | None = None

    @staticmethod
    def empty(n: int) -> ChangeDetector:
        return ChangeDetector(np.zeros(n), np.zeros(n), np.zeros((2, n)), 0)


def cylinder_friction(post: Posterior, rows: np.ndarray) -> np.ndarray:
    """(z,) per-cylinder friction torques rows (z, p_f) @ the leading p_f parameters [N m]."""
    return rows @ post.params[:rows.shape[1]]


def follow_smoothed(detector: ChangeDetector | None, smoothed_params: np.ndarray, rows: np.ndarray) -> ChangeDetector:
    """The detector (an empty one for None) with its running mean moved by minus the smoothed estimate's motion
    since the cycle before, rows (z, p_f) @ (p_t - p_t-1) [N m] at this cycle's rows (an operating-point change the
    model explains moves both alike and does not enter), and p_t kept for the next cycle.

    Why (design note 151): the innovation u = T_cycle - T_smoothed moves with the smoothed estimate while it learns
    -- on genset-v20, whose per-cylinder figures are shares (sigma ~51 N m of ~88), the looped demo's u drifted by
    ~-4 N m in 350 cycles on one cylinder against a scatter of ~2 N m -- and the EWMA mean lags a trend: the served
    demo raised a ``condition_change`` every 350-460 cycles on a healthy engine, each discounting the estimate to 30
    cycles. That drift is known exactly each cycle; taking it out leaves the cycle estimate's own deviations."""
    pf = rows.shape[1]
    now = np.array(smoothed_params[:pf], dtype=np.float64)
    det = ChangeDetector.empty(rows.shape[0]) if detector is None else detector
    if det.followed is None or det.followed.shape != now.shape:
        return replace(det, followed=now)
    return replace(det, mean=det.mean - rows @ (now - det.followed), followed=now)


def detect_change(detector: ChangeDetector | None, cycle: Posterior, smoothed: Posterior, rows: np.ndarray,
                  settings: ChangeSettings) -> tuple[ChangeDetector, np.ndarray]:
    """One cycle of the detector: the new detector and the alarm per cylinder (z,) bool. ``detect_change_reference``'s
    numbers by one kernel (``cusum_kernel``) after the two torques: its ~20 small numpy calls were ~1.5 % of a k9k
    cycle (tests/core/test_change_kernel.py: equal within rtol 1e-12 over warm-up, alarms and quiet cycles)."""
    smooth = cylinder_friction(smoothed, rows)
    u = cylinder_friction(cycle, rows) - smooth
    z_cyl = u.shape[0]
    det = follow_smoothed(detector, smoothed.params, rows)
    mean, var, sums, alarm = np.empty(z_cyl), np.empty(z_cyl), np.empty((2, z_cyl)), np.zeros(z_cyl, dtype=np.bool_)
    status = cusum_kernel(np.ascontiguousarray(u, dtype=np.float64), det.mean, det.var, det.sums, det.count,
                           det.quiet, cusum_limits(settings),
                           np.ascontiguousarray(settings.rel_floor * np.abs(smooth), dtype=np.float64),
                           mean, var, sums, alarm)
    return detector_after(det, status, mean, var, sums, settings), alarm


def detector_after(det: ChangeDetector, status: int, mean: np.ndarray, var: np.ndarray, sums: np.ndarray,
                   settings: ChangeSettings) -> ChangeDetector:
    """The detector after ``cusum_kernel``'s step from ``det`` with its status and the arrays it filled."""
    if status == _NOT_FINITE:
        return det
    n = det.count + 1
    if status == _LEARNING:
        return replace(det, mean=mean, var=var, count=n, quiet=max(det.quiet - 1, 0))
    if status == _NO_ALARM:
        return replace(det, mean=mean, var=var, sums=sums, count=n, quiet=0)
    return replace(det, mean=mean, var=var, sums=np.zeros((2, mean.shape[0])), count=n, quiet=settings.quiet)


_NOT_FINITE, _LEARNING, _NO_ALARM, _ALARM = 0, 1, 2, 3  # cusum_kernel's status


def cusum_limits(settings: ChangeSettings) -> np.ndarray:
    """(k, h, memory, warmup, clip): ``cusum_kernel``'s limits."""
    return np.array((settings.k, settings.h, settings.memory, settings.warmup, settings.clip))


@numba.njit(cache=True)
def cusum_kernel(u, mean, var, sums, count, quiet, limits, floor, new_mean, new_var, new_sums, alarm):
    """``detect_change_reference``'s step after the innovation u (z,), element by element in its arithmetic:
    fills new_mean, new_var (and new_sums, alarm where decided) and returns the status: _NOT_FINITE (u not finite,
    nothing filled), _LEARNING (warm-up or quiet: the sums unchanged), _NO_ALARM, _ALARM (alarm marks the cylinder
    with the largest sum). limits = (k, h, memory, warmup, clip); floor (z,) the least scale of each innovation."""
    z = u.shape[0]
    for i in range(z):
        if not np.isfinite(u[i]):
            return _NOT_FINITE
    n = count + 1
    g = max(1.0 - limits[2], 1.0 / n)
    ready = count >= limits[3]
    for i in range(z):
        ready = ready and np.sqrt(var[i]) > 0
    zs = np.empty(z)
    for i in range(z):
        sd = np.sqrt(var[i])
        if ready:
            zs[i] = min(max((u[i] - mean[i]) / max(sd, floor[i]), -limits[4]), limits[4])
            d = min(max(u[i] - mean[i], -limits[4] * sd), limits[4] * sd)
        else:
            d = u[i] - mean[i]
        new_mean[i] = mean[i] + g * d
        new_var[i] = (1.0 - g) * (var[i] + g * d * d) if n > 1 else 0.0
    if not ready or quiet > 0:
        return _LEARNING
    top = -np.inf
    for i in range(z):
        new_sums[0, i] = max(0.0, sums[0, i] + zs[i] - limits[0])
        new_sums[1, i] = max(0.0, sums[1, i] - zs[i] - limits[0])
        top = max(top, max(new_sums[0, i], new_sums[1, i]))
    if not top > limits[1]:
        return _NO_ALARM
    for i in range(z):
        alarm[i] = max(new_sums[0, i], new_sums[1, i]) == top
    return _ALARM


def detect_change_reference(detector: ChangeDetector | None, cycle: Posterior, smoothed: Posterior, rows: np.ndarray,
                            settings: ChangeSettings) -> tuple[ChangeDetector, np.ndarray]:
    """``detect_change`` in plain numpy (its reference)."""
    smooth = cylinder_friction(smoothed, rows)
    return cusum_step_reference(follow_smoothed(detector, smoothed.params, rows), cylinder_friction(cycle, rows) - smooth,
                                smooth, settings)


def cusum_step_reference(detector: ChangeDetector | None, u: np.ndarray, smooth: np.ndarray,
                         settings: ChangeSettings) -> tuple[ChangeDetector, np.ndarray]:
    """One step of the detector on the innovation u (z,) [N m] beside the smoothed figures smooth (z,) [N m]
    (``detect_change_reference`` after its two torques; bench.calibrate_change_floor replays recorded ones)."""
    z_cyl = u.shape[0]
    det = ChangeDetector.empty(z_cyl) if detector is None else detector
    none = np.zeros(z_cyl, dtype=bool)
    if not np.all(np.isfinite(u)):
        return det, none
    n = det.count + 1
    g = max(1.0 - settings.memory, 1.0 / n)
    sd = np.sqrt(det.var)
    ready = det.count >= settings.warmup and np.all(sd > 0)
    scale = np.maximum(np.where(sd > 0, sd, 1.0), settings.rel_floor * np.abs(smooth))
    zs = np.clip((u - det.mean) / scale, -settings.clip, settings.clip) if ready else None
    # the statistics learn from the innovation clipped at clip x its own spread, so one wild cycle does not inflate
    # the scale (the floor only widens the scale the sums see)
    d = (np.clip(u - det.mean, -settings.clip * sd, settings.clip * sd) if zs is not None else u - det.mean)
    mean = det.mean + g * d
    var = (1.0 - g) * (det.var + g * d * d) if n > 1 else np.zeros(z_cyl)
    if zs is None or det.quiet > 0:
        return replace(det, mean=mean, var=var, count=n, quiet=max(det.quiet - 1, 0)), none
    sums = np.stack([np.maximum(0.0, det.sums[0] + zs - settings.k), np.maximum(0.0, det.sums[1] - zs - settings.k)])
    over = sums.max(axis=0)
    if not np.any(over > settings.h):
        return replace(det, mean=mean, var=var, sums=sums, count=n, quiet=0), none
    alarm = over == over.max()  # the cylinder that changed most; the others' sums move with the shared estimate
    return replace(det, mean=mean, var=var, sums=np.zeros((2, z_cyl)), count=n, quiet=settings.quiet), alarm
