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
one call per term), ``pass_rows`` (below: mixed friction rows, FFT, chain, equations).

The pass's second half: ``pass_rows`` (one numba kernel, first in this file) takes the pass's time-grid rows
(core.monitor.balance.harmonic_balance_kernels.PassGrid) and the basis F_kl(t) the term library wrote (L, z, n), and
forms

1. the *mixed* rows G_pq(t) = sum_{(k,l) in group p, node(k) = q} a0_kl F_kl(t): the balance only needs the
   harmonics of those (linearity of the FFT), so one forward FFT covers n_mix + N rows instead of N + L z
   (``MixPlan``, built once per parameter layout by ``mix_plan``);
2. the work means <F_kl omega_q>/Omega and <T_g,k omega_q>/Omega (they close the energy balance, physics.md §12.3);
3. the static twist under the mean node torques (harmonic 0), the chain response Z_m^-1 T_m at the current
   parameters, the speed equations W_meas - W0 and their columns -sum_q H_m,q Ghat_pq,m, the tooth-pattern columns,
   the cylinder rows (ParameterLayout.cylinder_rows) and the dampers' mean dissipated power (physics.md §12.4).

The constants come in named records: ``ChainRecord`` (per operating point), ``MixPlan`` (per layout); the cycle's
values come as arrays; the result is a ``PassRows``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numba
import numpy as np
import rocket_fft  # noqa: F401  (registers numpy.fft for numba; must be imported before a cached kernel loads)
from frictionwatch.core.model.chain import static_twist_kernel
from frictionwatch.core.model.dynamics import (
    Receptance,
    ShaftModel,
    dissipation_kernel,
    free_modes,
    receptance,
    shaft_model,
)
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.balance.excitation import Excitation, cylinder_record
from frictionwatch.core.monitor.balance.harmonic_balance_kernels import (
    CycleMotion,
    CylinderRecord,
    motion_frequencies,
    pass_samples,
)
from frictionwatch.core.monitor.identify.parameters import CycleRows, ParameterLayout
from frictionwatch.core.monitor.teeth.flywheel import FlywheelMotion

_FAST = {"reassoc", "nsz"}  # the sums over samples may be vectorised (reordered; no signed zeros)


class ChainRecord(NamedTuple):
    """The drive train at one operating point (core.model.chain, core.model.dynamics.ShaftModel, Receptance)."""

    sections: np.ndarray  # (N-1,) section stiffness [N m/rad] (static twist, core.model.chain)
    flywheel: int  # node the encoder measures
    inverse: np.ndarray  # (M, N, N) complex Z_m^-1
    freq: np.ndarray  # (M,) w_m [rad/s] of the receptance
    transfer: np.ndarray  # (M, N) complex flywheel speed per node torque
    edges: np.ndarray  # (E, 2) int64 node pairs joined by a relative damper
    edge_damping: np.ndarray  # (E,) [N m s/rad]
    ground_damping: np.ndarray  # (N,) [N m s/rad]


class MixPlan(NamedTuple):
    """Which weighted basis rows go into which G row (``mix_plan``)."""

    group: np.ndarray  # (z, L) int64 parameter of term (k, l) (ParameterLayout.group)
    weight: np.ndarray  # (z, L) its prior a0_kl (ParameterLayout.prior)
    row: np.ndarray  # (z, L) int64 row of G it goes into, -1 for none (zero prior)
    param: np.ndarray  # (n_mix,) int64 parameter of each G row (-1: a term outside every group)
    node: np.ndarray  # (n_mix,) int64 node of each G row
    cyl_node: np.ndarray  # (z,) int64 node carrying cylinder k


class PassRows(NamedTuple):
    """Results of one pass (shapes: z cylinders, L terms, N nodes, M harmonics, P parameters)."""

    basis_mean: np.ndarray  # (z, L) work means <F_kl omega_q>/Omega
    indicated_mean: np.ndarray  # (z,) work means of the gas torques [N m]
    known_harm: np.ndarray  # (N, M) complex harmonics of the known node torques [N m]
    static: np.ndarray  # (N,) static twist, node minus flywheel [rad]
    relative_motion: np.ndarray  # (N, M) complex node-minus-flywheel angle harmonics [rad]
    node_speed: np.ndarray  # (N, M) complex node speed harmonics [rad/s]
    design: np.ndarray  # (M, P + n_nuisance) complex d W / d theta
    target: np.ndarray  # (M,) complex W_meas - W0
    cylinder_rows: np.ndarray  # (z, P) d(mean friction of cylinder k) / d theta
    mean_row: np.ndarray  # (P + n_nuisance,)
    power_relative: float  # mean power of the relative dampers [W]
    power_ground: float  # mean power of the ground dampers [W]


