"""The first half of a harmonic-balance pass (core.monitor.balance.harmonic_balance): the cycle's motion and sample rows.

``pass_samples`` (one numba kernel) forms, from the measured flywheel harmonics and the previous iterate's
node-minus-flywheel motion, every node's angle, speed and acceleration on the uniform time grid (one inverse FFT),
the pressure at the flywheel angle (np.interp's bracket, one walk per cycle), and per cylinder

  - the loss-term sample rows of core.model.terms (angle, sin, cos, x', x'', throw speed, gauge pressure), formed
    once per pass by ``core.model.terms.fill_sample``; the term library's kernels turn them into the basis rows;
  - the gas torque T_g,k = (p - p_cc) A x' and, summed per node, the known torque
    K_q = sum_k [T_g,k - (T_a,k - Jrec_mean alpha_q)], T_a,k = m_rec x'(x'' omega^2 + x' alpha) (physics.md §2-§3,
    §12.3 item 2).

The pressure sample of cylinder k was taken when the *flywheel* encoder read theta_F(t), so p_k(t) = P_k(theta_F(t)),
while its kinematics follow its own throw angle (twist; physics.md §12.3 item 3).

Constants come in named records (``CylinderRecord`` per engine, ``CycleMotion`` per cycle); the result is a
``PassGrid``. The second half (friction rows, FFT, chain) is core.monitor.balance.harmonic_balance.pass_rows.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
import rocket_fft  # noqa: F401  (registers numpy.fft for numba; must be imported before a cached kernel loads)
from frictionwatch.core.model.jit import sincos
from frictionwatch.core.model.terms import N_FIELDS, fill_sample, sample_rows
from frictionwatch.core.model.torques import gas_torque_sample, reciprocating_torque_sample

FOUR_PI = 4.0 * np.pi
_FAST = {"reassoc", "nsz"}  # the loops over samples may be vectorised (reordered sums; no signed zeros)


class CylinderRecord(NamedTuple):
    """What the pass needs of the engine's cylinders (built once per engine; core.monitor.balance.excitation)."""

    n_nodes: int  # N, nodes of the chain
    node: np.ndarray  # (z,) int64 node carrying cylinder k
    cos_phase: np.ndarray  # (z,) cos of its firing angle phi_k
    sin_phase: np.ndarray  # (z,) sin of phi_k
    phase: np.ndarray  # (z,) phi_k [rad]
    crank_radius: float  # R [m]
    inv_rod: float  # 1 / L [1/m]
    pin_offset: float  # e [m]
    area: float  # piston area [m^2]
    p_crankcase: float  # [Pa]
    m_rec: float  # reciprocating mass [kg]
    j_rec: float  # mean reciprocating inertia of one cylinder [kg m^2] (it stays in the mass matrix)
    variable_inertia: bool  # model J(theta) and the mass torque
    friction: np.ndarray  # (N_CONSTS,) EngineSpec.friction_params(): the loss terms' constants


class CycleMotion(NamedTuple):
    """The measured flywheel motion of one cycle (core.monitor.teeth.flywheel.FlywheelMotion) on a time grid."""

    harmonics: np.ndarray  # (M,) complex flywheel angle harmonics
    omega_mean: float  # 4 pi / period [rad/s]
    offset: float  # [rad]
    drift: float  # [rad]
    period: float  # [s]
    theta_start: float  # flywheel angle at tau = 0 [rad]
    n_time: int  # samples per cycle


class PassGrid(NamedTuple):
    """One pass on the time grid (n samples)."""

    tau: np.ndarray  # (n,) s
    theta_fly: np.ndarray  # (n,) flywheel angle [rad]
    omega_fly: np.ndarray  # (n,) [rad/s]
    alpha_fly: np.ndarray  # (n,) [rad/s^2]
    motion: np.ndarray  # (3, N, n) angle, speed, acceleration of every node (NaN rows where no cylinder needs them)
    samples: np.ndarray  # (N_FIELDS, z, n) loss-term sample rows (core.model.terms.FIELDS)
    gas: np.ndarray  # (z, n) gas torque [N m]
    known: np.ndarray  # (N, n) known node torque [N m]


