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
from core.excitation_kernels import OMEGA_SLOT, _excitation_rows, _interp_rows, excitation_consts
from core.flywheel import FlywheelMotion, harmonics_of
from core.friction import N_TERMS

FOUR_PI = 4.0 * np.pi
CRANKCASE_PA = 1.0e5


@dataclass(frozen=True)
class Excitation:
    """Torques of one cycle on n_t uniform time samples and their harmonics (M).

    tau (n_t,) s; theta_fly (n_t,) rad flywheel angle; omega_node (N, n_t) rad/s
    gas (z, n_t) N m; known_harm (N, M) complex N m: harmonics of the known node torques
    basis (z, 6, n_t) F_kl; basis_harm (z, 6, M); basis_mean (z, 6) work means of F_kl
    indicated_mean (z,) N m work mean of T_g,k (= IMEP_k V_d / 4 pi with the throw's own angle)
    omega_fly, alpha_fly (n_t,) measured flywheel speed [rad/s] and acceleration [rad/s^2] (the fit on the grid)
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
    omega_fly: np.ndarray | None = None
    alpha_fly: np.ndarray | None = None


@dataclass(frozen=True)
class ExcitationPlan:
    """What ``cycle_excitation`` needs from the spec, computed once (the monitor keeps it in its operating point).

    consts (23 + z,) see core.excitation_kernels; cyl_node (z,) int64; phases (z,) firing angles [rad]."""

    consts: np.ndarray
    cyl_node: np.ndarray
    phases: np.ndarray
    n_nodes: int


def excitation_plan(spec: EngineSpec, recip_inertia_mean: float, variable_inertia: bool = True) -> ExcitationPlan:
    consts = excitation_consts(spec.kinematics_params(), spec.friction_params(), spec.piston_area, CRANKCASE_PA,
                               spec.reciprocating_mass, recip_inertia_mean, variable_inertia, 1.0,
                               spec.firing_angles)
    return ExcitationPlan(consts, np.ascontiguousarray(spec.cylinder_node, dtype=np.int64),
                          np.ascontiguousarray(spec.firing_angles, dtype=np.float64), int(spec.n_nodes))


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
    plan: ExcitationPlan | None = None,
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
    plan : ``excitation_plan(spec, recip_inertia_mean, variable_inertia)`` if already at hand (saves its set-up)
    """
    z = spec.n_cyl
    n_nodes = spec.n_nodes
    m = fly.n_harmonics
    if plan is None:
        plan = excitation_plan(spec, recip_inertia_mean, variable_inertia)
    rel = None
    if relative_motion is not None:
        rel = np.asarray(relative_motion)
        if rel.shape != (n_nodes, m):
            raise ValueError(f"relative_motion must have shape {(n_nodes, m)}, got {rel.shape}")
    tau, theta_f, omega_f, alpha_f, motion = grid_motion(fly, n_time, theta_start, n_nodes, rel, static_twist)

    # pressure at the flywheel angle of each time sample (periodic in 4 pi)
    p_t = periodic_interp(theta_f, grid, pressure)

    consts = plan.consts.copy()
    consts[OMEGA_SLOT] = fly.omega_mean
    rows = np.empty((n_nodes + 7 * z, n_time))
    means = np.empty((z, 7))
    _excitation_rows(motion, theta_f, p_t, plan.cyl_node, consts, rows, means)
    # one FFT for the node torques and all basis terms
    harm = harmonics_of(rows[: n_nodes + 6 * z], m)
    return Excitation(
        tau=tau,
        theta_fly=theta_f,
        omega_node=motion[1],
        gas=rows[n_nodes + 6 * z:],
        known_harm=harm[:n_nodes],
        basis=rows[n_nodes: n_nodes + 6 * z].reshape(z, N_TERMS, n_time),
        basis_harm=harm[n_nodes:].reshape(z, N_TERMS, m),
        basis_mean=means[:, :N_TERMS],
        indicated_mean=means[:, N_TERMS],
        omega_fly=omega_f,
        alpha_fly=alpha_f,
    )


def grid_motion(fly: FlywheelMotion, n_time: int, theta_start: float, n_nodes: int,
                relative_motion: np.ndarray | None = None, static_twist: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Flywheel and throw motion on the uniform time grid with one inverse FFT (``FlywheelMotion.on_grid`` plus the
    node-minus-flywheel harmonics and static twist).

    Returns tau (n,) [s], theta_fly, omega_fly, alpha_fly (n,) and motion (3, N, n): angle, speed, acceleration of
    every node."""
    m = fly.n_harmonics
    n = n_time
    if 2 * m >= n:
        raise ValueError(f"{m} harmonics need more than {2 * m} samples per cycle, got {n}")
    w = fly.freq
    harm = fly.harmonics
    n_rel = 0 if relative_motion is None else n_nodes
    spec_rows = np.zeros((3 + 3 * n_rel, n // 2 + 1), dtype=np.complex128)
    half = 0.5 * n
    spec_rows[0, 1: m + 1] = harm * half
    spec_rows[1, 1: m + 1] = (1j * w * harm) * half
    spec_rows[2, 1: m + 1] = (-(w**2) * harm) * half
    if n_rel:
        rel = relative_motion
        spec_rows[3: 3 + n_rel, 1: m + 1] = rel * half
        spec_rows[3 + n_rel: 3 + 2 * n_rel, 1: m + 1] = (1j * w * rel) * half
        spec_rows[3 + 2 * n_rel:, 1: m + 1] = (-(w**2) * rel) * half
    series = np.fft.irfft(spec_rows, n=n, axis=-1)
    period = fly.period
    tau = np.arange(n) * (period / n)
    u = tau / period
    phi = fly.offset + fly.drift * u * (u - 1.0) + series[0]
    omega_f = (fly.omega_mean + fly.drift * (2.0 * u - 1.0) / period) + series[1]
    alpha_f = 2.0 * fly.drift / period**2 + series[2]
    theta_f = theta_start + fly.omega_mean * tau + phi
    motion = np.empty((3, n_nodes, n))
    if n_rel:
        motion[0] = theta_f + series[3: 3 + n_rel]
        motion[1] = omega_f + series[3 + n_rel: 3 + 2 * n_rel]
        motion[2] = alpha_f + series[3 + 2 * n_rel:]
    else:
        motion[0] = theta_f
        motion[1] = omega_f
        motion[2] = alpha_f
    if static_twist is not None:
        motion[0] += np.asarray(static_twist, dtype=np.float64)[:, None]
    return tau, theta_f, omega_f, alpha_f, motion


def periodic_interp(x: np.ndarray, grid: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of rows ``values`` (r, n) given on the uniform 4 pi-periodic ``grid`` (n,) at angles
    ``x`` (m,) [rad], wrapped into the grid's cycle (np.interp's own ``period`` mode sorts on every call)."""
    g0 = float(grid[0])
    xp = np.append(grid - g0, FOUR_PI)
    u = np.mod(np.asarray(x, dtype=np.float64) - g0, FOUR_PI)
    v = np.ascontiguousarray(np.atleast_2d(values), dtype=np.float64)
    out = np.empty((v.shape[0], u.shape[0]))
    _interp_rows(u, xp, v, out)  # np.interp per row, one bracket search per query (core.excitation_kernels)
    return out
