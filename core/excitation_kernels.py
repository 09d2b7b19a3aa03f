"""Fused numba kernels of the per-cycle excitation (core.excitation) and of periodic row interpolation.

One pass over (cylinder, time sample) evaluates the slider-crank kinematics once and from it the gas torque, the
reciprocating remainder and the six friction basis terms (core.torques, core.friction: the same formulas, paper 000
Eq. 4, physics.md §2-§3, §7, §12.3), writing into preallocated rows that go to one FFT. The plain-numpy references
are the public functions of core.torques / core.friction (tests/core/test_excitation_kernels.py).

``_excitation_rows`` is no longer on the monitor's path: core.harmonic_balance_kernels._cycle_rows replaced it
(same formulas, vectorised, pressure interpolation folded in); it stays as the tested reference of that kernel
(tests/core/test_harmonic_balance_fast.py).

Layout of ``consts`` (``excitation_consts``):
  0-2 kinematics [R, L, e]; 3-16 friction params (EngineSpec.friction_params()); 17 piston area [m^2];
  18 crankcase pressure [Pa]; 19 reciprocating mass [kg]; 20 mean reciprocating inertia of one cylinder [kg m^2];
  21 variable inertia (1.0) or not (0.0); 22 mean speed Omega [rad/s] (work means); 23.. firing angles [rad]
"""

from __future__ import annotations

import numba
import numpy as np

FOUR_PI = 4.0 * np.pi
N_CONSTS = 23
OMEGA_SLOT = 22


def excitation_consts(kin: np.ndarray, fric: np.ndarray, area: float, p_cc: float, m_rec: float,
                      recip_inertia_mean: float, variable_inertia: bool, omega_mean: float,
                      phases: np.ndarray) -> np.ndarray:
    """Bundle the constants of ``_excitation_rows`` (layout in the module docstring)."""
    ph = np.asarray(phases, dtype=np.float64).ravel()
    out = np.empty(N_CONSTS + ph.shape[0])
    out[0:3] = kin
    out[3:17] = fric
    out[17:N_CONSTS] = (area, p_cc, m_rec, recip_inertia_mean, 1.0 if variable_inertia else 0.0, omega_mean)
    out[N_CONSTS:] = ph
    return out


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
    # constant factors of the basis terms, grouped as in core.friction._friction_basis
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
                # slider-crank kinematics (core.kinematics._kinematics)
                sb = (r * st - e) / rod
                cb = np.sqrt(1.0 - sb * sb)
                tb = sb / cb
                dx = r * st + r * ct * tb
                ddx = r * ct - r * st * tb + r * r * ct * ct / (rod * cb * cb * cb)
                # gas and reciprocating torques (core.torques)
                pg = p_abs[k, i] - p_cc
                gas = pg * area * dx
                rows[g_row, i] = gas
                sum_gas[i] += gas
                w_node = motion[1, q, i]
                sum_recip[i] += m_rec * dx * (ddx * w_node * w_node + dx * motion[2, q, i])
                # friction basis (core.friction._friction_basis)
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


@numba.njit(cache=True)
def _interp_rows(xq, xp, fp, out):
    """np.interp of every row of fp (r, n) at xq (m,), with xp (n + 1,) increasing and fp's value at xp[n] equal to
    its first column (one period closed). The bracket is searched once per query and used for all rows; the
    arithmetic is np.interp's: slope (fp[j+1] - fp[j]) / (xp[j+1] - xp[j]) times (x - xp[j]) plus fp[j]."""
    n = xp.shape[0] - 1
    rows = fp.shape[0]
    for i in range(xq.shape[0]):
        x = xq[i]
        if x >= xp[n]:
            for k in range(rows):
                out[k, i] = fp[k, 0]
            continue
        if x <= xp[0]:
            for k in range(rows):
                out[k, i] = fp[k, 0]
            continue
        lo = 0
        hi = n
        while hi - lo > 1:  # xp[lo] <= x < xp[hi]
            mid = (lo + hi) >> 1
            if xp[mid] <= x:
                lo = mid
            else:
                hi = mid
        j = lo
        if x == xp[j]:
            for k in range(rows):
                out[k, i] = fp[k, j]
            continue
        dxp = xp[j + 1] - xp[j]
        for k in range(rows):
            y0 = fp[k, j]
            y1 = fp[k, j + 1] if j + 1 < n else fp[k, 0]
            out[k, i] = (y1 - y0) / dxp * (x - xp[j]) + y0


def interp_rows_periodic(xq: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """Rows fp (r, n), sampled at xp (n + 1,) increasing with fp[:, 0] repeated at xp[n], at queries xq (m,).

    Same numbers as ``np.interp(xq, xp, np.append(row, row[0]))`` for each row."""
    q = np.ascontiguousarray(xq, dtype=np.float64)
    x = np.ascontiguousarray(xp, dtype=np.float64)
    f = np.ascontiguousarray(np.atleast_2d(fp), dtype=np.float64)
    if x.ndim != 1 or f.shape[1] + 1 != x.shape[0] or f.shape[1] < 1:
        raise ValueError(f"xp must have one point more than the rows of fp, got {x.shape} and {f.shape}")
    if np.any(np.diff(x) <= 0):
        raise ValueError("xp must be strictly increasing")
    out = np.empty((f.shape[0], q.shape[0]))
    _interp_rows(q, x, f, out)
    return out
