"""One harmonic-balance pass of the monitor (core.monitor.harmonic_balance) as a single numba kernel.

The steps are those of tests/core/excitation_reference.excitation_rows + core.monitor.harmonic_balance_kernels._balance_rows, in the same
order and with the same helpers (``_mix_plan``, ``_cycle_rows``, ``_balance_rows``; the grid motion of
tests/core/excitation_reference.grid_motion with the same products); the two FFTs run inside the kernel through rocket-fft (numpy.fft
for numba, the same pocketfft as numpy: the same transforms). What this saves is call overhead: one dispatch per pass
instead of five kernel dispatches, two numpy FFT calls and ~40 small numpy calls and allocations; and the inverse FFT
forms a node's angle and acceleration only where a cylinder sits (genset-v20: 37 of 45 rows). genset-v20, 256
samples: 0.166 -> 0.10 ms per cycle warm (same inputs), 0.21 -> ~0.16 ms in the monitor.
tests/core/test_balance_pass_kernel.py checks it against the separate steps (1e-13), test_harmonic_balance_fast.py
against the plain-numpy reference.
"""

from __future__ import annotations

import numba
import numpy as np
import rocket_fft  # noqa: F401  (registers numpy.fft for numba; must be imported before a cached kernel loads)

from frictionwatch.core.model.dynamics import _dissipation
from frictionwatch.core.monitor.excitation_kernels import OMEGA_SLOT
from frictionwatch.core.monitor.harmonic_balance_kernels import _balance_rows, _cycle_rows, _mix_plan


@numba.njit(cache=True)
def _spectrum_rows(cyl_node, n_nodes, n_rel):
    """Row of each series in the inverse FFT: rows 0-2 the flywheel's angle, speed, acceleration deviation; then,
    with relative motion (n_rel = N), node q's speed minus the flywheel's (every node: ``Excitation.omega_node``)
    and, for the nodes that carry a cylinder, its angle and acceleration minus the flywheel's (the kinematics need
    those only where a cylinder sits). Returns (row_of (3, N), -1 where not needed; number of rows)."""
    row_of = np.full((3, n_nodes), -1, dtype=np.int64)
    n_rows = 3
    if n_rel == 0:
        return row_of, n_rows
    active = np.zeros(n_nodes, dtype=np.bool_)
    for k in range(cyl_node.shape[0]):
        active[cyl_node[k]] = True
    for q in range(n_nodes):
        row_of[1, q] = n_rows
        n_rows += 1
        if active[q]:
            row_of[0, q] = n_rows
            row_of[2, q] = n_rows + 1
            n_rows += 2
    return row_of, n_rows


@numba.njit(cache=True)
def _motion_spectrum(harm, freq, rel, row_of, half, out):
    """out (rows, n // 2 + 1) complex, zero: the spectra of ``_spectrum_rows`` scaled by half = n / 2 for the
    inverse rfft (the products of tests/core/excitation_reference._grid_spectrum, so the same numbers)."""
    m = harm.shape[0]
    n_rel = rel.shape[0]
    for j in range(m):
        w = freq[j]
        w2 = -(w * w)
        a = harm[j]
        out[0, j + 1] = a * half
        out[1, j + 1] = complex(-(w * a.imag) * half, (w * a.real) * half)
        out[2, j + 1] = complex((w2 * a.real) * half, (w2 * a.imag) * half)
        for q in range(n_rel):
            b = rel[q, j]
            if row_of[0, q] >= 0:
                out[row_of[0, q], j + 1] = b * half
            out[row_of[1, q], j + 1] = complex(-(w * b.imag) * half, (w * b.real) * half)
            if row_of[2, q] >= 0:
                out[row_of[2, q], j + 1] = complex((w2 * b.real) * half, (w2 * b.imag) * half)


@numba.njit(cache=True)
def _node_motion(series, row_of, n_rel, offset, drift, period, omega_mean, theta_start, static, tau, theta_f,
                 omega_f, alpha_f, motion):
    """tests/core/excitation_reference._motion_from_series on the rows of ``_spectrum_rows`` (same operations in
    the same order); the angle and acceleration of a node without a cylinder are not formed (NaN)."""
    n = series.shape[1]
    n_nodes = motion.shape[1]
    dt = period / n
    a0 = 2.0 * drift / (period * period)
    for i in range(n):
        t = i * dt
        u = t / period
        tau[i] = t
        phi = (offset + drift * u * (u - 1.0)) + series[0, i]
        omega_f[i] = (omega_mean + drift * (2.0 * u - 1.0) / period) + series[1, i]
        alpha_f[i] = a0 + series[2, i]
        theta_f[i] = (theta_start + omega_mean * t) + phi
    for q in range(n_nodes):
        for k in range(3):
            row = row_of[k, q]
            base = theta_f if k == 0 else (omega_f if k == 1 else alpha_f)
            if n_rel == 0:
                for i in range(n):
                    motion[k, q, i] = base[i]
            elif row >= 0:
                for i in range(n):
                    motion[k, q, i] = base[i] + series[row, i]
            else:
                for i in range(n):
                    motion[k, q, i] = np.nan
    if static.shape[0] == n_nodes:
        for q in range(n_nodes):
            s = static[q]
            for i in range(n):
                motion[0, q, i] += s


