"""Slider-crank kinematics (physics.md §1) and the variable inertia J(theta) (physics.md §3).

theta is the crank angle of the throw measured from crank-top (= TDC when the pin offset is zero), radians.
With a pin offset e: sin(beta) = (R sin(theta) - e)/L, and x is measured from the true top position.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def kinematics_kernel(theta, params, x, dx, ddx):
    """Fill x [m], dx/dtheta [m/rad], d2x/dtheta2 [m/rad^2] (n,) at crank angles theta (n,) [rad]; params = [R, L, e]
    (the kernel of ``kinematics``, also called inside other kernels)."""
    r = params[0]
    rod = params[1]
    e = params[2]
    s_top = np.sqrt((r + rod) ** 2 - e * e)
    for i in range(theta.shape[0]):
        st = np.sin(theta[i])
        ct = np.cos(theta[i])
        sb = (r * st - e) / rod
        cb = np.sqrt(1.0 - sb * sb)
        tb = sb / cb
        x[i] = s_top - (r * ct + rod * cb)
        dx[i] = r * st + r * ct * tb
        ddx[i] = r * ct - r * st * tb + r * r * ct * ct / (rod * cb * cb * cb)


def kinematics(theta: np.ndarray, params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Piston displacement from top x [m], dx/dtheta [m/rad] and d2x/dtheta2 [m/rad^2].

    Parameters
    ----------
    theta : (n,) crank angle of the throw [rad]
    params : [R, L, pin_offset] in m (``EngineSpec.kinematics_params()``)
    """
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    p = np.ascontiguousarray(params, dtype=np.float64)
    if p.shape != (3,) or not p[1] > 1.5 * p[0] > 0:
        raise ValueError("params must be [R, L, pin_offset] with L > 1.5 R > 0")
    x, dx, ddx = np.empty_like(th), np.empty_like(th), np.empty_like(th)
    kinematics_kernel(th, p, x, dx, ddx)
    return x, dx, ddx


@numba.njit(cache=True)
def cylinder_kinematics_kernel(theta, phases, params, dx, ddx):
    """x' and x'' (z, n) of every cylinder at its own local angle theta - phi_k."""
    n = theta.shape[0]
    x = np.empty(n)
    loc = np.empty(n)
    for k in range(phases.shape[0]):
        for i in range(n):
            loc[i] = theta[i] - phases[k]
        kinematics_kernel(loc, params, x, dx[k], ddx[k])


@numba.njit(cache=True)
def _variable_inertia(theta, phases, params, m_rec, j0, j, dj):
    dx = np.empty((phases.shape[0], theta.shape[0]))
    ddx = np.empty_like(dx)
    cylinder_kinematics_kernel(theta, phases, params, dx, ddx)
    for i in range(theta.shape[0]):
        j[i] = j0
        dj[i] = 0.0
        for k in range(phases.shape[0]):
            j[i] += m_rec * dx[k, i] * dx[k, i]
            dj[i] += 2.0 * m_rec * dx[k, i] * ddx[k, i]


def variable_inertia(
    theta: np.ndarray, phases: np.ndarray, params: np.ndarray, m_rec: float, j0: float
) -> tuple[np.ndarray, np.ndarray]:
    """J(theta) = J0 + sum_k m_rec x'(theta - phi_k)^2 and dJ/dtheta (Seddak Eq. 15), kg m^2 and kg m^2/rad.

    phases : (z,) firing angles phi_k [rad] of the cylinders on the shaft section that rotates with theta.
    """
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    ph = np.ascontiguousarray(phases, dtype=np.float64).ravel()
    if m_rec < 0 or j0 < 0:
        raise ValueError("m_rec and j0 must be >= 0")
    j, dj = np.empty_like(th), np.empty_like(th)
    _variable_inertia(th, ph, np.ascontiguousarray(params, dtype=np.float64), float(m_rec), float(j0), j, dj)
    return j, dj


def cylinder_volume(theta: np.ndarray, params: np.ndarray, piston_area: float, clearance: float) -> np.ndarray:
    """V(theta) = V_c + A_p x(theta) [m^3]."""
    x, _, _ = kinematics(theta, params)
    return clearance + piston_area * x