def mix_plan(group: np.ndarray, prior: np.ndarray, cyl_node: np.ndarray, n_params: int) -> MixPlan:
    """One G row per (parameter, node) pair that carries a coefficient; a zero prior adds nothing (row -1); a term
    outside every group (group -1) still enters the node torque through theta[-1], as ParameterLayout.coefficients
    has it, but gets no design column."""
    z, n_terms = group.shape
    table: dict[tuple[int, int], int] = {}
    row = np.full((z, n_terms), -1, dtype=np.int64)
    param: list[int] = []
    node: list[int] = []
    for k in range(z):
        for t_l in range(n_terms):
            if prior[k, t_l] == 0.0:
                continue
            key = (int(group[k, t_l]), int(cyl_node[k]))
            if key not in table:
                table[key] = len(param)
                param.append(key[0])
                node.append(key[1])
            row[k, t_l] = table[key]
    return MixPlan(np.ascontiguousarray(group, dtype=np.int64), np.ascontiguousarray(prior, dtype=np.float64), row,
                   np.array(param, dtype=np.int64), np.array(node, dtype=np.int64),
                   np.ascontiguousarray(cyl_node, dtype=np.int64))


@numba.njit(cache=True, fastmath=_FAST)
def _mixed_rows_and_means(known, motion, gas_rows, basis, mix, node, omega_mean, rows, basis_mean, indicated_mean):
    """rows[:n_mix] = G, rows[n_mix:] = known node torques; the work means of the basis and gas rows."""
    n_terms, z, n = basis.shape
    n_mix = mix.param.shape[0]
    for g in range(n_mix):
        for i in range(n):
            rows[g, i] = 0.0
    for q in range(known.shape[0]):
        for i in range(n):
            rows[n_mix + q, i] = known[q, i]
    w_over = np.empty(n)
    inv_n = 1.0 / n
    for k in range(z):
        w_node = motion[1, node[k]]
        for i in range(n):
            w_over[i] = w_node[i] / omega_mean
        for t_l in range(n_terms):
            src = basis[t_l, k]
            g = mix.row[k, t_l]
            if g >= 0:
                wt = mix.weight[k, t_l]
                dst = rows[g]
                for i in range(n):
                    dst[i] += wt * src[i]
            acc = 0.0
            for i in range(n):
                acc += src[i] * w_over[i]
            basis_mean[k, t_l] = acc * inv_n
        acc = 0.0
        gas = gas_rows[k]
        for i in range(n):
            acc += gas[i] * w_over[i]
        indicated_mean[k] = acc * inv_n


@numba.njit(cache=True)
def _static_twist(chain, mix, node, theta, basis_mean, indicated_mean, static):
    """Mean angle of every node minus the flywheel under the mean node torques at theta (the drive train's
    static_twist_kernel)."""
    z, n_terms = basis_mean.shape
    t = np.zeros(static.shape[0])
    for k in range(z):
        s = 0.0
        for t_l in range(n_terms):
            s += (mix.weight[k, t_l] * theta[mix.group[k, t_l]]) * basis_mean[k, t_l]
        t[node[k]] += indicated_mean[k] - s
    static_twist_kernel(t, chain.sections, chain.flywheel, static)


