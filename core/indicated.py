"""Indicated quantities from a pressure trace (physics.md §2, §6): net indicated work, IMEP, peak pressure.

Net IMEP = (1/V_d) ∮ p dV over the whole 720 deg cycle (pumping loop included).
"""

from __future__ import annotations

import numba
import numpy as np

from core.kinematics import _kinematics


@numba.njit(cache=True)
def _indicated_work(theta, pressure, params, area, out):
    """∮ p dV per row of pressure (z, n) with theta the local angle of each row's cylinder, (z, n)."""
    z, n = pressure.shape
    x = np.empty(n)
    dx = np.empty(n)
    ddx = np.empty(n)
    for k in range(z):
        _kinematics(theta[k], params, x, dx, ddx)
        w = 0.0
        for i in range(n):
            j = i + 1 if i + 1 < n else 0  # closed cycle: the last sample joins the first
            w += 0.5 * (pressure[k, i] + pressure[k, j]) * area * (x[j] - x[i])
        out[k] = w


def net_imep(theta: np.ndarray, pressure: np.ndarray, phases: np.ndarray, params: np.ndarray, area: float,
             displacement: float) -> np.ndarray:
    """Net IMEP [Pa] of each cylinder.

    theta : (n,) uniform cylinder-1 crank angle grid covering one full 4 pi cycle [rad] (endpoint excluded)
    pressure : (z, n) absolute pressure [Pa]; phases : (z,) firing angles [rad]; params : [R, L, e];
    area : piston area [m^2]; displacement : swept volume of one cylinder [m^3].
    """
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    p = np.ascontiguousarray(np.atleast_2d(pressure), dtype=np.float64)
    ph = np.ascontiguousarray(np.atleast_1d(phases), dtype=np.float64)
    if p.shape != (ph.shape[0], th.shape[0]):
        raise ValueError(f"pressure must have shape (z, n) = ({ph.shape[0]}, {th.shape[0]}), got {p.shape}")
    span = th[-1] - th[0] + (th[1] - th[0])
    if not np.isclose(span, 4 * np.pi, rtol=1e-6):
        raise ValueError(f"theta must cover one 720 deg cycle without its endpoint; it spans {np.degrees(span):.3f} deg")
    if not np.all(np.isfinite(p)):
        raise ValueError("pressure has NaN or inf samples; the cycle must be skipped before IMEP")
    local = np.ascontiguousarray(th[None, :] - ph[:, None])
    out = np.empty(ph.shape[0])
    _indicated_work(local, p, np.ascontiguousarray(params, dtype=np.float64), float(area), out)
    return out / displacement


def peak_pressure(theta: np.ndarray, pressure: np.ndarray, phases: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Peak pressure [Pa] per cylinder and its angle [rad] relative to that cylinder's firing TDC, in (-2pi, 2pi].

    The angle is refined by a parabola through the three samples around the maximum.
    """
    p = np.atleast_2d(pressure)
    i = np.argmax(p, axis=1)
    n = p.shape[1]
    rows = np.arange(p.shape[0])
    y0, y1, y2 = p[rows, (i - 1) % n], p[rows, i], p[rows, (i + 1) % n]
    denom = y0 - 2 * y1 + y2
    frac = np.where(denom < 0, 0.5 * (y0 - y2) / np.where(denom < 0, denom, 1.0), 0.0)
    step = theta[1] - theta[0]
    ang = theta[i] + frac * step - np.atleast_1d(phases)
    ang = (ang + 2 * np.pi) % (4 * np.pi) - 2 * np.pi
    return y1 - 0.25 * (y0 - y2) * frac, ang
