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
from functools import cached_property

import numpy as np

from core.engine import EngineSpec
from core.excitation_kernels import OMEGA_SLOT, _interp_rows, excitation_consts
from core.flywheel import FlywheelMotion, harmonics_of
from core.friction import N_TERMS
from core.harmonic_balance_kernels import _cycle_rows, _grid_spectrum, _motion_from_series

FOUR_PI = 4.0 * np.pi
CRANKCASE_PA = 1.0e5


@dataclass(frozen=True)
class Excitation:
    """Torques of one cycle on n_t uniform time samples and their harmonics (M).

    tau (n_t,) s; theta_fly (n_t,) rad flywheel angle; omega_node (N, n_t) rad/s
    gas (z, n_t) N m; known_harm (N, M) complex N m: harmonics of the known node torques
    basis (z, 6, n_t) F_kl; basis_harm (z, 6, M) (computed on first use: the harmonic balance needs only their
    parameter-weighted sums); basis_mean (z, 6) work means of F_kl
    indicated_mean (z,) N m work mean of T_g,k (= IMEP_k V_d / 4 pi with the throw's own angle)
    omega_fly, alpha_fly (n_t,) measured flywheel speed [rad/s] and acceleration [rad/s^2] (the fit on the grid)
    """

    tau: np.ndarray
    theta_fly: np.ndarray
    omega_node: np.ndarray
    gas: np.ndarray
    known_harm: np.ndarray
    basis: np.ndarray
    basis_mean: np.ndarray
    indicated_mean: np.ndarray
    omega_fly: np.ndarray | None = None
    alpha_fly: np.ndarray | None = None

    @cached_property
    def basis_harm(self) -> np.ndarray:
        return harmonics_of(self.basis, self.known_harm.shape[1])


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
    exc, _ = excitation_rows(spec, grid, pressure, fly, theta_start, n_time, recip_inertia_mean, relative_motion,
                             static_twist, variable_inertia, plan)
    return exc


def excitation_rows(spec: EngineSpec, grid: np.ndarray, pressure: np.ndarray, fly: FlywheelMotion,
                    theta_start: float, n_time: int, recip_inertia_mean: float,
                    relative_motion: np.ndarray | None = None, static_twist: np.ndarray | None = None,
                    variable_inertia: bool = True, plan: ExcitationPlan | None = None,
                    mix: tuple[np.ndarray, np.ndarray, int] | None = None) -> tuple[Excitation, np.ndarray]:
    """``cycle_excitation`` and the rfft of the rows [G (n_mix); known node torques (N)] (n_mix + N, n_time//2 + 1).

    mix : (mix_row (z, 6), mix_weight (z, 6), n_mix): which weighted basis terms are summed into the G rows
    (core.harmonic_balance_kernels._mix_plan); None for no G rows."""
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
    if mix is None:
        mix_row, mix_weight, n_mix = np.full((z, N_TERMS), -1, dtype=np.int64), np.zeros((z, N_TERMS)), 0
    else:
        mix_row, mix_weight, n_mix = mix
    consts = plan.consts.copy()
    consts[OMEGA_SLOT] = fly.omega_mean
    n_head = n_mix + n_nodes
    buf = np.empty((n_head + 7 * z, n_time))
    means = np.empty((z, 7))
    _cycle_rows(motion, theta_f, np.ascontiguousarray(grid, dtype=np.float64),
                np.ascontiguousarray(pressure, dtype=np.float64), plan.cyl_node, consts, mix_row, mix_weight, n_mix,
                buf, means)
    harm = np.fft.rfft(buf[:n_head], axis=-1)  # one FFT for the G rows and the node torques
    known = harm[n_mix:, 1: m + 1] * (2.0 / n_time)
    exc = Excitation(
        tau=tau,
        theta_fly=theta_f,
        omega_node=motion[1],
        gas=buf[n_head + 6 * z:],
        known_harm=known,
        basis=buf[n_head: n_head + 6 * z].reshape(z, N_TERMS, n_time),
        basis_mean=means[:, :N_TERMS],
        indicated_mean=means[:, N_TERMS],
        omega_fly=omega_f,
        alpha_fly=alpha_f,
    )
    return exc, harm


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
    n_rel = 0 if relative_motion is None else n_nodes
    rel = (np.ascontiguousarray(relative_motion, dtype=np.complex128) if n_rel
           else np.zeros((0, m), dtype=np.complex128))
    spec_rows = np.zeros((3 + 3 * n_rel, n // 2 + 1), dtype=np.complex128)
    _grid_spectrum(np.ascontiguousarray(fly.harmonics, dtype=np.complex128), fly.freq, rel, n_rel, 0.5 * n,
                   spec_rows)
    series = np.fft.irfft(spec_rows, n=n, axis=-1)
    static = np.zeros(0) if static_twist is None else np.ascontiguousarray(static_twist, dtype=np.float64)
    if static.shape not in ((0,), (n_nodes,)):
        raise ValueError(f"static_twist must have shape {(n_nodes,)}, got {static.shape}")
    tau = np.empty(n)
    theta_f = np.empty(n)
    omega_f = np.empty(n)
    alpha_f = np.empty(n)
    motion = np.empty((3, n_nodes, n))
    _motion_from_series(series, n_rel, float(fly.offset), float(fly.drift), float(fly.period), float(fly.omega_mean),
                        float(theta_start), static, tau, theta_f, omega_f, alpha_f, motion)
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
