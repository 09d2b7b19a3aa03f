"""Numba kernels of one harmonic-balance pass (core.monitor.harmonic_balance, core.monitor.excitation), run inside the one-kernel
pass core.monitor.balance_pass_kernel._balance_pass (which does the grid motion and the two FFTs itself):

1. ``_cycle_rows``: from the motion on the time grid, the pressure at the flywheel angle (np.interp's bracket, one
   walk per cycle, ``_pressure_brackets``), and per (cylinder, sample) the gas torque, reciprocating remainder, six
   friction basis terms (the formulas of core.model.torques, core.model.friction; paper 000 Eq. 4, physics.md §2-§3, §7, §12.3)
   and their work means. Besides the known node torques it writes *mixed* rows
   G_pq(t) = sum_{(k,l) in group p, node(k) = q} a0_kl F_kl(t): the harmonic balance only needs the harmonics of
   those (linearity of the FFT), so one forward FFT covers ~60 rows instead of N + 6 z.
2. ``_mix_plan``: which weighted basis terms go into which G row (once per parameter layout).
3. ``_balance_rows``: from the harmonics, the node torques at the current parameters, the chain response
   Z_m^-1 T_m, the static twist, the friction design columns -sum_q H_m,q Ghat_pq,m, W0, the cylinder rows.

The grid-motion kernels that ran before the forward FFT (``_grid_spectrum``, ``_motion_from_series``) and the earlier
fused excitation kernel (``_excitation_rows``) are test references now: tests/core/excitation_reference.py.

Rounding: the kinematics multiply by 1/L, 1/cos(beta) and 1/(4 pi) where the old kernel divided, the pressure
interpolation uses (x - x_j)/(x_j+1 - x_j) as one factor, and the friction harmonics are sums of FFTs taken in the
time domain; every value agrees with the previous implementation to ~1e-14 relative
(tests/core/test_harmonic_balance_fast.py).
"""

from __future__ import annotations

import numba
import numpy as np

from frictionwatch.core.monitor.excitation_kernels import N_CONSTS

FOUR_PI = 4.0 * np.pi
_FAST = {"reassoc", "nsz"}


@numba.njit(cache=True, fastmath=_FAST, error_model="numpy")
def _pressure_brackets(theta_f, grid, jlo, jhi, frac):
    """np.interp bracket of every flywheel angle on the 4 pi-periodic uniform ``grid`` (n_g,): the angle wrapped
    into [0, 4 pi) from grid[0], knots grid - grid[0] closed by 4 pi; samples between knots jlo and jhi (jhi wraps
    to 0) at fraction frac. One forward walk (the angles increase), a bisection where they do not."""
    n_g = grid.shape[0]
    g0 = grid[0]
    n = theta_f.shape[0]
    j = 0
    inv_4pi = 1.0 / FOUR_PI
    for i in range(n):
        x = theta_f[i] - g0
        x -= FOUR_PI * np.floor(x * inv_4pi)  # x mod 4 pi (a libm fmod costs more than the rest of the loop)
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


@numba.njit(cache=True, fastmath=_FAST, error_model="numpy")
def _sin_cos_twisted(ang, theta_f, s_fly, c_fly, s_out, c_out):
    """sin, cos of a node's angle from those of the flywheel angle: ``_sin_cos_near``
    (tests/core/excitation_reference.py) with the series' divisions by constants as products (so that the loop
    vectorises), then the direct evaluation wherever the twist is 0.05 rad or more."""
    for i in range(ang.shape[0]):
        d = ang[i] - theta_f[i]
        d2 = d * d
        sd = d * (1.0 - d2 * (1.0 / 6.0) * (1.0 - d2 * (1.0 / 20.0) * (1.0 - d2 * (1.0 / 42.0)
                                                                        * (1.0 - d2 * (1.0 / 72.0)))))
        cd = 1.0 - d2 * 0.5 * (1.0 - d2 * (1.0 / 12.0) * (1.0 - d2 * (1.0 / 30.0) * (1.0 - d2 * (1.0 / 56.0)
                                                                                    * (1.0 - d2 * (1.0 / 90.0)))))
        s_out[i] = s_fly[i] * cd + c_fly[i] * sd
        c_out[i] = c_fly[i] * cd - s_fly[i] * sd
    for i in range(ang.shape[0]):
        if not abs(ang[i] - theta_f[i]) < 0.05:
            s_out[i] = np.sin(ang[i])
            c_out[i] = np.cos(ang[i])


