"""The second half of a harmonic-balance pass (core.monitor.balance.harmonic_balance): friction rows, FFT, chain, equations.

``pass_rows`` (one numba kernel) takes the pass's time-grid rows (core.monitor.balance.harmonic_balance_kernels.PassGrid) and
the basis F_kl(t) the term library wrote (L, z, n), and forms

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

from typing import NamedTuple

import numba
import numpy as np
import rocket_fft  # noqa: F401  (registers numpy.fft for numba; must be imported before a cached kernel loads)
from frictionwatch.core.model.chain import static_twist_kernel
from frictionwatch.core.model.dynamics import dissipation_kernel
from frictionwatch.core.monitor.balance.harmonic_balance_kernels import motion_frequencies

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
