"""One cycle's harmonic balance through the torsional chain (design.md §4, physics.md §12.3), as the monitor runs it.

``operating_point`` keeps what depends on the engine, the parameter layout (and its term library) and one mean speed
and load: the chain matrices and transfer functions (rebuilt when the operating point moves) and the kernels'
constant records. ``harmonic_balance`` evaluates the cycle's excitation on the measured flywheel motion, passes it
through the chain and returns the speed equations, affine in the friction parameters and the tooth-error
nuisances. The frozen terms (twist, throw speeds, J(theta) remainder) come from the previous cycle's model motion
(warm start, passed in and out by the caller), refreshed once on the first cycle (physics.md §12.3: one refresh is
enough).

A pass is three steps: ``pass_samples`` (core.monitor.balance.harmonic_balance_kernels: motion, pressure, the loss terms'
sample rows, gas and known torques), the term library's kernels (core.model.terms: the basis F_kl of every cylinder,
one call per term), ``pass_rows`` (core.monitor.balance.balance_pass_kernel: mixed friction rows, FFT, chain, equations).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from frictionwatch.core.model.dynamics import Receptance, ShaftModel, receptance, shaft_model
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.balance.balance_pass_kernel import ChainRecord, MixPlan, PassRows, mix_plan, pass_rows
from frictionwatch.core.monitor.balance.excitation import Excitation, cylinder_record
from frictionwatch.core.monitor.balance.harmonic_balance_kernels import CycleMotion, CylinderRecord, pass_samples
from frictionwatch.core.monitor.identify.parameters import CycleRows, ParameterLayout
from frictionwatch.core.monitor.teeth.flywheel import FlywheelMotion


class KnownLoadRipple(NamedTuple):
    """A load torque A sin(order theta_L + phase) [N m] at node ``node`` that the model states (its load_ripple
    effect), resolved for one cycle."""

    node: int
    amplitude: float
    order: float
    phase: float


def known_load_ripple(ripple: tuple[float, float, float, float], load: float, node: int) -> KnownLoadRipple | None:
    """The model's ripple (amplitude [N m], fraction, order, phase [rad]) for a cycle whose mean load torque is
    ``load`` [N m] (NaN: not measured): the amplitude, or where it is 0 the fraction of |load| (the plant's rule); None
    where there is none (a fraction of an unmeasured load is none: nothing says how large it is)."""
    amplitude, fraction, order, phase = ripple
    if amplitude <= 0.0 and fraction > 0.0 and math.isfinite(load):
        amplitude = fraction * abs(load)
    return KnownLoadRipple(int(node), float(amplitude), float(order), float(phase)) if amplitude > 0.0 else None


@dataclass(frozen=True)
class OperatingPoint:
    """Chain matrices and transfer functions at one mean speed and load, and the constant records of the pass
    kernels for one engine and parameter layout (kept in the monitor state)."""

    omega_mean: float
    load_torque: float
    shaft: ShaftModel
    receptance: Receptance
    transfer: np.ndarray  # (M, N) flywheel speed per node torque
    layout: ParameterLayout  # the layout (and term library) the records below were built for
    variable_inertia: bool
    chain: ChainRecord
    cylinders: CylinderRecord
    mix: MixPlan
    load_ripple: KnownLoadRipple | None = None  # the model's known load ripple at this load (None: none)


def operating_point(spec: EngineSpec, op: OperatingPoint | None, omega: float, load: float, m: int,
                    rebuild_tolerance: float, variable_inertia: bool, layout: ParameterLayout,
                    load_ripple: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)) -> OperatingPoint:
    """``op`` itself while Omega is within ``rebuild_tolerance`` (relative), the load within 5 % and the layout,
    inertia model and load ripple the same, else a new one; ``load_ripple``: the model's (MonitorConfig's), resolved
    at this load (``known_load_ripple``: a fraction of the load is sized at the point's load, within its 5 %)."""
    load_ok = math.isfinite(load)
    if op is not None and op.layout is layout and op.variable_inertia == variable_inertia and op.transfer.shape[0] == m \
            and abs(omega / op.omega_mean - 1.0) <= rebuild_tolerance and (
            not load_ok or abs(load - op.load_torque) <= 0.05 * max(abs(op.load_torque), 1e-9)) \
            and op.load_ripple == known_load_ripple(load_ripple, op.load_torque, spec.load_node):
        return op
    shaft = shaft_model(spec, load if load_ok else 0.0, omega)
    rec = receptance(shaft, omega, m)
    transfer = np.ascontiguousarray(rec.speed_transfer(shaft.flywheel), dtype=np.complex128)
    chain = ChainRecord(np.ascontiguousarray(shaft.train.stiffness, dtype=np.float64), int(shaft.flywheel),
                        np.ascontiguousarray(rec.inverse, dtype=np.complex128),
                        np.ascontiguousarray(rec.freq, dtype=np.float64), transfer,
                        np.ascontiguousarray(shaft.edges, dtype=np.int64).reshape(-1, 2),
                        np.ascontiguousarray(shaft.edge_damping, dtype=np.float64),
                        np.ascontiguousarray(shaft.ground_damping, dtype=np.float64))
    return OperatingPoint(omega, load if load_ok else 0.0, shaft, rec, transfer, layout, bool(variable_inertia), chain,
                          cylinder_record(spec, shaft.recip_inertia_mean, variable_inertia),
                          mix_plan(layout.group, layout.prior, spec.cylinder_node, layout.n_params),
                          known_load_ripple(load_ripple, load, spec.load_node))


@dataclass(frozen=True)
class BalanceResult:
    """One cycle's harmonic balance: the last pass's excitation and rows, the node speed harmonics (N, M), the
    node-minus-flywheel motion for the next cycle's warm start (harmonics (N, M) and static twist (N,)), and the
    mean power [W] the relative and the ground dampers dissipate; with a second wheel its speed equations
    ``free_rows`` = (design (M, P + n_nuisance) complex, target (M,) complex: measured - modelled free-end speed
    harmonics, the flywheel's tooth nuisances not in them), else None."""

    excitation: Excitation
    rows: CycleRows
    node_speed: np.ndarray
    relative_motion: np.ndarray
    static: np.ndarray
    power_relative: float
    power_ground: float
    free_rows: tuple[np.ndarray, np.ndarray] | None = None


def subtract_load_ripple(known: np.ndarray, theta_fly: np.ndarray, static: np.ndarray, ripple: KnownLoadRipple) -> None:
    """known[node] -= A sin(order theta_L + phase) in place: the load torque opposes the driving torques; theta_L is
    the flywheel angle plus the load node's static twist against it (the previous iterate's; none on a rigid crank or
    the first pass: a twist of a few tenths of a degree moves a half-order ripple's phase by less)."""
    twist = float(static[ripple.node]) if static.shape[0] > ripple.node else 0.0
    known[ripple.node] -= ripple.amplitude * np.sin(ripple.order * (theta_fly + twist) + ripple.phase)


def harmonic_balance(op: OperatingPoint, theta: np.ndarray, n_nuisance: int, relative_motion: np.ndarray | None,
                     static: np.ndarray | None, grid: np.ndarray, pressure: np.ndarray, fly: FlywheelMotion,
                     theta_start: float, passes: int, time_samples: int,
                     free_end: tuple[np.ndarray, np.ndarray] | None = None) -> BalanceResult:
    """Passes of excitation + chain response at the current parameters ``theta`` (friction first, then the
    ``n_nuisance`` tooth-error nuisances); ``relative_motion`` (N, M) and ``static`` (N,) are the previous cycle's
    node-minus-flywheel motion (None on the first cycle); grid (n_g,) and pressure (z, n_g) the cycle's pressure on
    its crank-angle grid [Pa]; fly the flywheel fit; theta_start the flywheel angle at its first sample [rad].
    free_end: a second wheel's (transfer (M, N) complex: its node's speed per node torque, harmonics (M,) complex
    [rad]: its measured angle harmonics referred to the flywheel window's first edge): its speed equations from the
    last pass's excitation, the same chain and parameters (one more ``pass_rows``). A load torque the model states
    (``op.load_ripple``) is taken off the load node's known torque every pass."""
    cyl = op.cylinders
    library = op.layout.library
    n_nodes = cyl.n_nodes
    n_par = op.layout.n_params
    m = fly.harmonics.shape[0]
    if 2 * m >= time_samples:
        raise ValueError(f"{m} harmonics need more than {2 * m} samples per cycle, got {time_samples}")
    twist = n_nodes > 1  # one node has no node-minus-flywheel motion
    warm = relative_motion is not None and relative_motion.shape == (n_nodes, m) and static is not None \
        and static.shape == (n_nodes,)
    # warm start: with the previous cycle's node motion the first pass already is a refresh (physics.md §12.3)
    n_pass = max(1, passes - 1) if warm else max(1, passes)
    # the flywheel fit, the previous motion and the parameters are kernel outputs (C-contiguous; another layout
    # would only be another specialisation): no per-call copies; the cycle's grid and pressure are checked by the
    # monitor (checked_pressure)
    rel_in = relative_motion if twist and warm else np.zeros((0, m), dtype=np.complex128)
    static_in = static if twist and warm else np.zeros(0)
    harmonics = fly.harmonics
    omega_mean = float(fly.omega_mean)
    cyc = CycleMotion(harmonics, omega_mean, float(fly.offset), float(fly.drift), float(fly.period),
                      float(theta_start), int(time_samples))
    pattern = fly.pattern_harmonics if n_nuisance else np.zeros((m, 0), np.complex128)
    params = theta[:n_par]
    grid = _contiguous(grid, np.float64)
    pressure = _contiguous(pressure, np.float64)
    z = cyl.node.shape[0]
    basis = np.empty((len(library), z, int(time_samples)))  # term-major: each term's kernel fills one block
    for _ in range(n_pass):
        on_grid = pass_samples(cyc, cyl, rel_in, static_in, grid, pressure)
        if op.load_ripple is not None:
            subtract_load_ripple(on_grid.known, on_grid.theta_fly, static_in, op.load_ripple)
        library.evaluate_into(on_grid.samples, cyl.friction, basis)
        out: PassRows = pass_rows(harmonics, omega_mean, on_grid.known, on_grid.motion, on_grid.gas, basis, op.mix,
                                  op.chain, params, pattern, int(n_nuisance))
        if twist:
            rel_in, static_in = out.relative_motion, out.static
    exc = Excitation(tau=on_grid.tau, theta_fly=on_grid.theta_fly, omega_node=on_grid.motion[1],
                           gas=on_grid.gas, known_harm=out.known_harm, basis=basis.transpose(1, 0, 2), basis_mean=out.basis_mean,
                           indicated_mean=out.indicated_mean, omega_fly=on_grid.omega_fly,
                           alpha_fly=on_grid.alpha_fly)
    rows = CycleRows(design=out.design, target=out.target, mean_row=out.mean_row, mean_target=float("nan"),
                      cylinder_rows=out.cylinder_rows)
    free_rows = None
    if free_end is not None:  # the same torques through the chain to the second wheel's node; no flywheel nuisance
        transfer2, harmonics2 = free_end
        chain2 = op.chain._replace(transfer=np.ascontiguousarray(transfer2, dtype=np.complex128))
        out2 = pass_rows(np.ascontiguousarray(harmonics2, dtype=np.complex128), omega_mean, on_grid.known,
                         on_grid.motion, on_grid.gas, basis, op.mix, chain2, params,
                         np.zeros((m, int(n_nuisance)), np.complex128), int(n_nuisance))
        free_rows = (out2.design, out2.target)
    return BalanceResult(exc, rows, out.node_speed, out.relative_motion, out.static, out.power_relative,
                         out.power_ground, free_rows)



def _contiguous(a, dtype) -> np.ndarray:
    """``a`` itself when it already is a C-contiguous array of ``dtype`` (the monitor's case), else a copy."""
    if type(a) is np.ndarray and a.dtype == dtype and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=dtype)
