"""One cycle's harmonic balance through the torsional chain (design.md §4, physics.md §12.3), as the monitor runs it.

``operating_point`` keeps the chain matrices and transfer functions of one mean speed and load (they depend on Omega
only and are rebuilt when the operating point moves); ``harmonic_balance`` evaluates the cycle's excitation on the
measured flywheel motion, passes it through the chain and returns the speed equations, affine in the friction
coefficients and the tooth-error nuisances. The frozen terms (twist, throw speeds, J(theta) remainder) come from the
previous cycle's model motion (warm start), refreshed once on the first cycle (physics.md §12.3: one refresh is
enough).

Speed: a pass is one numba kernel (core.monitor.balance_pass_kernel._balance_pass: motion, torques, both FFTs, chain, rows);
the arguments fixed by the engine, layout and operating point are prepared once per operating point (``_constants``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from frictionwatch.core.monitor.balance_pass_kernel import _balance_pass
from frictionwatch.core.model.dynamics import Receptance, ShaftModel, receptance, shaft_model
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.excitation import Excitation, ExcitationPlan, excitation_plan
from frictionwatch.core.monitor.flywheel import FlywheelMotion
from frictionwatch.core.model.friction import N_TERMS
from frictionwatch.core.monitor.identify import CycleRows, ParameterLayout


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
    load_ok = math.isfinite(load)
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
                     ) -> tuple[Excitation, CycleRows, np.ndarray, np.ndarray, np.ndarray, tuple[float, float]]:
    """Passes of excitation + chain response at the current parameters ``theta`` (friction first, then the
    ``n_nuisance`` tooth-error nuisances); ``relative_motion`` (N, M) and ``static`` (N,) are the previous cycle's
    node-minus-flywheel motion (None on the first cycle). Returns the last excitation, the rows (friction columns,
    then the tooth-error nuisances), node speeds (N, M), this cycle's node-minus-flywheel motion (harmonics and
    static twist) for the next cycle, and the mean power [W] the relative and the ground dampers dissipate
    (``core.model.dynamics.dissipated_power`` of the node speeds, formed in the kernel while they are in cache)."""
    const = _constants(spec, layout, op, variable_inertia)
    (n_nodes, z, n_par, twist, cyl_node, consts, group, prior, compliance, flywheel, inverse, rec_freq,
     transfer, edges, edge_damping, ground_damping) = const[4]
    harmonics = fly.harmonics
    m = harmonics.shape[0]
    if 2 * m >= time_samples:
        raise ValueError(f"{m} harmonics need more than {2 * m} samples per cycle, got {time_samples}")
    rel = relative_motion
    if rel is not None and rel.shape != (n_nodes, m):
        rel = None
    if static is not None and static.shape != (n_nodes,):
        static = None
    # warm start: with the previous cycle's node motion the first pass already is a refresh (physics.md §12.3)
    n_pass = max(1, passes - 1) if rel is not None and static is not None else max(1, passes)
    th = _contiguous(theta[:n_par], np.float64)
    harmonics = _contiguous(harmonics, np.complex128)
    pattern = _contiguous(fly.pattern_harmonics, np.complex128) if n_nuisance else _empty(m, 0)
    grid = _contiguous(grid, np.float64)
    pressure = _contiguous(pressure, np.float64)
    # one node has no node-minus-flywheel motion
    rel_in = _contiguous(rel, np.complex128) if twist and rel is not None else _empty(0, m)
    static_in = _contiguous(static, np.float64) if twist and static is not None else _NO_STATIC
    for _ in range(n_pass):
        (tau, theta_f, omega_f, alpha_f, omega_node, buf, basis_mean, indicated_mean, known, static, rel, node_speed,
         design, target, cyl_rows, mean_row, p_rel, p_gnd) = _balance_pass(
            harmonics, float(fly.omega_mean), float(fly.offset), float(fly.drift), float(fly.period),
            float(theta_start), int(time_samples), rel_in, static_in, grid, pressure, cyl_node, consts, group, prior,
            th, compliance, flywheel, inverse, rec_freq, transfer, pattern, int(n_nuisance), edges, edge_damping,
            ground_damping)
        if twist:
            rel_in, static_in = rel, static
    n_head = buf.shape[0] - 7 * z
    exc = Excitation(tau=tau, theta_fly=theta_f, omega_node=omega_node, gas=buf[n_head + 6 * z:],
                     known_harm=known, basis=buf[n_head: n_head + 6 * z].reshape(z, N_TERMS, time_samples),
                     basis_mean=basis_mean, indicated_mean=indicated_mean, omega_fly=omega_f, alpha_fly=alpha_f)
    rows = CycleRows(design=design, target=target, mean_row=mean_row, mean_target=float("nan"),
                     cylinder_rows=cyl_rows)
    return exc, rows, node_speed, rel, static, (p_rel, p_gnd)


# the last (spec, layout, op, variable_inertia, kernel constants): one monitor's steady state
_LAST: list[tuple] = [(None, None, None, None, None)]


def _constants(spec: EngineSpec, layout: ParameterLayout, op: OperatingPoint, variable_inertia: bool) -> tuple:
    """The kernel arguments that depend on the engine, the parameter layout and the operating point only
    (contiguous arrays), kept for the last (spec, layout, op) seen: those are immutable and the monitor passes the
    same objects cycle after cycle, so the checks and conversions run once per operating point, not per cycle."""
    last = _LAST[0]
    if last[0] is spec and last[1] is layout and last[2] is op and (op.plan is not None or last[3] == variable_inertia):
        return last
    plan = op.plan if op.plan is not None else excitation_plan(spec, op.shaft.recip_inertia_mean, variable_inertia)
    shaft = op.shaft
    rec = op.receptance
    n_nodes = spec.n_nodes
    args = (n_nodes, spec.n_cyl, layout.n_params, n_nodes > 1, np.ascontiguousarray(plan.cyl_node, dtype=np.int64),
            np.ascontiguousarray(plan.consts, dtype=np.float64), np.ascontiguousarray(layout.group, dtype=np.int64),
            np.ascontiguousarray(layout.prior, dtype=np.float64),
            np.ascontiguousarray(shaft.compliance, dtype=np.float64), int(shaft.flywheel),
            np.ascontiguousarray(rec.inverse, dtype=np.complex128), np.ascontiguousarray(rec.freq, dtype=np.float64),
            np.ascontiguousarray(op.transfer, dtype=np.complex128),
            np.ascontiguousarray(shaft.edges, dtype=np.int64).reshape(-1, 2),
            np.ascontiguousarray(shaft.edge_damping, dtype=np.float64),
            np.ascontiguousarray(shaft.ground_damping, dtype=np.float64))
    entry = (spec, layout, op, variable_inertia, args)
    _LAST[0] = entry
    return entry


def _contiguous(a, dtype) -> np.ndarray:
    """``a`` itself when it already is a C-contiguous array of ``dtype`` (the monitor's case), else a copy."""
    if type(a) is np.ndarray and a.dtype == dtype and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=dtype)


_NO_STATIC = np.zeros(0)
_EMPTY: dict[tuple[int, int], np.ndarray] = {}


def _empty(rows: int, cols: int) -> np.ndarray:
    """A zero-size complex array (rows, cols), kept (nothing can be written into it)."""
    out = _EMPTY.get((rows, cols))
    if out is None:
        out = _EMPTY[(rows, cols)] = np.zeros((rows, cols), dtype=np.complex128)
    return out
