"""Per-cycle torques on the uniform *time* grid of the cycle, ready for harmonic balance (physics.md §12).

For each throw node q and cylinder k on it, with the node's angle theta_q(t), speed omega_q, acceleration alpha_q:

  known torque   K_q = sum_k [ T_g,k  -  (T_a,k - Jrec_mean alpha_q) ]            (physics.md §12.3 item 2)
  friction       T_f,k = sum_l a_kl F_kl(theta_q - phi_k, omega_q, p_k)           (physics.md §7)

T_a,k = m_rec x'(x'' omega^2 + x' alpha) is the reciprocating torque; its mean-inertia part stays in the mass matrix.
The pressure sample of cylinder k was taken when the *flywheel* encoder read theta_F(t), so p_k(t) = P_k(theta_F(t)),
while its kinematics follow its own throw angle (twist; physics.md §12.3 item 3). The throw motion is the measured
flywheel motion plus the model's node-minus-flywheel motion of the previous iterate (zero on the first pass).

Mean torques are work means, (1/4 pi) * integral of T d(theta_q) = <T omega_q> / Omega, so they close the energy balance.

This module holds what the monitor shares about them: the ``Excitation`` record of one cycle's torques, and
``ExcitationPlan`` / ``excitation_plan``, the spec's constants computed once. The torques themselves are evaluated
inside the one-kernel harmonic-balance pass (core.monitor.balance_pass_kernel, with core.monitor.harmonic_balance_kernels._cycle_rows).
The step-by-step functions it replaced (grid motion, cycle excitation, periodic interpolation) are test references
now: tests/core/excitation_reference.py.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.excitation_kernels import excitation_consts
from frictionwatch.core.monitor.flywheel import harmonics_of

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
    """What the excitation of a cycle needs from the spec, computed once (the monitor keeps it in its operating point).

    consts (23 + z,) see core.monitor.excitation_kernels; cyl_node (z,) int64; phases (z,) firing angles [rad]."""

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
