"""Gas, reciprocating-mass and load torques (physics.md §2, §3, §5).

Sign convention (physics.md §0): gas and mass torques positive in the direction of rotation; friction and load are
magnitudes that oppose rotation.

``gas_torque_sample`` and ``reciprocating_torque_sample`` are the one per-sample definition: the plant
(core.plant.plant), the monitor's harmonic balance (core.monitor.balance.harmonic_balance_kernels), the array
functions below and the coast-down's mean gas torque all call them.
"""

from __future__ import annotations

import numba
import numpy as np
from frictionwatch.core.model.kinematics import cylinder_kinematics_kernel


@numba.njit(cache=True, inline="always")
def gas_torque_sample(p_gauge: float, area: float, dx: float) -> float:
    """T_g = (p - p_cc) A_p x' [N m] at one sample: gauge pressure [Pa], piston area [m^2], x' = dx/dtheta [m/rad]."""
    return p_gauge * area * dx


@numba.njit(cache=True, inline="always")
def reciprocating_torque_sample(m_rec: float, dx: float, ddx: float, omega: float, alpha: float) -> float:
    """T_a = m_rec x'(x'' omega^2 + x' alpha) [N m] at one sample (Cruz-Peragon; the reciprocating part of
    J(theta) alpha + 1/2 J' omega^2, physics.md §3)."""
    return m_rec * dx * (ddx * omega * omega + dx * alpha)


@numba.njit(cache=True)
def _gas_torque(theta, pressure, phases, params, area, p_cc, out):
    dx = np.empty_like(out)
    ddx = np.empty_like(out)
    cylinder_kinematics_kernel(theta, phases, params, dx, ddx)
    for k in range(phases.shape[0]):
        for i in range(theta.shape[0]):
            out[k, i] = gas_torque_sample(pressure[k, i] - p_cc, area, dx[k, i])


def gas_torque(
    theta: np.ndarray, pressure: np.ndarray, phases: np.ndarray, params: np.ndarray, area: float, p_cc: float = 1.0e5
) -> np.ndarray:
    """Per-cylinder gas torque T_g,k = (p_k - p_cc) A_p x'(theta - phi_k) [N m], shape (z, n).

    theta : (n,) cylinder-1 crank angle [rad]; pressure : (z, n) absolute [Pa] sampled at theta;
    phases : (z,) firing angles [rad]; params : [R, L, e]; area : piston area [m^2]; p_cc : crankcase pressure [Pa].
    """
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    p = np.ascontiguousarray(pressure, dtype=np.float64)
    ph = np.ascontiguousarray(phases, dtype=np.float64).ravel()
    if p.ndim != 2 or p.shape != (ph.shape[0], th.shape[0]):
        raise ValueError(f"pressure must have shape (z, n) = ({ph.shape[0]}, {th.shape[0]}), got {p.shape}")
    out = np.empty_like(p)
    _gas_torque(th, p, ph, np.ascontiguousarray(params, dtype=np.float64), float(area), float(p_cc), out)
    return out


@numba.njit(cache=True)
def _mass_torque(theta, omega, alpha, phases, params, m_rec, out):
    dx = np.empty_like(out)
    ddx = np.empty_like(out)
    cylinder_kinematics_kernel(theta, phases, params, dx, ddx)
    for k in range(phases.shape[0]):
        for i in range(theta.shape[0]):
            out[k, i] = reciprocating_torque_sample(m_rec, dx[k, i], ddx[k, i], omega[i], alpha[i])


def reciprocating_torque(
    theta: np.ndarray, omega: np.ndarray, alpha: np.ndarray, phases: np.ndarray, params: np.ndarray, m_rec: float
) -> np.ndarray:
    """Cruz-Peragon's reciprocating torque T_a,k = m_rec x'(x'' omega^2 + x' alpha) [N m], shape (z, n).

    It is the reciprocating part of the left-hand side of J(theta) alpha + 1/2 J' omega^2 (physics.md §3, R1).
    With alpha = 0 it is minus the mass torque: T_m,k = -m_rec x' x'' omega^2.
    """
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    n = th.shape[0]
    w = np.ascontiguousarray(np.broadcast_to(np.asarray(omega, dtype=np.float64), (n,)))
    a = np.ascontiguousarray(np.broadcast_to(np.asarray(alpha, dtype=np.float64), (n,)))
    ph = np.ascontiguousarray(phases, dtype=np.float64).ravel()
    out = np.empty((ph.shape[0], n))
    _mass_torque(th, w, a, ph, np.ascontiguousarray(params, dtype=np.float64), float(m_rec), out)
    return out


def mass_torque(theta: np.ndarray, omega: np.ndarray, phases: np.ndarray, params: np.ndarray, m_rec: float) -> np.ndarray:
    """Mass (inertia) torque T_m = -1/2 J'(theta) omega^2 per cylinder, (z, n) [N m]."""
    return -reciprocating_torque(theta, omega, np.zeros_like(np.asarray(theta, dtype=np.float64)), phases, params, m_rec)


def load_torque(omega: np.ndarray, c: float, k: float, s: float) -> np.ndarray:
    """Speed-power load T_L = c + k omega^s [N m] (paper 001 Eq. 22). A magnitude opposing rotation."""
    w = np.asarray(omega, dtype=np.float64)
    if np.any(w < 0):
        raise ValueError("omega must be >= 0 for the speed-power load model")
    return c + k * w**s
