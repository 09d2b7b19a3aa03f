"""Step-by-step per-cycle excitation that the monitor no longer runs, kept as test references.

Production (core.monitor.balance_pass_kernel._balance_pass behind core.monitor.harmonic_balance) does one harmonic-balance pass in a
single numba kernel. These are the steps it replaced, moved here unchanged from core/excitation.py,
core/excitation_kernels.py and core/harmonic_balance_kernels.py (same code, so the same numbers):

- ``grid_motion`` (with the kernels ``_grid_spectrum`` and ``_motion_from_series``): flywheel and throw motion on the
  uniform time grid with one inverse FFT.
- ``excitation_rows`` / ``cycle_excitation``: that motion, then core.monitor.harmonic_balance_kernels._cycle_rows and one
  numpy rfft of [G; known node torques] (tests/core/test_balance_pass_kernel.py, test_harmonic_balance_fast.py).
- ``_excitation_rows`` (with ``_sin_cos_near``): the earlier fused excitation kernel, itself tested against
  core.model.torques / core.model.friction (tests/core/test_excitation_kernels.py); ``periodic_interp``: np.interp-style
  pressure at the flywheel angle. Layout of ``consts``: core.monitor.excitation_kernels module docstring.
"""

from __future__ import annotations

import numba
import numpy as np

from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.excitation import Excitation, ExcitationPlan, excitation_plan
from frictionwatch.core.monitor.excitation_kernels import N_CONSTS, OMEGA_SLOT, _interp_rows
from frictionwatch.core.monitor.flywheel import FlywheelMotion
from frictionwatch.core.model.friction import N_TERMS
from frictionwatch.core.monitor.harmonic_balance_kernels import _cycle_rows

FOUR_PI = 4.0 * np.pi


@numba.njit(cache=True)
def _grid_spectrum(harm, freq, rel, n_rel, half, out):
    """out (3 + 3 n_rel, n // 2 + 1) complex, zero: rows angle, speed, acceleration of the flywheel, then of each
    node minus the flywheel (n_rel rows each), harmonics m = 1..M in columns 1..M, scaled by ``half`` = n / 2 for
    the inverse rfft. Same products as the numpy expressions of ``grid_motion`` (harm * half, (i w harm) * half,
    (-w^2 harm) * half)."""
    m = harm.shape[0]
    for j in range(m):
        w = freq[j]
        w2 = -(w * w)
        a = harm[j]
        out[0, j + 1] = a * half
        out[1, j + 1] = complex(-(w * a.imag) * half, (w * a.real) * half)
        out[2, j + 1] = complex((w2 * a.real) * half, (w2 * a.imag) * half)
        for q in range(n_rel):
            b = rel[q, j]
            out[3 + q, j + 1] = b * half
            out[3 + n_rel + q, j + 1] = complex(-(w * b.imag) * half, (w * b.real) * half)
            out[3 + 2 * n_rel + q, j + 1] = complex((w2 * b.real) * half, (w2 * b.imag) * half)


@numba.njit(cache=True)
def _motion_from_series(series, n_rel, offset, drift, period, omega_mean, theta_start, static, tau, theta_f,
                        omega_f, alpha_f, motion):
    """The time-domain part of ``grid_motion`` (same operations in the same order; no fast-math here)."""
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
        for i in range(n):
            if n_rel:
                motion[0, q, i] = theta_f[i] + series[3 + q, i]
                motion[1, q, i] = omega_f[i] + series[3 + n_rel + q, i]
                motion[2, q, i] = alpha_f[i] + series[3 + 2 * n_rel + q, i]
            else:
                motion[0, q, i] = theta_f[i]
                motion[1, q, i] = omega_f[i]
                motion[2, q, i] = alpha_f[i]
    if static.shape[0] == n_nodes:
        for q in range(n_nodes):
            s = static[q]
            for i in range(n):
                motion[0, q, i] += s


@numba.njit(cache=True)
def _sin_cos_near(x, ref, s_ref, c_ref):
    """sin(x), cos(x) for x near ref whose sin/cos are known: the angle-sum rule with the short series of the
    small difference (|d| < 0.05 rad: truncation below 1e-17), else a direct evaluation."""
    d = x - ref
    if abs(d) < 0.05:
        d2 = d * d
        sd = d * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0 * (1.0 - d2 / 42.0 * (1.0 - d2 / 72.0))))
        cd = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0 * (1.0 - d2 / 56.0 * (1.0 - d2 / 90.0))))
        return s_ref * cd + c_ref * sd, c_ref * cd - s_ref * sd
    return np.sin(x), np.cos(x)