@numba.njit(cache=True)
def motion_frequencies(omega_mean, m):
    """w_j = 0.5 Omega (j + 1), j < M: the cycle's harmonic frequencies [rad/s]."""
    out = np.empty(m)
    for j in range(m):
        out[j] = 0.5 * omega_mean * (j + 1)
    return out


@numba.njit(cache=True)
def _spectrum_rows(cyl_node, n_nodes, n_rel):
    """Row of each series in the inverse FFT: rows 0-2 the flywheel's angle, speed, acceleration deviation; then,
    with relative motion (n_rel = N), node q's speed minus the flywheel's (every node) and, for the nodes that carry
    a cylinder, its angle and acceleration minus the flywheel's. Returns (row_of (3, N), -1 where not needed; rows)."""
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
    """out (rows, n // 2 + 1) complex, zero: the spectra of ``_spectrum_rows`` (angle, i w angle, -w^2 angle)
    scaled by half = n / 2 for the inverse rfft."""
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
def _node_motion(series, row_of, n_rel, cyc, static, tau, theta_f, omega_f, alpha_f, motion):
    """Flywheel motion (fit: mean speed, drift, harmonics) and every node's (flywheel plus relative series, plus
    the static twist); the angle and acceleration of a node without a cylinder are not formed (NaN)."""
    n = series.shape[1]
    n_nodes = motion.shape[1]
    period = cyc.period
    drift = cyc.drift
    dt = period / n
    a0 = 2.0 * drift / (period * period)
    for i in range(n):
        t = i * dt
        u = t / period
        tau[i] = t
        phi = (cyc.offset + drift * u * (u - 1.0)) + series[0, i]
        omega_f[i] = (cyc.omega_mean + drift * (2.0 * u - 1.0) / period) + series[1, i]
        alpha_f[i] = a0 + series[2, i]
        theta_f[i] = (cyc.theta_start + cyc.omega_mean * t) + phi
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


@numba.njit(cache=True, fastmath=_FAST)
def _pressure_brackets(theta_f, grid, jlo, jhi, frac):
    """np.interp bracket of every flywheel angle on the 4 pi-periodic uniform ``grid`` (n_g,): the angle wrapped
    into [0, 4 pi) from grid[0], knots grid - grid[0] closed by 4 pi; samples between knots jlo and jhi (jhi wraps
    to 0) at fraction frac. One forward walk (the angles increase), a bisection where they do not."""
    n_g = grid.shape[0]
    g0 = grid[0]
    j = 0
    for i in range(theta_f.shape[0]):
        x = theta_f[i] - g0
        x -= FOUR_PI * np.floor(x * (1.0 / FOUR_PI))  # x mod 4 pi (a libm fmod costs more than the loop)
        if x < 0.0:
            x += FOUR_PI
        if x >= FOUR_PI or x <= 0.0:  # np.interp: at or beyond the ends, the end values (both are fp[0])
            jlo[i] = 0
            jhi[i] = 0
            frac[i] = 0.0
            continue
        if x < grid[j] - g0:
            lo = 0
            hi = n_g
            while hi - lo > 1:
                mid = (lo + hi) >> 1
                if grid[mid] - g0 <= x:
                    lo = mid
                else:
                    hi = mid
            j = lo
        else:
            while j + 1 < n_g and grid[j + 1] - g0 <= x:
                j += 1
        x_hi = grid[j + 1] - g0 if j + 1 < n_g else FOUR_PI
        x_lo = grid[j] - g0
        jlo[i] = j
        jhi[i] = j + 1 if j + 1 < n_g else 0
        frac[i] = (x - x_lo) / (x_hi - x_lo)