@numba.njit(cache=True)
def pass_rows(harmonics, omega_mean, known_rows, motion, gas, basis, mix, chain, theta, pattern, n_nuis):
    """Friction rows, FFT, chain response and speed equations of one pass (module docstring) as a ``PassRows``.

    harmonics (M,) complex and omega_mean: the flywheel fit (CycleMotion); known_rows (N, n), motion (3, N, n), gas
    (z, n): the pass's time-grid rows (PassGrid from core.monitor.balance.harmonic_balance_kernels.pass_samples); basis
    (L, z, n) the library's F_kl on the grid; mix: MixPlan; chain: ChainRecord (both built once per operating
    point); theta (P,) the friction parameters; pattern (M, >= n_nuis) complex the fitted tooth-pattern harmonics
    of the n_nuis nuisances. (Per-cycle values come as arrays, not records: a record costs ~5 us per call.)"""
    n_params = theta.shape[0]
    n_terms, z, n = basis.shape
    n_nodes = known_rows.shape[0]
    m = harmonics.shape[0]
    n_mix = mix.param.shape[0]
    node = mix.cyl_node
    rows = np.empty((n_mix + n_nodes, n))
    basis_mean = np.empty((z, n_terms))
    indicated_mean = np.empty(z)
    _mixed_rows_and_means(known_rows, motion, gas, basis, mix, node, omega_mean, rows, basis_mean, indicated_mean)
    harm = np.fft.rfft(rows, axis=-1)
    scale = 2.0 / n
    known = np.empty((n_nodes, m), dtype=np.complex128)
    for q in range(n_nodes):
        for j in range(m):
            known[q, j] = harm[n_mix + q, j + 1] * scale
    static = np.empty(n_nodes)
    _static_twist(chain, mix, node, theta, basis_mean, indicated_mean, static)
    # harmonic node torques at theta, chain response
    torque = known.copy()
    for g in range(n_mix):
        p = mix.param[g]
        th = theta[p] if p >= 0 else theta[n_params - 1]
        q = mix.node[g]
        for j in range(m):
            torque[q, j] -= th * (harm[g, j + 1] * scale)
    phi = np.empty((n_nodes, m), dtype=np.complex128)
    rel = np.empty((n_nodes, m), dtype=np.complex128)
    node_speed = np.empty((n_nodes, m), dtype=np.complex128)
    fly = chain.flywheel
    for j in range(m):
        w = chain.freq[j]
        for i in range(n_nodes):
            acc = 0j
            for q in range(n_nodes):
                acc += chain.inverse[j, i, q] * torque[q, j]
            phi[i, j] = acc
            node_speed[i, j] = complex(-(w * acc.imag), w * acc.real)
        for i in range(n_nodes):
            rel[i, j] = phi[i, j] - phi[fly, j]
    # speed equations: W_meas - W0 and the columns d W / d theta
    fly_freq = motion_frequencies(omega_mean, m)
    design = np.zeros((m, n_params + n_nuis), dtype=np.complex128)
    target = np.empty(m, dtype=np.complex128)
    for j in range(m):
        w0 = 0j
        for q in range(n_nodes):
            w0 += chain.transfer[j, q] * known[q, j]
        w = fly_freq[j]
        a = harmonics[j]
        target[j] = complex(-(w * a.imag), w * a.real) - w0
        for g in range(n_mix):
            p = mix.param[g]
            if p >= 0:
                design[j, p] -= chain.transfer[j, mix.node[g]] * (harm[g, j + 1] * scale)
        for c in range(n_nuis):
            b = pattern[j, c]
            design[j, n_params + c] = complex(-(w * b.imag), w * b.real)
    # mean-balance rows (ParameterLayout.cylinder_rows)
    cyl_rows = np.zeros((z, n_params))
    mean_row = np.zeros(n_params + n_nuis)
    for k in range(z):
        for t_l in range(n_terms):
            p = mix.group[k, t_l]
            if p >= 0:
                cyl_rows[k, p] += mix.weight[k, t_l] * basis_mean[k, t_l]
        for p in range(n_params):
            mean_row[p] += cyl_rows[k, p]
    p_rel, p_gnd = dissipation_kernel(node_speed, chain.edges, chain.edge_damping, chain.ground_damping)
    return PassRows(basis_mean, indicated_mean, known, static, rel, node_speed, design, target, cyl_rows, mean_row,
                    p_rel, p_gnd)


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

    @cached_property
    def modes(self) -> np.ndarray:
        """The chain's free-vibration eigenvalues (core.model.dynamics.free_modes), formed when first asked."""
        return free_modes(self.shaft)


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
    basis = np.empty((op.layout.n_terms, z, int(time_samples)))  # term-major: each term's kernel fills one block
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
