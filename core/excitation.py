"""Per-cycle torques on the uniform *time* grid of the cycle, ready for harmonic balance (physics.md §12).

For each throw node q and cylinder k on it, with the node's angle theta_q(t), speed omega_q, acceleration alpha_q:

  known torque   K_q = sum_k [ T_g,k  -  (T_a,k - Jrec_mean alpha_q) ]            (physics.md §12.3 item 2)
  friction       T_f,k = sum_l a_kl F_kl(theta_q - phi_k, omega_q, p_k)           (physics.md §7)

T_a,k = m_rec x'(x'' omega^2 + x' alpha) is the reciprocating torque; its mean-inertia part stays in the mass matrix.
The pressure sample of cylinder k was taken when the *flywheel* encoder read theta_F(t), so p_k(t) = P_k(theta_F(t)),
while its kinematics follow its own throw angle (twist; physics.md §12.3 item 3). The throw motion is the measured
flywheel motion plus the model's node-minus-flywheel motion of the previous iterate (zero on the first pass).

Mean torques are work means, (1/4 pi) * integral of T d(theta_q) = <T omega_q> / Omega, so they close the energy balance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.engine import EngineSpec
from core.flywheel import FlywheelMotion, harmonic_series, harmonics_of
from core.friction import N_TERMS, friction_basis
from core.torques import gas_torque, reciprocating_torque

FOUR_PI = 4.0 * np.pi
CRANKCASE_PA = 1.0e5


@dataclass(frozen=True)
class Excitation:
    """Torques of one cycle on n_t uniform time samples and their harmonics (M).

    tau (n_t,) s; theta_fly (n_t,) rad flywheel angle; omega_node (N, n_t) rad/s
    gas (z, n_t) N m; known_harm (N, M) complex N m: harmonics of the known node torques
    basis (z, 6, n_t) F_kl; basis_harm (z, 6, M); basis_mean (z, 6) work means of F_kl
    indicated_mean (z,) N m work mean of T_g,k (= IMEP_k V_d / 4 pi with the throw's own angle)
    """

    tau: np.ndarray
    theta_fly: np.ndarray
    omega_node: np.ndarray
    gas: np.ndarray
    known_harm: np.ndarray
    basis: np.ndarray
    basis_harm: np.ndarray
    basis_mean: np.ndarray
    indicated_mean: np.ndarray


def cycle_excitation(
    spec: EngineSpec,
    grid: np.ndarray,
    pressure: np.ndarray,
    fly: FlywheelMotion,
    theta_start: float,
    n_time: int,
    recip_inertia_mean: float,
    relative_motion: np.ndarray | None = None,
    static_twist: np.ndarray | None = None,
    variable_inertia: bool = True,
) -> Excitation:
    """Evaluate gas, reciprocating-remainder and friction-basis torques of one cycle.

    Parameters
    ----------
    grid : (n,) uniform crank-angle grid of the pressure [rad, cyl-1 convention], spanning 4 pi
    pressure : (z, n) absolute cylinder pressure [Pa] (finite)
    fly : fitted flywheel motion of the cycle
    theta_start : flywheel angle of the first tooth edge [rad] (the fit's tau = 0)
    n_time : samples per cycle of the time grid
    recip_inertia_mean : m_rec <x'^2> [kg m^2]
    relative_motion : (N, M) complex angle harmonics of node minus flywheel [rad] from the previous iterate, or None
    static_twist : (N,) mean angle of each node minus the flywheel [rad] (the m = 0 part the harmonics lack)
    variable_inertia : False models a crank whose reciprocating inertia is constant (no J(theta), no mass torque)
    """
    z = spec.n_cyl
    n_nodes = spec.n_nodes
    m = fly.n_harmonics
    tau, phi, omega_f, alpha_f = fly.on_grid(n_time)
    theta_f = theta_start + fly.omega_mean * tau + phi
    theta_n = np.broadcast_to(theta_f, (n_nodes, n_time)).copy()
    omega_n = np.broadcast_to(omega_f, (n_nodes, n_time)).copy()
    alpha_n = np.broadcast_to(alpha_f, (n_nodes, n_time)).copy()
    if relative_motion is not None:
        rel = np.asarray(relative_motion)
        if rel.shape != (n_nodes, m):
            raise ValueError(f"relative_motion must have shape {(n_nodes, m)}, got {rel.shape}")
        w = fly.freq
        theta_n += harmonic_series(rel, n_time)
        omega_n += harmonic_series(1j * w * rel, n_time)
        alpha_n += harmonic_series(-(w**2) * rel, n_time)
    if static_twist is not None:
        theta_n += np.asarray(static_twist, dtype=np.float64)[:, None]

    # pressure at the flywheel angle of each time sample (periodic in 4 pi)
    p_t = periodic_interp(theta_f, grid, pressure)

    kin = spec.kinematics_params()
    fric = spec.friction_params()
    area = spec.piston_area
    gas = np.empty((z, n_time))
    known = np.zeros((n_nodes, n_time))
    for q in np.unique(spec.cylinder_node):
        cyl = np.flatnonzero(spec.cylinder_node == q)
        ph = spec.firing_angles[cyl]
        gas[cyl] = gas_torque(theta_n[q], p_t[cyl], ph, kin, area, CRANKCASE_PA)
        known[q] = gas[cyl].sum(axis=0)
        if variable_inertia:
            t_a = reciprocating_torque(theta_n[q], omega_n[q], alpha_n[q], ph, kin, spec.reciprocating_mass)
            known[q] += recip_inertia_mean * cyl.size * alpha_n[q] - t_a.sum(axis=0)
    # all cylinders in one kernel call: local angle, throw speed and gauge pressure side by side
    node_of = spec.cylinder_node
    local = theta_n[node_of] - spec.firing_angles[:, None]
    basis = friction_basis(local.ravel(), omega_n[node_of].ravel(), (p_t - CRANKCASE_PA).ravel(), fric)
    basis = np.ascontiguousarray(basis.reshape(N_TERMS, z, n_time).transpose(1, 0, 2))

    w_over = omega_n[node_of] / fly.omega_mean  # (z, n_t): work mean = <T omega_q>/Omega
    return Excitation(
        tau=tau,
        theta_fly=theta_f,
        omega_node=omega_n,
        gas=gas,
        known_harm=harmonics_of(known, m),
        basis=basis,
        basis_harm=harmonics_of(basis, m),
        basis_mean=np.mean(basis * w_over[:, None, :], axis=-1),
        indicated_mean=np.mean(gas * w_over, axis=-1),
    )


def periodic_interp(x: np.ndarray, grid: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of rows ``values`` (r, n) given on the uniform 4 pi-periodic ``grid`` (n,) at angles
    ``x`` (m,) [rad], wrapped into the grid's cycle (np.interp's own ``period`` mode sorts on every call)."""
    g0 = float(grid[0])
    xp = np.append(grid - g0, FOUR_PI)
    u = np.mod(np.asarray(x, dtype=np.float64) - g0, FOUR_PI)
    v = np.atleast_2d(values)
    out = np.empty((v.shape[0], u.shape[0]))
    for k in range(v.shape[0]):
        out[k] = np.interp(u, xp, np.append(v[k], v[k, 0]))
    return out
