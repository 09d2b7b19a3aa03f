"""Indicated quantities from a pressure trace (physics.md §2, §6): net indicated work, IMEP, peak pressure.

Net IMEP = (1/V_d) ∮ p dV over the whole 720 deg cycle (pumping loop included).
"""

from __future__ import annotations

import numba
import numpy as np
from frictionwatch.core.model.kinematics import kinematics_kernel


@numba.njit(cache=True)
def _indicated_work(theta, pressure, params, area, out):
    """∮ p dV per row of pressure (z, n) with theta the local angle of each row's cylinder, (z, n)."""
    z, n = pressure.shape
    x = np.empty(n)
    dx = np.empty(n)
    ddx = np.empty(n)
    for k in range(z):
        kinematics_kernel(theta[k], params, x, dx, ddx)
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


@numba.njit(cache=True)
def _peak_pressure(theta, pressure, phases, pmax, angle):
    """Per row of pressure (z, n): the first maximum sample, refined by the parabola through it and its two
    periodic neighbours; writes the refined peak and its angle relative to phases[k], wrapped to [-2pi, 2pi).
    The arithmetic is that of the numpy reference (tests/core/test_peak_pressure_kernel.py)."""
    z, n = pressure.shape
    step = theta[1] - theta[0]
    for k in range(z):
        i = 0
        best = pressure[k, 0]
        if best == best:
            for j in range(1, n):  # np.argmax: the first maximum, or the first NaN
                v = pressure[k, j]
                if v > best:
                    best = v
                    i = j
                elif v != v:
                    i = j
                    break
        y0 = pressure[k, (i - 1) % n]
        y1 = pressure[k, i]
        y2 = pressure[k, (i + 1) % n]
        denom = y0 - 2 * y1 + y2
        frac = 0.5 * (y0 - y2) / denom if denom < 0 else 0.0
        ang = theta[i] + frac * step - phases[k]
        angle[k] = (ang + 2 * np.pi) % (4 * np.pi) - 2 * np.pi
        pmax[k] = y1 - 0.25 * (y0 - y2) * frac


@numba.njit(cache=True, fastmath={"reassoc"})
def _all_finite(flat):
    """Whether every sample is finite: x * 0 is 0 for a finite x and NaN for NaN or inf, so the sum is NaN iff one
    is not (reassociation only lets the sum vectorise; it cannot turn a NaN into a number)."""
    acc = 0.0
    for i in range(flat.shape[0]):
        acc += flat[i] * 0.0
    return acc == 0.0


@numba.njit(cache=True)
def _peak_pressure_finite(theta, pressure, phases, pmax, angle):
    """``_peak_pressure`` and the number of non-finite samples of pressure (z, n) (C-contiguous). The count is made
    only when ``_all_finite`` (a vectorised test) says there is something to count."""
    flat = pressure.ravel()
    bad = 0
    if not _all_finite(flat):
        for i in range(flat.shape[0]):
            if not np.isfinite(flat[i]):
                bad += 1
    _peak_pressure(theta, pressure, phases, pmax, angle)
    return bad


def peak_pressure(theta: np.ndarray, pressure: np.ndarray, phases: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Peak pressure [Pa] per cylinder and its angle [rad] relative to that cylinder's firing TDC, in [-2pi, 2pi).

    The angle is refined by a parabola through the three samples around the maximum.
    theta : (n,) uniform crank-angle grid [rad]; pressure : (z, n) [Pa] (a row with a NaN gives NaN, as with
    np.argmax); phases : (z,) firing angles [rad] (or one for every row).
    """
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    p = np.ascontiguousarray(np.atleast_2d(pressure), dtype=np.float64)
    ph = np.ascontiguousarray(phases, dtype=np.float64).ravel()
    if ph.shape[0] == 1 and p.shape[0] > 1:
        ph = np.full(p.shape[0], ph[0])
    if p.shape[1] != th.shape[0] or th.shape[0] < 2 or ph.shape[0] != p.shape[0]:
        raise ValueError(f"pressure (z, n) needs n = {th.shape[0]} grid angles and z phases, got {p.shape} and "
                         f"{ph.shape[0]} phases")
    pmax = np.empty(p.shape[0])
    angle = np.empty(p.shape[0])
    _peak_pressure(th, p, ph, pmax, angle)
    return pmax, angle