@numba.njit(cache=True, fastmath=_FAST, error_model="numpy")
def _cylinder_samples(r, inv_rod, e, area, p_cc, m_rec, k0, mu_eth, k1, c_f2, c_f3, mu, k5, pe, lo_1, hi_1, ph, c_ph, s_ph,
                      ang, s_q, c_q, w_node, a_node, w_c, rw, p_row, gas_row, b0, b1, b2, b3, b4, b5, sum_gas,
                      sum_recip):
    """One cylinder over all samples: gas torque, reciprocating torque (into the node sums) and the six basis
    rows. Loop body of the earlier ``_excitation_rows`` (tests/core/excitation_reference.py) with the divisions
    by L and cos(beta) as products."""
    inv_4pi = 1.0 / FOUR_PI
    for i in range(ang.shape[0]):
        st = s_q[i] * c_ph - c_q[i] * s_ph
        ct = c_q[i] * c_ph + s_q[i] * s_ph
        sb = (r * st - e) * inv_rod
        cb = np.sqrt(1.0 - sb * sb)
        icb = 1.0 / cb
        tb = sb * icb
        dx = r * st + r * ct * tb
        ddx = r * ct - r * st * tb + r * r * ct * ct * inv_rod * (icb * icb * icb)
        pg = p_row[i] - p_cc
        gas = pg * area * dx
        gas_row[i] = gas
        sum_gas[i] += gas
        w_n = w_node[i]
        sum_recip[i] += m_rec * dx * (ddx * w_n * w_n + dx * a_node[i])
        p = max(0.0, pg)
        lever = abs(dx)
        w = w_c[i]
        c = w * lever
        pp = pe + p
        loc = ang[i] - ph
        th = loc - FOUR_PI * np.floor(loc * inv_4pi)
        b0[i] = np.sqrt(mu_eth * c * pp) * k0 * lever
        b1[i] = k1 * pp * (1.0 - abs(st)) * lever if (th <= lo_1 or th >= hi_1) else 0.0
        b2[i] = c_f2 * c * lever
        b3[i] = c_f3 * lever * rw[i]
        b4[i] = mu * w
        b5[i] = k5 * p * abs(ct) * rw[i]


@numba.njit(cache=True, fastmath=_FAST, error_model="numpy")
def _work_means(rows, first, w_over, out):
    """out[j] = <rows[first + j] w_over> for the 7 rows (6 basis, gas) of one cylinder."""
    n = w_over.shape[0]
    for j in range(7):
        row = rows[first[j]]
        acc = 0.0
        for i in range(n):
            acc += row[i] * w_over[i]
        out[j] = acc / n