@numba.njit(cache=True, fastmath=_FAST)
def _cylinder_rows(cyl, motion, theta_f, grid, pressure, samples, gas, known):
    """Sample rows, gas torque and known node torque of every cylinder (see the module docstring)."""
    n_nodes = motion.shape[1]
    n = motion.shape[2]
    z = cyl.node.shape[0]
    jlo = np.empty(n, dtype=np.int64)
    jhi = np.empty(n, dtype=np.int64)
    frac = np.empty(n)
    _pressure_brackets(theta_f, grid, jlo, jhi, frac)
    recip = np.empty(n)
    s_q = np.empty(n)
    c_q = np.empty(n)
    r, inv_rod, e = cyl.crank_radius, cyl.inv_rod, cyl.pin_offset
    for q in range(n_nodes):
        row = known[q]
        for i in range(n):
            row[i] = 0.0
            recip[i] = 0.0
        n_on = 0
        for k in range(z):
            if cyl.node[k] == q:
                n_on += 1
        if n_on == 0:
            continue
        ang = motion[0, q]
        w_node = motion[1, q]
        a_node = motion[2, q]
        # libm per node: the former Taylor series of the twist by the addition theorem gave < 20 % end to end
        # (issue 26 item 6); one sincos call a sample (one argument reduction for both: the C library's very sin
        # and cos, tests/core/test_jit.py) costs ~0.6x np.sin and np.cos
        for i in range(n):
            s_q[i], c_q[i] = sincos(ang[i])
        for k in range(z):
            if cyl.node[k] != q:
                continue
            ph, c_ph, s_ph = cyl.phase[k], cyl.cos_phase[k], cyl.sin_phase[k]
            pk = pressure[k]
            rows = sample_rows(samples, k)
            for i in range(n):
                y0 = pk[jlo[i]]
                pg = (y0 + (pk[jhi[i]] - y0) * frac[i]) - cyl.p_crankcase
                st = s_q[i] * c_ph - c_q[i] * s_ph  # sin, cos of the local angle ang - phi_k
                ct = c_q[i] * c_ph + s_q[i] * s_ph
                dx, ddx = fill_sample(rows, i, ang[i] - ph, st, ct, w_node[i], pg, r, inv_rod, e)
                t_gas = gas_torque_sample(pg, cyl.area, dx)
                gas[k, i] = t_gas
                row[i] += t_gas
                recip[i] += reciprocating_torque_sample(cyl.m_rec, dx, ddx, w_node[i], a_node[i])
        if cyl.variable_inertia:
            c_inertia = cyl.j_rec * n_on
            for i in range(n):
                row[i] += c_inertia * a_node[i] - recip[i]


@numba.njit(cache=True)
def pass_samples(cyc, cyl, rel, static, grid, pressure):
    """Motion and sample rows of one pass (module docstring) as a ``PassGrid``.

    cyc: CycleMotion; cyl: CylinderRecord; rel (N, M) complex node-minus-flywheel harmonics of the previous pass or
    cycle, (0, M) for none; static (N,) static twist or (0,); grid (n_g,) the pressure's uniform crank-angle grid
    spanning 4 pi; pressure (z, n_g) [Pa]."""
    m = cyc.harmonics.shape[0]
    n = cyc.n_time
    n_nodes = cyl.n_nodes
    z = cyl.node.shape[0]
    freq = motion_frequencies(cyc.omega_mean, m)
    n_rel = n_nodes if rel.shape[0] == n_nodes else 0
    row_of, n_rows = _spectrum_rows(cyl.node, n_nodes, n_rel)
    spec_rows = np.zeros((n_rows, n // 2 + 1), dtype=np.complex128)
    _motion_spectrum(cyc.harmonics, freq, rel[:n_rel], row_of, 0.5 * n, spec_rows)
    series = np.fft.irfft(spec_rows, n, -1)
    tau = np.empty(n)
    theta_f = np.empty(n)
    omega_f = np.empty(n)
    alpha_f = np.empty(n)
    motion = np.empty((3, n_nodes, n))
    _node_motion(series, row_of, n_rel, cyc, static, tau, theta_f, omega_f, alpha_f, motion)
    samples = np.empty((N_FIELDS, z, n))
    gas = np.empty((z, n))
    known = np.empty((n_nodes, n))
    _cylinder_rows(cyl, motion, theta_f, grid, pressure, samples, gas, known)
    return PassGrid(tau, theta_f, omega_f, alpha_f, motion, samples, gas, known)