@numba.njit(cache=True, fastmath={"reassoc", "nsz"})
def _excitation_rows(motion, theta_fly, p_abs, cyl_node, consts, rows, means):
    """motion (3, N, n): throw angle, speed, acceleration of each node; theta_fly (n,) flywheel angle [rad];
    p_abs (z, n) absolute pressure [Pa]; cyl_node (z,) int node of each cylinder; consts (23 + z,): the layout of
    the module docstring followed by the firing angles [rad].

    Writes rows (N + 7 z, n): [known node torque (N); basis F_kl (z * 6, cylinder-major); gas torque (z)] and
    means (z, 7): work means <F_kl omega_q>/Omega (6) and <T_g,k omega_q>/Omega. (fastmath: reassociation only,
    so that the sums vectorise; every value is within a few ulp of the sequential formulas.)"""
    n_nodes = motion.shape[1]
    n = motion.shape[2]
    z = cyl_node.shape[0]
    r = consts[0]
    rod = consts[1]
    e = consts[2]
    d = consts[3 + 3]
    mu = consts[3 + 4]
    pe = consts[3 + 5]
    eth = consts[3 + 6]
    nc = consts[3 + 7]
    no = consts[3 + 8]
    lfp = consts[3 + 9]
    ga = consts[3 + 10]
    nv = consts[3 + 11]
    ls = consts[3 + 12]
    rb = consts[3 + 13]
    area = consts[17]
    p_cc = consts[18]
    m_rec = consts[19]
    j_rec = consts[20]
    var_inertia = consts[21] != 0.0
    omega_mean = consts[22]
    phases = consts[N_CONSTS:]
    # constant factors of the basis terms, grouped as in core.model.friction._friction_basis
    k0 = np.pi * d * (no + 0.4 * nc)
    k1 = np.pi * d * nc
    k5 = 0.25 * np.pi * d * d * rb
    lo_1 = 0.5 * np.pi
    hi_1 = FOUR_PI - 0.5 * np.pi
    s_fly = np.empty(n)
    c_fly = np.empty(n)
    for i in range(n):
        s_fly[i] = np.sin(theta_fly[i])
        c_fly[i] = np.cos(theta_fly[i])
    # per node: sin/cos of its angle, clipped speed, 1/sqrt(speed), work-mean weight, shared by its cylinders
    s_q = np.empty(n)
    c_q = np.empty(n)
    w_c = np.empty(n)
    rw = np.empty(n)
    w_over = np.empty(n)
    sum_gas = np.empty(n)
    sum_recip = np.empty(n)
    for q in range(n_nodes):
        n_on = 0
        for k in range(z):
            if cyl_node[k] == q:
                n_on += 1
        if n_on == 0:
            for i in range(n):
                rows[q, i] = 0.0
            continue
        for i in range(n):
            s_q[i], c_q[i] = _sin_cos_near(motion[0, q, i], theta_fly[i], s_fly[i], c_fly[i])
            w_node = motion[1, q, i]
            w = max(0.001, w_node)
            w_c[i] = w
            rw[i] = 1.0 / np.sqrt(w)
            w_over[i] = w_node / omega_mean
            sum_gas[i] = 0.0
            sum_recip[i] = 0.0
        for k in range(z):
            if cyl_node[k] != q:
                continue
            ph = phases[k]
            c_ph = np.cos(ph)
            s_ph = np.sin(ph)
            b0 = n_nodes + 6 * k
            g_row = n_nodes + 6 * z + k
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            a3 = 0.0
            a4 = 0.0
            a5 = 0.0
            a6 = 0.0
            for i in range(n):
                loc = motion[0, q, i] - ph
                # sin/cos of the local angle by the angle-difference rule
                st = s_q[i] * c_ph - c_q[i] * s_ph
                ct = c_q[i] * c_ph + s_q[i] * s_ph
                # slider-crank kinematics (core.model.kinematics._kinematics)
                sb = (r * st - e) / rod
                cb = np.sqrt(1.0 - sb * sb)
                tb = sb / cb
                dx = r * st + r * ct * tb
                ddx = r * ct - r * st * tb + r * r * ct * ct / (rod * cb * cb * cb)
                # gas and reciprocating torques (core.model.torques)
                pg = p_abs[k, i] - p_cc
                gas = pg * area * dx
                rows[g_row, i] = gas
                sum_gas[i] += gas
                w_node = motion[1, q, i]
                sum_recip[i] += m_rec * dx * (ddx * w_node * w_node + dx * motion[2, q, i])
                # friction basis (core.model.friction._friction_basis)
                p = max(0.0, pg)
                lever = abs(dx)
                w = w_c[i]
                c = w * lever
                f0 = np.sqrt(mu * c * (pe + p) * eth) * k0 * lever
                th = loc - FOUR_PI * np.floor(loc / FOUR_PI)  # [0, 4 pi); F2 vanishes at its window's edges
                f1 = k1 * (pe + p) * (1.0 - abs(st)) * lever if (th <= lo_1 or th >= hi_1) else 0.0
                f2 = mu * c / ga * np.pi * d * lfp * lever
                f3 = nv * ls * lever * rw[i]
                f4 = mu * w
                f5 = k5 * p * abs(ct) * rw[i]
                rows[b0, i] = f0
                rows[b0 + 1, i] = f1
                rows[b0 + 2, i] = f2
                rows[b0 + 3, i] = f3
                rows[b0 + 4, i] = f4
                rows[b0 + 5, i] = f5
                # work means: <T omega_q> / Omega
                wo = w_over[i]
                a0 += f0 * wo
                a1 += f1 * wo
                a2 += f2 * wo
                a3 += f3 * wo
                a4 += f4 * wo
                a5 += f5 * wo
                a6 += gas * wo
            means[k, 0] = a0 / n
            means[k, 1] = a1 / n
            means[k, 2] = a2 / n
            means[k, 3] = a3 / n
            means[k, 4] = a4 / n
            means[k, 5] = a5 / n
            means[k, 6] = a6 / n
        if var_inertia:
            c_inertia = j_rec * n_on
            for i in range(n):
                rows[q, i] = sum_gas[i] + (c_inertia * motion[2, q, i] - sum_recip[i])
        else:
            for i in range(n):
                rows[q, i] = sum_gas[i]