@numba.njit(cache=True, fastmath=_FAST, error_model="numpy")
def _cycle_rows(motion, theta_f, grid, pressure, cyl_node, consts, mix_row, mix_weight, n_mix, buf, means):
    """Rows of one cycle on the time grid.

    motion (3, N, n) angle, speed, acceleration of every node; theta_f (n,) flywheel angle [rad]; grid (n_g,) the
    pressure's uniform crank-angle grid spanning 4 pi, pressure (z, n_g) [Pa]; cyl_node (z,); consts: the layout of
    core.monitor.excitation_kernels; mix_row (z, 6) row of G that term (k, l) goes into (-1: none), mix_weight (z, 6) its
    weight a0_kl. Writes buf (n_mix + N + 7 z, n) = [G (n_mix); known node torque (N); basis F_kl (6 z,
    cylinder-major); gas torque (z)] and means (z, 7): work means <F_kl omega_q>/Omega (6), <T_g,k omega_q>/Omega."""
    n_nodes = motion.shape[1]
    n = motion.shape[2]
    z = cyl_node.shape[0]
    r = consts[0]
    inv_rod = 1.0 / consts[1]
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
    k0 = np.pi * d * (no + 0.4 * nc)
    k1 = np.pi * d * nc
    k5 = 0.25 * np.pi * d * d * rb
    c_f2 = mu / ga * np.pi * d * lfp
    c_f3 = nv * ls
    mu_eth = mu * eth
    lo_1 = 0.5 * np.pi
    hi_1 = FOUR_PI - 0.5 * np.pi
    known0 = n_mix
    basis0 = n_mix + n_nodes
    gas0 = basis0 + 6 * z
    for g in range(n_mix):
        for i in range(n):
            buf[g, i] = 0.0
    jlo = np.empty(n, dtype=np.int64)
    jhi = np.empty(n, dtype=np.int64)
    frac = np.empty(n)
    _pressure_brackets(theta_f, grid, jlo, jhi, frac)
    s_fly = np.empty(n)
    c_fly = np.empty(n)
    for i in range(n):
        s_fly[i] = np.sin(theta_f[i])
        c_fly[i] = np.cos(theta_f[i])
    s_q = np.empty(n)
    c_q = np.empty(n)
    w_c = np.empty(n)
    rw = np.empty(n)
    w_over = np.empty(n)
    sum_gas = np.empty(n)
    sum_recip = np.empty(n)
    p_row = np.empty(n)
    first = np.empty(7, dtype=np.int64)
    mean_k = np.empty(7)
    for q in range(n_nodes):
        n_on = 0
        for k in range(z):
            if cyl_node[k] == q:
                n_on += 1
        known = buf[known0 + q]
        if n_on == 0:
            for i in range(n):
                known[i] = 0.0
            continue
        ang = motion[0, q]
        w_node = motion[1, q]
        a_node = motion[2, q]
        _sin_cos_twisted(ang, theta_f, s_fly, c_fly, s_q, c_q)
        for i in range(n):
            w = max(0.001, w_node[i])
            w_c[i] = w
            rw[i] = 1.0 / np.sqrt(w)
            w_over[i] = w_node[i] / omega_mean
            sum_gas[i] = 0.0
            sum_recip[i] = 0.0
        for k in range(z):
            if cyl_node[k] != q:
                continue
            ph = consts[N_CONSTS + k]
            pk = pressure[k]
            for i in range(n):
                y0 = pk[jlo[i]]
                p_row[i] = y0 + (pk[jhi[i]] - y0) * frac[i]
            b = basis0 + 6 * k
            _cylinder_samples(r, inv_rod, e, area, p_cc, m_rec, k0, mu_eth, k1, c_f2, c_f3, mu, k5, pe, lo_1, hi_1,
                              ph, np.cos(ph), np.sin(ph), ang, s_q, c_q, w_node, a_node, w_c, rw, p_row,
                              buf[gas0 + k], buf[b], buf[b + 1], buf[b + 2], buf[b + 3], buf[b + 4], buf[b + 5],
                              sum_gas, sum_recip)
            for t_l in range(6):
                g = mix_row[k, t_l]
                if g >= 0:
                    wt = mix_weight[k, t_l]
                    src = buf[b + t_l]
                    dst = buf[g]
                    for i in range(n):
                        dst[i] += wt * src[i]
                first[t_l] = b + t_l
            first[6] = gas0 + k
            _work_means(buf, first, w_over, mean_k)
            for j in range(7):
                means[k, j] = mean_k[j]
        if var_inertia:
            c_inertia = j_rec * n_on
            for i in range(n):
                known[i] = sum_gas[i] + (c_inertia * a_node[i] - sum_recip[i])
        else:
            for i in range(n):
                known[i] = sum_gas[i]


@numba.njit(cache=True)
def _mix_plan(group, prior, cyl_node, n_params, n_nodes, mix_row, mix_param, mix_node):
    """One G row per (parameter, node) pair that carries a coefficient: mix_row (z, 6) the row of term (k, l)
    (-1 for a zero prior: it adds nothing); mix_param, mix_node (>= z * 6,) of each row (parameter -1: a term
    outside every group, which the node torque still sees through theta[-1] as ``ParameterLayout.coefficients``
    does, but no design column). Returns the number of rows."""
    z = group.shape[0]
    table = np.full((n_params + 1, n_nodes), -1, dtype=np.int64)
    n_mix = 0
    for k in range(z):
        q = cyl_node[k]
        for t_l in range(group.shape[1]):
            if prior[k, t_l] == 0.0:
                mix_row[k, t_l] = -1
                continue
            p = group[k, t_l]
            slot = p if p >= 0 else n_params
            if table[slot, q] < 0:
                table[slot, q] = n_mix
                mix_param[n_mix] = p
                mix_node[n_mix] = q
                n_mix += 1
            mix_row[k, t_l] = table[slot, q]
    return n_mix


