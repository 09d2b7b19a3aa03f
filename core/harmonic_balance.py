"""One cycle's harmonic balance through the torsional chain (design.md §4, physics.md §12.3), as the monitor runs it.

``operating_point`` keeps the chain matrices and transfer functions of one mean speed and load (they depend on Omega
only and are rebuilt when the operating point moves); ``harmonic_balance`` evaluates the cycle's excitation on the
measured flywheel motion, passes it through the chain and returns the speed equations, affine in the friction
coefficients and the tooth-error nuisances. The frozen terms (twist, throw speeds, J(theta) remainder) come from the
previous cycle's model motion (warm start), refreshed once on the first cycle (physics.md §12.3: one refresh is
enough).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.dynamics import Receptance, ShaftModel, receptance, shaft_model, static_twist
from core.engine import EngineSpec
from core.excitation import Excitation, ExcitationPlan, cycle_excitation, excitation_plan
from core.flywheel import FlywheelMotion
from core.identify import CycleRows, ParameterLayout, friction_design


@dataclass(frozen=True)
class OperatingPoint:
    """Chain matrices and transfer functions at one mean speed and load (cached in the monitor state)."""

    omega_mean: float
    load_torque: float
    shaft: ShaftModel
    receptance: Receptance
    transfer: np.ndarray  # (M, N) flywheel speed per node torque
    plan: ExcitationPlan | None = None  # spec constants of the excitation kernel


def operating_point(spec: EngineSpec, op: OperatingPoint | None, omega: float, load: float, m: int,
                    rebuild_tolerance: float, variable_inertia: bool) -> OperatingPoint:
    """``op`` itself while Omega is within ``rebuild_tolerance`` (relative) and the load within 5 %, else a new one."""
    load_ok = np.isfinite(load)
    if op is not None and abs(omega / op.omega_mean - 1.0) <= rebuild_tolerance and (
            not load_ok or abs(load - op.load_torque) <= 0.05 * max(abs(op.load_torque), 1e-9)):
        return op
    shaft = shaft_model(spec, load if load_ok else 0.0, omega)
    rec = receptance(shaft, omega, m)
    return OperatingPoint(omega, load if load_ok else 0.0, shaft, rec, rec.speed_transfer(shaft.flywheel),
                          excitation_plan(spec, shaft.recip_inertia_mean, variable_inertia))


def harmonic_balance(spec: EngineSpec, layout: ParameterLayout, theta: np.ndarray, n_nuisance: int,
                     relative_motion: np.ndarray | None, static: np.ndarray | None, grid: np.ndarray,
                     pressure: np.ndarray, fly: FlywheelMotion, theta_start: float, op: OperatingPoint,
                     passes: int, time_samples: int, variable_inertia: bool
                     ) -> tuple[Excitation, CycleRows, np.ndarray, np.ndarray, np.ndarray]:
    """Passes of excitation + chain response at the current parameters ``theta`` (friction first, then the
    ``n_nuisance`` tooth-error nuisances); ``relative_motion`` (N, M) and ``static`` (N,) are the previous cycle's
    node-minus-flywheel motion (None on the first cycle). Returns the last excitation, the rows (friction columns,
    then the tooth-error nuisances), node speeds (N, M), and this cycle's node-minus-flywheel motion (harmonics and
    static twist) for the next cycle."""
    rel = relative_motion
    n_nodes = spec.n_nodes
    if rel is not None and rel.shape != (n_nodes, fly.n_harmonics):
        rel = None
    coef = layout.coefficients(theta[: layout.n_params])
    static = static if static is not None and static.shape == (n_nodes,) else None
    # warm start: with the previous cycle's node motion the first pass already is a refresh (physics.md §12.3)
    n_pass = max(1, passes - 1) if rel is not None and static is not None else max(1, passes)
    for _ in range(n_pass):
        exc = cycle_excitation(spec, grid, pressure, fly, theta_start, time_samples,
                               op.shaft.recip_inertia_mean, rel if n_nodes > 1 else None,
                               static if n_nodes > 1 else None, variable_inertia, op.plan)
        mean_torque = np.zeros(n_nodes)
        np.add.at(mean_torque, spec.cylinder_node, exc.indicated_mean - (coef * exc.basis_mean).sum(axis=1))
        static = static_twist(op.shaft, mean_torque)
        torque = exc.known_harm.copy()
        np.add.at(torque, spec.cylinder_node, -np.einsum("kl,klm->km", coef, exc.basis_harm))
        phi = np.einsum("mij,jm->im", op.receptance.inverse, torque)
        rel = phi - phi[op.shaft.flywheel]
    node_speed = 1j * op.receptance.freq[None, :] * phi
    w0 = np.einsum("mq,qm->m", op.transfer, exc.known_harm)
    design = friction_design(layout, op.transfer, exc.basis_harm, spec.cylinder_node)
    if n_nuisance:
        design = np.hstack([design, 1j * fly.freq[:, None] * fly.pattern_harmonics[:, :n_nuisance]])
    cyl_rows = layout.cylinder_rows(exc.basis_mean)
    rows = CycleRows(design=design, target=fly.speed_harmonics - w0,
                     mean_row=np.concatenate([cyl_rows.sum(axis=0), np.zeros(n_nuisance)]),
                     mean_target=float("nan"),
                     cylinder_rows=cyl_rows)
    return exc, rows, node_speed, rel, static