@numba.njit(cache=True)
def _balance_pass(fly_harm, omega_mean, offset, drift, period, theta_start, n_time, rel, static, grid, pressure,
                  cyl_node, plan_consts, group, prior, theta, compliance, flywheel, inverse, rec_freq, transfer,
                  pattern, n_nuisance, edges, edge_damping, ground_damping):
    """One pass: excitation on the time grid, the two FFTs, the chain response, the identification rows and the
    dampers' mean dissipated power (core.model.dynamics._dissipation, while the node speeds are in cache).

    fly_harm (M,) complex flywheel angle harmonics of the cycle's fit, omega_mean = 4 pi / period [rad/s], offset,
    drift [rad], period [s] (core.monitor.flywheel.FlywheelMotion); theta_start [rad]; n_time samples per cycle; rel (N, M)
    node-minus-flywheel harmonics of the previous pass or cycle, (0, M) for none; static (N,) or (0,); grid (n_g,),
    pressure (z, n_g) [Pa]; cyl_node (z,); plan_consts (23 + z,) core.monitor.excitation_kernels layout (its Omega slot is
    replaced by omega_mean); group, prior (z, 6) of the parameter layout; theta (P,) friction parameters;
    compliance (N, N), flywheel node, inverse (M, N, N), rec_freq (M,), transfer (M, N) of the operating point;
    pattern (M, >= n_nuisance) complex tooth-pattern harmonics; edges (E, 2), edge_damping (E,), ground_damping (N,)
    the shaft's dampers (core.model.dynamics.ShaftModel).

    Returns tau, theta_fly, omega_fly, alpha_fly (n,), node speeds (N, n), rows (n_mix + N + 7 z, n) = [G; known;
    basis; gas], basis_mean (z, 6), indicated_mean (z,) (work means), known_harm (N, M), static (N,), rel (N, M), node_speed (N, M), design (M, P + n_nuis),
    target (M,), cylinder_rows (z, P), mean_row (P + n_nuis,), and the mean power [W] dissipated by the relative and
    by the ground dampers (``core.model.dynamics.dissipated_power`` of node_speed)."""
    m = fly_harm.shape[0]
    n = n_time
    n_nodes = compliance.shape[0]
    z = cyl_node.shape[0]
    n_par = theta.shape[0]
    n_terms = group.shape[1]
    # the friction terms' parameter-weighted sums per node (core.monitor.harmonic_balance_kernels._mix_plan)
    mix_row = np.empty((z, n_terms), dtype=np.int64)
    mix_param = np.empty(z * n_terms, dtype=np.int64)
    mix_node = np.empty(z * n_terms, dtype=np.int64)
    n_mix = _mix_plan(group, prior, cyl_node, n_par, n_nodes, mix_row, mix_param, mix_node)
    # motion on the time grid (tests/core/excitation_reference.grid_motion; fly.freq = 0.5 Omega (1..M))
    fly_freq = np.empty(m)
    half_omega = 0.5 * omega_mean
    for j in range(m):
        fly_freq[j] = half_omega * (j + 1)
    n_rel = n_nodes if rel.shape[0] == n_nodes else 0
    row_of, n_rows = _spectrum_rows(cyl_node, n_nodes, n_rel)
    spec_rows = np.zeros((n_rows, n // 2 + 1), dtype=np.complex128)
    _motion_spectrum(fly_harm, fly_freq, rel[:n_rel], row_of, 0.5 * n, spec_rows)
    series = np.fft.irfft(spec_rows, n, -1)
    tau = np.empty(n)
    theta_f = np.empty(n)
    omega_f = np.empty(n)
    alpha_f = np.empty(n)
    motion = np.empty((3, n_nodes, n))
    _node_motion(series, row_of, n_rel, offset, drift, period, omega_mean, theta_start, static, tau, theta_f, omega_f,
                 alpha_f, motion)
    # torques on the grid, one forward FFT of [G; known] (tests/core/excitation_reference.excitation_rows)
    consts = plan_consts.copy()
    consts[OMEGA_SLOT] = omega_mean
    n_head = n_mix + n_nodes
    rows = np.empty((n_head + 7 * z, n))
    means = np.empty((z, 7))
    _cycle_rows(motion, theta_f, grid, pressure, cyl_node, consts, mix_row, prior, n_mix, rows, means)
    harm = np.fft.rfft(rows[:n_head], axis=-1)
    # chain response and identification rows (core.monitor.harmonic_balance_kernels._balance_rows)
    known = np.empty((n_nodes, m), dtype=np.complex128)
    static_out = np.empty(n_nodes)
    phi = np.empty((n_nodes, m), dtype=np.complex128)
    rel_out = np.empty((n_nodes, m), dtype=np.complex128)
    node_speed = np.empty((n_nodes, m), dtype=np.complex128)
    design = np.empty((m, n_par + n_nuisance), dtype=np.complex128)
    target = np.empty(m, dtype=np.complex128)
    cyl_rows = np.empty((z, n_par))
    mean_row = np.empty(n_par + n_nuisance)
    _balance_rows(harm, 2.0 / n, m, n_mix, mix_param, mix_node, theta, group, prior, cyl_node, means, compliance,
                  flywheel, inverse, rec_freq, transfer, fly_freq, fly_harm, pattern, n_nuisance, known, static_out, phi,
                  rel_out, node_speed, design, target, cyl_rows, mean_row)
    # the work means as two C-contiguous blocks (the monitor's kernels read basis_mean in place)
    basis_mean = np.empty((z, n_terms))
    indicated_mean = np.empty(z)
    for k in range(z):
        for t_l in range(n_terms):
            basis_mean[k, t_l] = means[k, t_l]
        indicated_mean[k] = means[k, n_terms]
    power = _dissipation(node_speed, edges, edge_damping, ground_damping)
    return (tau, theta_f, omega_f, alpha_f, motion[1], rows, basis_mean, indicated_mean, known, static_out, rel_out,
            node_speed, design, target, cyl_rows, mean_row, power[0], power[1])
