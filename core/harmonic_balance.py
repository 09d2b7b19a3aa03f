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

from core.dynamics import Receptance, ShaftModel, receptance, shaft_model
from core.engine import EngineSpec
from core.excitation import Excitation, ExcitationPlan, excitation_plan, excitation_rows
from core.flywheel import FlywheelMotion
from core.friction import N_TERMS
from core.harmonic_balance_kernels import _balance_rows, _mix_plan
from core.identify import CycleRows, ParameterLayout


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
    m = fly.n_harmonics
    if rel is not None and rel.shape != (n_nodes, m):
        rel = None
    static = static if static is not None and static.shape == (n_nodes,) else None
    # warm start: with the previous cycle's node motion the first pass already is a refresh (physics.md §12.3)
    n_pass = max(1, passes - 1) if rel is not None and static is not None else max(1, passes)
    z = spec.n_cyl
    n_par = layout.n_params
    cyl_node = op.plan.cyl_node if op.plan is not None else np.ascontiguousarray(spec.cylinder_node, dtype=np.int64)
    group = np.ascontiguousarray(layout.group, dtype=np.int64)
    prior = np.ascontiguousarray(layout.prior, dtype=np.float64)
    # the friction terms enter the chain only as parameter-weighted sums per node: one G row per (parameter, node)
    mix_row = np.empty((z, N_TERMS), dtype=np.int64)
    mix_param = np.empty(z * N_TERMS, dtype=np.int64)
    mix_node = np.empty(z * N_TERMS, dtype=np.int64)
    n_mix = _mix_plan(group, prior, cyl_node, n_par, n_nodes, mix_row, mix_param, mix_node)
    th = np.ascontiguousarray(theta[:n_par], dtype=np.float64)
    shaft = op.shaft
    rec = op.receptance
    fly_freq = fly.freq
    fly_harm = np.ascontiguousarray(fly.harmonics, dtype=np.complex128)
    pattern = np.ascontiguousarray(fly.pattern_harmonics, dtype=np.complex128) if n_nuisance else (
        np.zeros((m, 0), dtype=np.complex128))
    known = np.empty((n_nodes, m), dtype=np.complex128)
    design = np.empty((m, n_par + n_nuisance), dtype=np.complex128)
    target = np.empty(m, dtype=np.complex128)
    cyl_rows = np.empty((z, n_par))
    mean_row = np.empty(n_par + n_nuisance)
    for _ in range(n_pass):
        exc, harm = excitation_rows(spec, grid, pressure, fly, theta_start, time_samples, shaft.recip_inertia_mean,
                                    rel if n_nodes > 1 else None, static if n_nodes > 1 else None, variable_inertia,
                                    op.plan, (mix_row, prior, n_mix))
        static = np.empty(n_nodes)
        phi = np.empty((n_nodes, m), dtype=np.complex128)
        rel = np.empty((n_nodes, m), dtype=np.complex128)
        node_speed = np.empty((n_nodes, m), dtype=np.complex128)
        _balance_rows(harm, 2.0 / time_samples, m, n_mix, mix_param, mix_node, th, group, prior, cyl_node,
                      _means_of(exc), shaft.compliance, shaft.flywheel, rec.inverse, rec.freq, op.transfer, fly_freq,
                      fly_harm, pattern, n_nuisance, known, static, phi, rel, node_speed, design, target, cyl_rows,
                      mean_row)
    rows = CycleRows(design=design, target=target, mean_row=mean_row, mean_target=float("nan"), cylinder_rows=cyl_rows)
    return exc, rows, node_speed, rel, static


def _means_of(exc: Excitation) -> np.ndarray:
    """The (z, 7) work-means block [basis_mean | indicated_mean] that ``excitation_rows`` wrote (both are views)."""
    base = exc.basis_mean.base
    if base is not None and base.shape == (exc.basis_mean.shape[0], N_TERMS + 1) and base.flags.c_contiguous:
        return base
    return np.ascontiguousarray(np.column_stack([exc.basis_mean, exc.indicated_mean]))
