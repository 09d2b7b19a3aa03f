"""Crank dynamics: the rigid torque balance (paper 001 Eq. 26) and the torsional chain by harmonic balance
(paper 000 Eq. 3; physics.md §4, §11, §12).

Harmonic convention used throughout the monitor: a periodic signal over one cycle of period T is

    x(tau) = x_0 + sum_{m=1..M} Re( X_m exp(i w_m tau) ),   w_m = m * 2 pi / T = m * Omega / 2,

so ``X_m = 2 * rfft(x)[m] / n`` for n uniform samples, harmonic m is engine order m/2, and the mean of a product is
x_0 y_0 + 1/2 sum_m Re(X_m conj(Y_m)).

The shaft is M phi'' + C phi' + K phi = T (physics.md §11, phi = theta - Omega t). M holds each node's rotating inertia
plus the *mean* reciprocating inertia of the cylinders it carries; the periodic remainder of J(theta) and the mass
torque go to the right-hand side (physics.md §12.3 item 2). Ground terms at the load node: the linearised
electromagnetic spring/damper of a grid generator, or dT_L/domega of a speed-power brake. A single-node spec is the
rigid engine: Z_m = -w_m^2 J + i w_m c_load.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import scipy.linalg
from frictionwatch.core.model.chain import DriveTrain, drive_train, mean_reciprocating_inertia
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.kinematics import variable_inertia


@dataclass(frozen=True)
class ShaftModel:
    """The drive train (core.model.chain) at one operating point: constant matrices of the chain with its ground
    terms (SI).

    mass           (N,) kg m^2: rotating inertia + mean reciprocating inertia of the node's cylinders
    stiffness      (N, N) N m/rad incl. ground stiffness at the load node
    damping        (N, N) N m s/rad incl. ground damping at the load node
    edges          (E, 2) int: node pairs joined by a relative damper (for the dissipation, physics.md §12.4)
    edge_damping   (E,) N m s/rad
    ground_damping (N,) N m s/rad: absolute damping of each node (load node only)
    flywheel       index of the node whose speed the encoder measures
    cylinder_node  (z,) int node carrying each cylinder
    recip_inertia_mean  mean reciprocating inertia of one cylinder, m_rec <x'^2> [kg m^2]
    train          the drive train itself (static twist: ``DriveTrain.static_twist``)
    """

    mass: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    edges: np.ndarray
    edge_damping: np.ndarray
    ground_damping: np.ndarray
    flywheel: int
    cylinder_node: np.ndarray
    recip_inertia_mean: float
    train: DriveTrain

    @property
    def n_nodes(self) -> int:
        return int(self.mass.shape[0])


def shaft_model(spec: EngineSpec, load_torque: float = 0.0, omega_mean: float = 1.0) -> ShaftModel:
    """The chain of ``spec`` (core.model.chain.drive_train) at an operating point.

    Parameters
    ----------
    load_torque : mean load torque [N m]; with a speed-power brake T = k omega^s it sets the load damping
        dT/domega = s T / omega at the load node (physics.md §5)
    omega_mean : mean speed [rad/s]
    """
    if omega_mean <= 0:
        raise ValueError(f"omega_mean must be > 0 rad/s, got {omega_mean}")
    train = drive_train(spec)
    ground = np.zeros(train.n_nodes)
    grid_k = 0.0
    ld = spec.load
    if ld.kind == "grid":
        grid_k = ld.grid_stiffness_nm_per_rad
        ground[train.load] += ld.grid_damping_nms_per_rad
    elif np.isfinite(load_torque) and load_torque > 0:
        ground[train.load] += ld.exponent * load_torque / omega_mean
    _, stiff, damp = train.matrices(grid_k, ground)
    return ShaftModel(mass=train.mass, stiffness=stiff, damping=damp, edges=train.edges,
                      edge_damping=train.damping.copy(), ground_damping=ground, flywheel=train.flywheel,
                      cylinder_node=train.cylinder_node.copy(), recip_inertia_mean=mean_reciprocating_inertia(spec),
                      train=train)


def natural_frequencies(shaft: ShaftModel) -> np.ndarray:
    """Undamped natural frequencies [Hz] of the chain (generalised eigenvalues of K, M), ascending, rigid mode
    (0 Hz of a free-free chain) included. A single node gives [0] (or the grid mode)."""
    lam = scipy.linalg.eigh(shaft.stiffness, np.diag(shaft.mass), eigvals_only=True)
    return np.sqrt(np.clip(lam, 0.0, None)) / (2.0 * np.pi)


def free_modes(shaft: ShaftModel) -> np.ndarray:
    """The chain's damped free-vibration eigenvalues lambda [1/s] with Im lambda > 0 (one of each oscillating
    pair), ascending in |lambda|: its free motion is a sum of Re(c e^(lambda t)). Overdamped (real) modes and the
    rigid mode are left out."""
    n = shaft.n_nodes
    m = shaft.mass[:, None]
    state = np.block([[np.zeros((n, n)), np.eye(n)], [-shaft.stiffness / m, -shaft.damping / m]])
    lam = np.linalg.eigvals(state)
    lam = lam[lam.imag > 1e-9 * np.maximum(np.abs(lam), 1.0)]
    return np.ascontiguousarray(lam[np.argsort(np.abs(lam))], dtype=np.complex128)


def first_flexible_mode_hz(shaft: ShaftModel, min_hz: float = 5.0) -> float:
    """The lowest natural frequency above ``min_hz`` (skips the rigid and grid electromechanical modes); inf if rigid."""
    f = natural_frequencies(shaft)
    f = f[f > min_hz]
    return float(f[0]) if f.size else float("inf")


@dataclass(frozen=True)
class Receptance:
    """Per-harmonic inverse dynamic stiffness Z_m^-1 = (K - w_m^2 M + i w_m C)^-1 at one mean speed.

    It depends on Omega only, so the monitor computes it once per operating point (physics.md §12.1).
    harmonics (M,) int m = 1..M; freq (M,) w_m [rad/s]; inverse (M, N, N) complex [rad/(N m)].
    """

    omega_mean: float
    harmonics: np.ndarray
    freq: np.ndarray
    inverse: np.ndarray

    @property
    def n_harmonics(self) -> int:
        return int(self.harmonics.shape[0])

    def speed_transfer(self, node: int) -> np.ndarray:
        """(M, N): speed harmonic of ``node`` per unit torque harmonic at each node, i w_m [Z_m^-1]_{node, q}."""
        return 1j * self.freq[:, None] * self.inverse[:, node, :]


def receptance(shaft: ShaftModel, omega_mean: float, n_harmonics: int) -> Receptance:
    """Solve Z_m^-1 for m = 1..n_harmonics (harmonic m = engine order m/2, w_m = m Omega/2)."""
    if n_harmonics < 1:
        raise ValueError("n_harmonics must be >= 1")
    if omega_mean <= 0:
        raise ValueError(f"omega_mean must be > 0 rad/s, got {omega_mean}")
    m = np.arange(1, n_harmonics + 1)
    w = 0.5 * omega_mean * m
    inv = np.linalg.inv(dynamic_stiffness(shaft, w))
    return Receptance(omega_mean=float(omega_mean), harmonics=m, freq=w, inverse=inv)


def dynamic_stiffness(shaft: ShaftModel, freq: np.ndarray) -> np.ndarray:
    """(M, N, N) complex Z_m = K - w_m^2 M + i w_m C at the frequencies ``freq`` (M,) [rad/s]."""
    w = np.asarray(freq, dtype=np.float64)
    return (shaft.stiffness[None, :, :] - (w**2)[:, None, None] * np.diag(shaft.mass)[None, :, :]
            + 1j * w[:, None, None] * shaft.damping[None, :, :])


def node_torque_harmonics(shaft: ShaftModel, rec: Receptance, speed: np.ndarray) -> np.ndarray:
    """The node torque harmonics (N, M) [N m] that drive node speed harmonics ``speed`` (N, M) [rad/s] through
    the chain: Z_m (speed / i w_m), the inverse of ``node_speed_harmonics`` (what the balance put through the chain,
    kept for the drive train's identification, core.monitor.calibration.drive_train)."""
    s = np.asarray(speed)
    if s.shape != (rec.inverse.shape[1], rec.n_harmonics):
        raise ValueError(f"node speed harmonics must have shape (N, M) = {(rec.inverse.shape[1], rec.n_harmonics)}")
    phi = s / (1j * rec.freq[None, :])
    return np.einsum("mij,jm->im", dynamic_stiffness(shaft, rec.freq), phi)


def node_speed_harmonics(rec: Receptance, torque: np.ndarray) -> np.ndarray:
    """Speed harmonics (N, M) [rad/s] of every node under node torque harmonics ``torque`` (N, M) [N m]."""
    t = np.asarray(torque)
    if t.shape != (rec.inverse.shape[1], rec.n_harmonics):
        raise ValueError(f"torque harmonics must have shape (N, M) = {(rec.inverse.shape[1], rec.n_harmonics)}")
    phi = np.einsum("mij,jm->im", rec.inverse, t)
    return 1j * rec.freq[None, :] * phi


def dissipated_power(shaft: ShaftModel, speed: np.ndarray) -> tuple[float, float]:
    """Mean power [W] dissipated by the relative dampers (torsional damper, shaft, coupling) and by the ground
    dampers (load node), from node speed harmonics (N, M) (physics.md §12.4: the cycle mean of omega^T C omega).

    One small kernel (``dissipation_kernel``); the plain-numpy reference is in tests/core/test_dissipation_kernel.py."""
    s = speed
    if not (type(s) is np.ndarray and s.dtype == np.complex128 and s.flags.c_contiguous):
        s = np.ascontiguousarray(s, dtype=np.complex128)
    n = shaft.mass.shape[0]
    if s.ndim != 2 or s.shape[0] != n:
        raise ValueError(f"node speed harmonics must have shape (N, M) with N = {n}, got {s.shape}")
    edges, c_edge, c_ground = shaft.edges, shaft.edge_damping, shaft.ground_damping
    if not (edges.dtype == np.int64 and edges.flags.c_contiguous and c_edge.dtype == np.float64
            and c_edge.flags.c_contiguous and c_ground.dtype == np.float64 and c_ground.flags.c_contiguous):
        edges = np.ascontiguousarray(edges, dtype=np.int64).reshape(-1, 2)
        c_edge = np.ascontiguousarray(c_edge, dtype=np.float64)
        c_ground = np.ascontiguousarray(c_ground, dtype=np.float64)
    return dissipation_kernel(s, edges, c_edge, c_ground)


@numba.njit(cache=True)
def dissipation_kernel(speed, edges, edge_damping, ground_damping):
    """(relative, ground) mean dissipated power [W]: 0.5 sum_e c_e |s_i - s_j|^2 and 0.5 sum_q c_q |s_q|^2 over
    the node speed harmonics ``speed`` (N, M) (the mean of a product of harmonics is half the real inner product)."""
    n, m = speed.shape
    rel = 0.0
    for q in range(edges.shape[0]):
        a = edges[q, 0]
        b = edges[q, 1]
        c = edge_damping[q]
        for i in range(m):
            d = speed[a, i] - speed[b, i]
            rel += c * (d.real * d.real + d.imag * d.imag)
    gnd = 0.0
    for q in range(n):
        c = ground_damping[q]
        for i in range(m):
            v = speed[q, i]
            gnd += c * (v.real * v.real + v.imag * v.imag)
    return 0.5 * rel, 0.5 * gnd


def static_twist(shaft: ShaftModel, node_torque: np.ndarray) -> np.ndarray:
    """Mean angle of every node minus the flywheel [rad] under mean node torques (N,) [N m] (harmonic m = 0):
    the drive train's (core.model.chain.DriveTrain.static_twist)."""
    return shaft.train.static_twist(node_torque)


# ---- rigid balance ------------------------------------------------------------------------------------------


def rigid_friction_torque(
    theta: np.ndarray,
    omega: np.ndarray,
    alpha: np.ndarray,
    gas_torque_total: np.ndarray,
    load_torque: np.ndarray | float,
    spec: EngineSpec,
) -> np.ndarray:
    """Instantaneous total friction torque of a rigid engine [N m] (paper 001 Eq. 26, Newton form, physics.md §4):

        T_f(theta) = sum_k T_g,k - T_L - J(theta) alpha - 1/2 J'(theta) omega^2,

    with J(theta) = sum of node inertias + sum_k m_rec x'(theta - phi_k)^2. The mass torque is counted exactly once
    (through J'). Valid below the first torsional mode: pass omega, alpha low-passed below ~0.6 f1.

    theta (n,) cylinder-1 crank angle [rad]; omega, alpha (n,) [rad/s, rad/s^2]; gas_torque_total (n,) [N m];
    load_torque scalar or (n,) [N m] (a magnitude).
    """
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    n = th.shape[0]
    w = np.broadcast_to(np.asarray(omega, dtype=np.float64), (n,))
    a = np.broadcast_to(np.asarray(alpha, dtype=np.float64), (n,))
    g = np.broadcast_to(np.asarray(gas_torque_total, dtype=np.float64), (n,))
    tl = np.broadcast_to(np.asarray(load_torque, dtype=np.float64), (n,))
    j, dj = variable_inertia(th, spec.firing_angles, spec.kinematics_params(), spec.reciprocating_mass,
                             spec.total_inertia)
    return g - tl - j * a - 0.5 * dj * w * w
