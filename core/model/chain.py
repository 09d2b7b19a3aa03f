"""The drive train as one chain of inertias (physics.md §11): the one model the simulator's plant
(core.plant.plant_setup) and the monitor's harmonic balance (core.model.dynamics.shaft_model) are built from.

N nodes in a line, front to rear; section i joins nodes i and i + 1 with a spring (stiffness[i]) and a relative
damper (damping[i]). Each node carries its rotating inertia and the cylinders on it (``cylinder_node``); the mean
reciprocating inertia m_rec <x'^2> of those cylinders is kept apart (``recip_inertia``): the monitor and a plant with
constant inertia add it to the node, a plant with variable inertia J(theta) integrates it exactly. The encoder reads
``flywheel``, the brake or generator acts on ``load`` (the last node in the presets). A spec with torsional
flexibility off is one rigid node with the whole inertia, every cylinder, the flywheel and the load.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.kinematics import kinematics
from scipy.linalg import eigh


@dataclass(frozen=True)
class DriveTrain:
    """The chain (SI). rotating (N,) kg m^2; recip_inertia (N,) kg m^2 mean reciprocating inertia of the node's
    cylinders; stiffness, damping (N-1,) N m/rad, N m s/rad of the sections; cylinder_node (z,); flywheel, load."""

    rotating: np.ndarray
    recip_inertia: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    cylinder_node: np.ndarray
    flywheel: int
    load: int

    @property
    def n_nodes(self) -> int:
        return int(self.rotating.shape[0])

    @property
    def mass(self) -> np.ndarray:
        """(N,) constant-inertia diagonal: rotating plus mean reciprocating inertia [kg m^2]."""
        return self.rotating + self.recip_inertia

    @property
    def edges(self) -> np.ndarray:
        """(N-1, 2) int64 node pairs of the sections."""
        n = self.n_nodes
        return np.array([(i, i + 1) for i in range(n - 1)], dtype=np.int64).reshape(-1, 2)

    def matrices(self, ground_stiffness: float = 0.0, ground_damping: np.ndarray | float = 0.0
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(M, K, C) of M phi'' + C phi' + K phi = T: M = diag(mass); K, C of the sections, plus a spring to ground
        at the load node (a grid generator) and ground damping (a scalar at the load node or one value per node)."""
        n = self.n_nodes
        k = _section_matrix(self.stiffness, n)
        c = _section_matrix(self.damping, n)
        k[self.load, self.load] += ground_stiffness
        g = np.asarray(ground_damping, dtype=np.float64)
        if g.ndim == 0:
            c[self.load, self.load] += float(g)
        else:
            c[np.diag_indices(n)] += g
        return np.diag(self.mass), k, c

    def static_twist(self, node_torque: np.ndarray) -> np.ndarray:
        """Mean angle of every node minus the flywheel [rad] under constant node torques (N,) [N m]
        (``static_twist_kernel``)."""
        t = np.ascontiguousarray(node_torque, dtype=np.float64)
        if t.shape != (self.n_nodes,):
            raise ValueError(f"node torques must have shape ({self.n_nodes},), got {t.shape}")
        out = np.empty(self.n_nodes)
        static_twist_kernel(t, np.ascontiguousarray(self.stiffness, dtype=np.float64), self.flywheel, out)
        return out


@numba.njit(cache=True)
def static_twist_kernel(node_torque, stiffness, flywheel, out):
    """out (N,) mean angle of every node minus the flywheel under node_torque (N,). The torques are balanced first
    (the last node, the load, takes what is left, as in steady state); section i carries the sum of the torques in
    front of it and twists by that over its stiffness (theta_i+1 = theta_i - twist_i); a section with K = 0 (a
    viscous coupling only) takes no static twist."""
    n = node_torque.shape[0]
    carried = 0.0
    out[0] = 0.0
    for i in range(n - 1):
        carried += node_torque[i]
        out[i + 1] = out[i] - (carried / stiffness[i] if stiffness[i] > 0.0 else 0.0)
    # the balancing torque sits on the last node: it changes no section's load
    ref = out[flywheel]
    for q in range(n):
        out[q] -= ref


def mean_reciprocating_inertia(spec: EngineSpec, samples: int = 2880) -> float:
    """Cycle mean m_rec <x'(theta)^2> of one cylinder [kg m^2] (physics.md §3: m R^2 (1/2 + lambda^2/8 + ...))."""
    th = np.linspace(0.0, 4.0 * np.pi, samples, endpoint=False)
    _, dx, _ = kinematics(th, spec.kinematics_params())
    return float(spec.reciprocating_mass * np.mean(dx * dx))


def scaled_flywheel(spec: EngineSpec, scale: float) -> EngineSpec:
    """``spec`` with its flywheel node's rotating inertia x ``scale`` (a flywheel, pulley or coupling the record has
    wrong; core.model.effects.mismatch.FlywheelInertia). On a one-node record the flywheel node is the whole crank:
    its inertia is scaled."""
    inertia = spec.node_inertia.astype(np.float64).copy()
    inertia[spec.flywheel_node] *= scale
    return replace(spec, node_inertia=inertia)


def drive_train(spec: EngineSpec, flexible: bool = True) -> DriveTrain:
    """The chain of ``spec`` (``flexible``) or its rigid one-node equivalent."""
    z = spec.n_cyl
    if flexible:
        rotating = spec.node_inertia.astype(np.float64).copy()
        stiffness = spec.stiffness.astype(np.float64).copy()
        damping = spec.damping.astype(np.float64).copy()
        cyl_node = spec.cylinder_node.astype(np.int64).copy()
        fly, load = spec.flywheel_node, spec.load_node
    else:
        rotating = np.array([spec.total_inertia])
        stiffness, damping = np.zeros(0), np.zeros(0)
        cyl_node = np.zeros(z, dtype=np.int64)
        fly = load = 0
    recip = np.zeros(rotating.shape[0])
    np.add.at(recip, cyl_node, mean_reciprocating_inertia(spec))
    return DriveTrain(rotating, recip, stiffness, damping, cyl_node, int(fly), int(load))


def lowest_mode_hz(spec: EngineSpec) -> float:
    """The flexible line's lowest non-rigid natural frequency [Hz] (undamped, the load node free); NaN on a one-node
    line (no mode to read). Near it the speed reads omega^2 ~ k / J of the line (design note 109)."""
    if not spec.stiffness.size:
        return float("nan")
    m, k, _ = drive_train(spec, flexible=True).matrices()
    w2 = eigh(k, m, eigvals_only=True)
    w2 = w2[w2 > 1e-9 * max(float(w2.max()), 1e-300)]
    return float(np.sqrt(w2.min()) / (2.0 * np.pi)) if w2.size else float("nan")


def _section_matrix(k: np.ndarray, n: int) -> np.ndarray:
    m = np.zeros((n, n))
    for i, ki in enumerate(k):
        m[i, i] += ki
        m[i + 1, i + 1] += ki
        m[i, i + 1] -= ki
        m[i + 1, i] -= ki
    return m