def cycle_excitation(
    spec: EngineSpec,
    grid: np.ndarray,
    pressure: np.ndarray,
    fly: FlywheelMotion,
    theta_start: float,
    n_time: int,
    recip_inertia_mean: float,
    relative_motion: np.ndarray | None = None,
    static_twist: np.ndarray | None = None,
    variable_inertia: bool = True,
    plan: ExcitationPlan | None = None,
) -> Excitation:
    """Evaluate gas, reciprocating-remainder and friction-basis torques of one cycle.

    Parameters
    ----------
    grid : (n,) uniform crank-angle grid of the pressure [rad, cyl-1 convention], spanning 4 pi
    pressure : (z, n) absolute cylinder pressure [Pa] (finite)
    fly : fitted flywheel motion of the cycle
    theta_start : flywheel angle of the first tooth edge [rad] (the fit's tau = 0)
    n_time : samples per cycle of the time grid
    recip_inertia_mean : m_rec <x'^2> [kg m^2]
    relative_motion : (N, M) complex angle harmonics of node minus flywheel [rad] from the previous iterate, or None
    static_twist : (N,) mean angle of each node minus the flywheel [rad] (the m = 0 part the harmonics lack)
    variable_inertia : False models a crank whose reciprocating inertia is constant (no J(theta), no mass torque)
    plan : ``excitation_plan(spec, recip_inertia_mean, variable_inertia)`` if already at hand (saves its set-up)
    """
    exc, _ = excitation_rows(spec, grid, pressure, fly, theta_start, n_time, recip_inertia_mean, relative_motion,
                             static_twist, variable_inertia, plan)
    return exc


