"""The measurement side of the scipy baseline (bench/scipy_baseline.py): one assembled cycle -> the flywheel speed on
its crank-angle grid, from the monitor's own tooth fit, and how in-band tooth-spacing errors would move it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.identify.parameters import tooth_patterns
from frictionwatch.core.monitor.teeth.flywheel import fit_flywheel, harmonic_series
from frictionwatch.core.types import Cycle

FOUR_PI = 4.0 * np.pi


@dataclass(frozen=True)
class MeasuredCycle:
    """What the baseline takes from one assembled cycle: mean speed, the flywheel speed on the crank-angle grid
    (band-limited to ``n_harmonics``, drift removed), pressure and load, and how an in-band tooth-spacing error
    moves the measured speed harmonics (``tooth_columns`` (M, 2 n_orders) complex, per rad of each cos/sin pattern,
    core.monitor.identify.parameters.tooth_patterns: fixed in angle, such errors look like engine response at integer orders)."""

    omega: float  # rad/s
    period: float  # s
    theta_start: float  # flywheel angle of the first edge [rad]
    grid: np.ndarray  # (n,) rad
    speed: np.ndarray  # (n,) rad/s
    pressure: np.ndarray  # (z, n) Pa
    load_torque: float  # N m
    n_harmonics: int
    edge_noise: float  # rms angle residual of the tooth fit [rad]
    n_edges: int
    tooth_columns: np.ndarray


def measure(spec: EngineSpec, cycle: Cycle, n_harmonics: int, correction: np.ndarray | None = None,
            tooth_orders: int | None = None) -> MeasuredCycle:
    """Flywheel speed of one cycle from its tooth edges (core.monitor.teeth.flywheel.fit_flywheel with the drift fitted apart).

    correction : (wheel_teeth,) learned tooth-angle corrections [rad] (e.g. the monitor's), or None
    tooth_orders : integer orders of the in-band tooth-error patterns (default n_harmonics // 2, as the monitor)"""
    nominal = np.asarray(cycle.tooth_angle, dtype=np.float64)
    end = int(np.searchsorted(nominal, nominal[0] + FOUR_PI - 1e-6))
    if end >= nominal.shape[0]:
        raise ValueError("the cycle has no tooth edge 720 deg after its first one")
    pos = np.asarray(cycle.tooth_index[: end + 1]) % spec.sensors.wheel_teeth
    ang = nominal[: end + 1] + (0.0 if correction is None else np.asarray(correction)[pos])
    orders = n_harmonics // 2 if tooth_orders is None else tooth_orders
    patterns = tooth_patterns(nominal[: end + 1], orders) if orders else None
    fly = fit_flywheel(cycle.tooth_ticks[: end + 1], cycle.tick_hz, ang, n_harmonics, patterns, drift=True)
    n_t = max(512, 4 * n_harmonics)
    tau = np.arange(n_t) * (fly.period / n_t)
    theta = ang[0] + fly.omega_mean * tau + harmonic_series(fly.harmonics, n_t, fly.offset)
    omega = harmonic_series(fly.speed_harmonics, n_t, fly.omega_mean)
    cols = harmonic_series(1j * fly.freq * fly.pattern_harmonics.T, n_t)  # (q, n_t) speed per unit pattern
    cols = np.array([angle_harmonics(on_angle_grid(cycle.grid, theta, c), n_harmonics) for c in cols]).T
    load = cycle.load_torque if np.isfinite(cycle.load_torque) else cycle.load_power / fly.omega_mean
    return MeasuredCycle(fly.omega_mean, fly.period, float(ang[0]), np.asarray(cycle.grid, dtype=np.float64),
                         on_angle_grid(cycle.grid, theta, omega), np.asarray(cycle.pressure, dtype=np.float64),
                         float(load), n_harmonics, fly.residual_rms, fly.n_edges,
                         cols.reshape(n_harmonics, -1))


def on_angle_grid(grid: np.ndarray, theta: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Values sampled at increasing angles ``theta`` spanning one cycle, onto the 4 pi-periodic ``grid``."""
    x = np.append(theta, theta[0] + FOUR_PI)
    u = theta[0] + np.mod(grid - theta[0], FOUR_PI)
    return np.interp(u, x, np.append(values, values[0]))


def angle_harmonics(x: np.ndarray, n_harmonics: int) -> np.ndarray:
    """Harmonics 1..M (order m/2) of a signal on the uniform crank-angle grid (core.model.dynamics convention)."""
    return np.fft.rfft(x)[1 : n_harmonics + 1] * (2.0 / x.shape[0])
