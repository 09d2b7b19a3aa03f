"""Per-cycle torques on the uniform *time* grid of the cycle, ready for harmonic balance (physics.md §12).

For each throw node q and cylinder k on it, with the node's angle theta_q(t), speed omega_q, acceleration alpha_q:

  known torque   K_q = sum_k [ T_g,k  -  (T_a,k - Jrec_mean alpha_q) ]            (physics.md §12.3 item 2)
  friction       T_f,k = sum_l a_kl F_kl(theta_q - phi_k, omega_q, p_k)           (physics.md §7)

T_a,k = m_rec x'(x'' omega^2 + x' alpha) is the reciprocating torque; its mean-inertia part stays in the mass matrix.
The pressure sample of cylinder k was taken when the *flywheel* encoder read theta_F(t), so p_k(t) = P_k(theta_F(t)),
while its kinematics follow its own throw angle (twist; physics.md §12.3 item 3). The throw motion is the measured
flywheel motion plus the model's node-minus-flywheel motion of the previous iterate (zero on the first pass).

Mean torques are work means, (1/4 pi) * integral of T d(theta_q) = <T omega_q> / Omega, so they close the energy balance.

This module holds what the monitor shares about them: the ``Excitation`` record of one cycle's torques and
``cylinder_record``, the engine's constants of the pass kernels (core.monitor.balance.harmonic_balance_kernels), built once.
The friction basis F_kl is whatever term library the parameter layout carries (core.model.terms).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.balance.harmonic_balance_kernels import CylinderRecord
from frictionwatch.core.monitor.teeth.flywheel import harmonics_of

CRANKCASE_PA = 1.0e5


@dataclass(frozen=True)
class Excitation:
    """Torques of one cycle on n_t uniform time samples and their harmonics (M).

    tau (n_t,) s; theta_fly (n_t,) rad flywheel angle; omega_node (N, n_t) rad/s
    gas (z, n_t) N m; known_harm (N, M) complex N m: harmonics of the known node torques
    basis (z, L, n_t) F_kl of the L library terms; basis_harm (z, L, M) (computed on first use: the harmonic balance
    needs only their parameter-weighted sums); basis_mean (z, L) work means of F_kl
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


def cylinder_record(spec: EngineSpec, recip_inertia_mean: float, variable_inertia: bool = True) -> CylinderRecord:
    """The engine's constants of the pass kernels: node and firing angle of each cylinder, kinematics, piston area,
    crankcase pressure, reciprocating mass and mean inertia, the loss terms' constants."""
    r, rod, e = (float(v) for v in spec.kinematics_params())
    ph = np.ascontiguousarray(spec.firing_angles, dtype=np.float64)
    return CylinderRecord(int(spec.n_nodes), np.ascontiguousarray(spec.cylinder_node, dtype=np.int64), np.cos(ph),
                          np.sin(ph), ph, r, 1.0 / rod, e, float(spec.piston_area), CRANKCASE_PA,
                          float(spec.reciprocating_mass), float(recip_inertia_mean), bool(variable_inertia),
                          np.ascontiguousarray(spec.friction_params(), dtype=np.float64))