def excitation_rows(spec: EngineSpec, grid: np.ndarray, pressure: np.ndarray, fly: FlywheelMotion,
                    theta_start: float, n_time: int, recip_inertia_mean: float,
                    relative_motion: np.ndarray | None = None, static_twist: np.ndarray | None = None,
                    variable_inertia: bool = True, plan: ExcitationPlan | None = None,
                    mix: tuple[np.ndarray, np.ndarray, int] | None = None) -> tuple[Excitation, np.ndarray]:
    """``cycle_excitation`` and the rfft of the rows [G (n_mix); known node torques (N)] (n_mix + N, n_time//2 + 1).

    mix : (mix_row (z, 6), mix_weight (z, 6), n_mix): which weighted basis terms are summed into the G rows
    (core.monitor.harmonic_balance_kernels._mix_plan); None for no G rows."""
    z = spec.n_cyl
    n_nodes = spec.n_nodes
    m = fly.n_harmonics
    if plan is None:
        plan = excitation_plan(spec, recip_inertia_mean, variable_inertia)
    rel = None
    if relative_motion is not None:
        rel = np.asarray(relative_motion)
        if rel.shape != (n_nodes, m):
            raise ValueError(f"relative_motion must have shape {(n_nodes, m)}, got {rel.shape}")
    tau, theta_f, omega_f, alpha_f, motion = grid_motion(fly, n_time, theta_start, n_nodes, rel, static_twist)
    if mix is None:
        mix_row, mix_weight, n_mix = np.full((z, N_TERMS), -1, dtype=np.int64), np.zeros((z, N_TERMS)), 0
    else:
        mix_row, mix_weight, n_mix = mix
    consts = plan.consts.copy()
    consts[OMEGA_SLOT] = fly.omega_mean
    n_head = n_mix + n_nodes
    buf = np.empty((n_head + 7 * z, n_time))
    means = np.empty((z, 7))
    _cycle_rows(motion, theta_f, np.ascontiguousarray(grid, dtype=np.float64),
                np.ascontiguousarray(pressure, dtype=np.float64), plan.cyl_node, consts, mix_row, mix_weight, n_mix,
                buf, means)
    harm = np.fft.rfft(buf[:n_head], axis=-1)  # one FFT for the G rows and the node torques
    known = harm[n_mix:, 1: m + 1] * (2.0 / n_time)
    exc = Excitation(
        tau=tau,
        theta_fly=theta_f,
        omega_node=motion[1],
        gas=buf[n_head + 6 * z:],
        known_harm=known,
        basis=buf[n_head: n_head + 6 * z].reshape(z, N_TERMS, n_time),
        basis_mean=means[:, :N_TERMS],
        indicated_mean=means[:, N_TERMS],
        omega_fly=omega_f,
        alpha_fly=alpha_f,
    )
    return exc, harm


def grid_motion(fly: FlywheelMotion, n_time: int, theta_start: float, n_nodes: int,
                relative_motion: np.ndarray | None = None, static_twist: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Flywheel and throw motion on the uniform time grid with one inverse FFT (``FlywheelMotion.on_grid`` plus the
    node-minus-flywheel harmonics and static twist).

    Returns tau (n,) [s], theta_fly, omega_fly, alpha_fly (n,) and motion (3, N, n): angle, speed, acceleration of
    every node."""
    m = fly.n_harmonics
    n = n_time
    if 2 * m >= n:
        raise ValueError(f"{m} harmonics need more than {2 * m} samples per cycle, got {n}")
    n_rel = 0 if relative_motion is None else n_nodes
    rel = (np.ascontiguousarray(relative_motion, dtype=np.complex128) if n_rel
           else np.zeros((0, m), dtype=np.complex128))
    spec_rows = np.zeros((3 + 3 * n_rel, n // 2 + 1), dtype=np.complex128)
    _grid_spectrum(np.ascontiguousarray(fly.harmonics, dtype=np.complex128), fly.freq, rel, n_rel, 0.5 * n,
                   spec_rows)
    series = np.fft.irfft(spec_rows, n=n, axis=-1)
    static = np.zeros(0) if static_twist is None else np.ascontiguousarray(static_twist, dtype=np.float64)
    if static.shape not in ((0,), (n_nodes,)):
        raise ValueError(f"static_twist must have shape {(n_nodes,)}, got {static.shape}")
    tau = np.empty(n)
    theta_f = np.empty(n)
    omega_f = np.empty(n)
    alpha_f = np.empty(n)
    motion = np.empty((3, n_nodes, n))
    _motion_from_series(series, n_rel, float(fly.offset), float(fly.drift), float(fly.period), float(fly.omega_mean),
                        float(theta_start), static, tau, theta_f, omega_f, alpha_f, motion)
    return tau, theta_f, omega_f, alpha_f, motion


def periodic_interp(x: np.ndarray, grid: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of rows ``values`` (r, n) given on the uniform 4 pi-periodic ``grid`` (n,) at angles
    ``x`` (m,) [rad], wrapped into the grid's cycle (np.interp's own ``period`` mode sorts on every call)."""
    g0 = float(grid[0])
    xp = np.append(grid - g0, FOUR_PI)
    u = np.mod(np.asarray(x, dtype=np.float64) - g0, FOUR_PI)
    v = np.ascontiguousarray(np.atleast_2d(values), dtype=np.float64)
    out = np.empty((v.shape[0], u.shape[0]))
    _interp_rows(u, xp, v, out)  # np.interp per row, one bracket search per query (core.monitor.excitation_kernels)
    return out