@numba.njit(cache=True)
def _balance_rows(harm, scale, m, n_mix, mix_param, mix_node, theta, group, prior, cyl_node, means, compliance,
                  flywheel, inverse, freq, transfer, fly_freq, fly_harm, pattern, n_nuisance, known_harm, static, phi, rel,
                  node_speed, design, target, cyl_rows, mean_row):
    """Chain response and identification rows of one pass (see the module docstring).

    harm (n_mix + N, n // 2 + 1) complex: rfft of the rows [G; known]; scale 2 / n; theta (P,) friction parameters
    (the monitor's theta[:P]); group, prior (z, 6) of the layout; means (z, 7) work means from ``_cycle_rows``;
    compliance (N, N); inverse (M, N, N) Z_m^-1; freq (M,) its w_m; transfer (M, N) flywheel speed per node torque;
    fly_freq (M,) w_m of the cycle's fit; fly_harm (M,) flywheel angle harmonics; pattern (M, >= n_nuisance) fitted tooth-pattern harmonics.
    Writes known_harm (N, M), static (N,), phi, rel, node_speed (N, M), design (M, P + n_nuisance), target (M,),
    cyl_rows (z, P), mean_row (P + n_nuisance,)."""
    n_nodes = known_harm.shape[0]
    z = group.shape[0]
    n_terms = group.shape[1]
    n_params = theta.shape[0]
    for q in range(n_nodes):
        for j in range(m):
            known_harm[q, j] = harm[n_mix + q, j + 1] * scale
    # mean node torques -> static twist (core.model.dynamics.static_twist)
    t = np.zeros(n_nodes)
    for k in range(z):
        s = 0.0
        for t_l in range(n_terms):
            s += (prior[k, t_l] * theta[group[k, t_l]]) * means[k, t_l]
        t[cyl_node[k]] += means[k, n_terms] - s
    total = 0.0
    for q in range(n_nodes):
        total += t[q]
    t[n_nodes - 1] -= total
    for q in range(n_nodes):
        acc = 0.0
        for j in range(n_nodes):
            acc += compliance[q, j] * t[j]
        static[q] = acc
    s_fly = static[flywheel]
    for q in range(n_nodes):
        static[q] -= s_fly
    # harmonic node torques at theta, chain response
    torque = known_harm.copy()
    for g in range(n_mix):
        p = mix_param[g]
        th = theta[p] if p >= 0 else theta[n_params - 1]
        q = mix_node[g]
        for j in range(m):
            torque[q, j] -= th * (harm[g, j + 1] * scale)
    for j in range(m):
        w = freq[j]
        for i in range(n_nodes):
            acc = 0j
            for q in range(n_nodes):
                acc += inverse[j, i, q] * torque[q, j]
            phi[i, j] = acc
        for i in range(n_nodes):
            v = phi[i, j]
            node_speed[i, j] = complex(-(w * v.imag), w * v.real)
        for i in range(n_nodes):
            rel[i, j] = phi[i, j] - phi[flywheel, j]
    # speed equations: W_meas - W0 and the columns d W / d theta
    for j in range(m):
        w0 = 0j
        for q in range(n_nodes):
            w0 += transfer[j, q] * known_harm[q, j]
        w = fly_freq[j]
        a = fly_harm[j]
        target[j] = complex(-(w * a.imag), w * a.real) - w0
        for p in range(design.shape[1]):
            design[j, p] = 0j
        for g in range(n_mix):
            p = mix_param[g]
            if p >= 0:
                design[j, p] -= transfer[j, mix_node[g]] * (harm[g, j + 1] * scale)
        for c in range(n_nuisance):
            b = pattern[j, c]
            design[j, n_params + c] = complex(-(w * b.imag), w * b.real)
    # mean-balance rows (ParameterLayout.cylinder_rows; the same additions in the same order)
    for k in range(z):
        for p in range(n_params):
            cyl_rows[k, p] = 0.0
        for t_l in range(n_terms):
            p = group[k, t_l]
            if p >= 0:
                cyl_rows[k, p] += prior[k, t_l] * means[k, t_l]
    for p in range(mean_row.shape[0]):
        mean_row[p] = 0.0
    for k in range(z):
        for p in range(n_params):
            mean_row[p] += cyl_rows[k, p]
