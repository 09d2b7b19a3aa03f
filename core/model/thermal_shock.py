"""Thermal shock of a piezoelectric pressure transducer: the reading's error over a cycle (sensor side only).

The flame heats the sensor's diaphragm during combustion; its front face expands and the sensor reads low while the
heat soaks in, then recovers over the exhaust stroke as it cools (Rosseel & Sierens, SAE 960236; Lee et al.,
Meas. Sci. Technol. 2013; the AVL and Kistler application notes on thermal shock). Modelled as the diaphragm's
first-order thermal response (time constant ``tau`` [s]) to the heat flux from the burning gas, a pulse that starts
at the start of combustion and peaks ``HEAT_FLUX_PEAK_DEG`` after it (x e^(1 - x), x = angle after SOC / that
width: the flux's rise with the flame and its fall as the gas expands and cools). In the cycle's periodic steady
state the response peaks some 30-70 deg after TDC (later for a slower sensor) and has died away by the next
intake; it is scaled to a peak of 1 and read as

    error [Pa] = - peak_full_load x (idle + (1 - idle) x load) x shape(local angle)

(load 0..1: the heat flux grows with the fuel burnt; ``idle``: the size at no load as a fraction of full load's).
The sensor reads p + error (before its gain and pegging): the plant's pressure is unchanged.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

HEAT_FLUX_PEAK_DEG = 20.0  # the flux peaks ~20 deg after the start of combustion (the gas's peak temperature)
SHAPE_STEP_DEG = 0.25  # the shape's table over one 720-deg cycle


def shock_shape(soc_deg: float, tau_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(local angle grid [rad] over [0, 4 pi], shape there, peak 1) of a sensor of time constant ``tau_deg`` [deg of
    crank angle at the run's speed] whose cylinder starts to burn at ``soc_deg`` (0 = firing TDC). The lag's
    periodic steady state: the recurrence e_(i+1) = a e_i + (1 - a) q_i (a = exp(-step / tau), the flux held over a
    step) run over two cycles from 0, the second kept (the first's start is forgotten to exp(-720 / tau))."""
    n = int(round(720.0 / SHAPE_STEP_DEG))
    deg = np.arange(n + 1) * SHAPE_STEP_DEG
    x = np.mod(deg - soc_deg, 720.0) / HEAT_FLUX_PEAK_DEG
    q = x * np.exp(1.0 - x)
    a = float(np.exp(-SHAPE_STEP_DEG / max(tau_deg, 1e-9)))
    # out[i] = e_i: the recurrence as a filter y_i = a y_(i-1) + (1 - a) q_(i-1), its state the e carried in (the
    # monitor's view sizes a shape once a cycle: the plain loop's numbers to the bit, ~18x faster at load 5)
    b, den = np.array([0.0, 1.0 - a]), np.array([1.0, -a])
    first = lfilter(b, den, q, zi=np.zeros(1))[0]
    out = lfilter(b, den, q, zi=np.array([a * first[-1] + (1.0 - a) * q[-1]]))[0]  # periodic: from where it ended
    return np.radians(deg), out / out.max()


def shock_error(local_angle: np.ndarray, shapes: list[tuple[np.ndarray, np.ndarray]],
                size_pa: np.ndarray) -> np.ndarray:
    """The error [Pa] (m, z), <= 0, of readings at ``local_angle`` (m, z) rad (each cylinder's angle from its firing
    TDC, unwrapped), cylinder k's ``shapes[k]`` (``shock_shape``) scaled to ``size_pa[k]`` (its peak at this load)."""
    out = np.zeros(local_angle.shape)
    four_pi = 4.0 * np.pi
    for k, (grid, shape) in enumerate(shapes):
        if size_pa[k] != 0.0:
            out[:, k] = -size_pa[k] * np.interp(np.mod(local_angle[:, k], four_pi), grid, shape)
    return out


def cycle_error(grid: np.ndarray, firing_angles: np.ndarray, omega: float, soc_deg: float, size_pa: np.ndarray,
                tau_s: np.ndarray) -> np.ndarray:
    """(z, n) the error [Pa] (<= 0) of each cylinder's reading on a cycle's ``grid`` (n,) rad (cylinder 1's angle,
    [0, 4 pi)) at mean speed ``omega`` [rad/s]: cylinder k's sensor, of time constant ``tau_s[k]``, sized
    ``size_pa[k]`` (0: none), its flame starting ``soc_deg`` from its firing TDC ``firing_angles[k]``. The
    monitor's side of the plant's error (``shock_shape`` once per time constant at this cycle's speed, as the plant
    takes it at its run's speed): what a model with a thermal_shock effect adds back to the pressure it reads."""
    tau_deg = np.degrees(np.asarray(tau_s, dtype=np.float64) * omega).tolist()
    shapes = {t: shock_shape(soc_deg, t) for t in set(tau_deg)}  # cylinders of one sensor type share a shape
    local = grid[:, None] - np.asarray(firing_angles)[None, :]
    return shock_error(local, [shapes[t] for t in tau_deg], size_pa).T


def load_scale(load: float, idle: np.ndarray) -> np.ndarray:
    """(z,) the error's size at ``load`` (0..1; None-like NaN: motored, no flame) as a fraction of full load's."""
    if not np.isfinite(load):
        return np.zeros_like(idle)
    return idle + (1.0 - idle) * float(np.clip(load, 0.0, 1.0))


__all__ = ["HEAT_FLUX_PEAK_DEG", "cycle_error", "load_scale", "shock_error", "shock_shape"]
