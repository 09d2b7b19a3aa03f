"""Numba kernels of the monitor's per-cycle glue (core.monitor.monitor, core.monitor.monitor_glue, core.monitor.estimate, core.monitor.sharing); the
result's trace and speed-series kernels are in core.monitor.report_kernels.

Each kernel does, in one call, what the plain-numpy steps did in a dozen small-array calls; the arithmetic follows
the numpy steps operation by operation (same order, numpy's pairwise summation where numpy sums), so the numbers
agree to the last bits except where numpy went through BLAS (matrix-vector products, dot products), whose
summation order is its own. The plain-numpy references are in tests/core/test_monitor_kernels.py.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from frictionwatch.core.model.pairwise import pairwise_sum


@numba.njit(cache=True)
def _abs2(z):
    """np.abs(z) ** 2 of a complex number (hypot, then the square)."""
    v = math.hypot(z.real, z.imag)
    return v * v


# ---- noise model and whitened rows (core.monitor.monitor) ----------------------------------------------------------------


@numba.njit(cache=True)
def _residual_into(design, target, theta, out):
    """out (M,) = target - design @ theta for complex design (M, P) and real theta (P,), real and imaginary parts
    summed over P in order (the monitor's noise rows and the reported residual use the same numbers)."""
    m, p = design.shape
    for i in range(m):
        sr = 0.0
        si = 0.0
        for j in range(p):
            sr += design[i, j].real * theta[j]
            si += design[i, j].imag * theta[j]
        out[i] = complex(target[i].real - sr, target[i].imag - si)


@numba.njit(cache=True)
def noise_rows(design, target, theta, freq, drift_harm, use_drift, st_mean, st_var, st_scalars, memory, balance,
               mean_row, floor, t_i, drift_var, period, harmonics, model_rel_error, sys_balance,
               out_mean, out_var, out_scalars, a, y, inv_sigma, sys_var):
    """One cycle's noise model and whitened rows (the inline steps of core.monitor.monitor.process_cycle).

    design (M, P) complex, target (M,) complex, theta (P,) the previous estimate; freq (M,) harmonic frequencies;
    drift_harm (M,) complex: the drift pattern's angle harmonics (its speed column is i freq drift_harm);
    st_mean (M,) complex, st_var (M,), st_scalars [balance_mean, balance_var, count]: ResidualStats before;
    writes the updated statistics to out_mean, out_var, out_scalars; the whitened rows a (2M+1, P), y (2M+1),
    inv_sigma (2M+1) and sys_var (2M+1), the last entry of sys_var being ``sys_balance``."""
    m, p = design.shape
    resid = np.empty(m, dtype=np.complex128)
    _residual_into(design, target, theta, resid)
    d = np.empty(m, dtype=np.complex128)
    if use_drift:
        for i in range(m):  # 1j * freq * drift_harm, as numpy multiplies complex numbers
            d[i] = complex(0.0 * drift_harm[i].real - freq[i] * drift_harm[i].imag,
                           0.0 * drift_harm[i].imag + freq[i] * drift_harm[i].real)
        dd = 0.0
        dr = 0.0
        for i in range(m):
            dd += d[i].real * d[i].real + d[i].imag * d[i].imag
            dr += d[i].real * resid[i].real + d[i].imag * resid[i].imag
        f = dr / max(dd, 1e-300)
        for i in range(m):
            resid[i] = resid[i] - d[i] * f
    if math.isfinite(balance):
        s = 0.0
        for j in range(p):
            s += mean_row[j] * theta[j]
        bal_resid = balance - s
    else:
        bal_resid = 0.0
    # ResidualStats.update
    bal_mean = st_scalars[0]
    bal_var = st_scalars[1]
    n = int(st_scalars[2]) + 1
    g = max(1.0 - memory, 1.0 / n)
    g_half = g * 0.5
    for i in range(m):
        dl = resid[i] - st_mean[i]
        out_mean[i] = st_mean[i] + g * dl
        if n > 1:
            out_var[i] = (1.0 - g) * (st_var[i] + g_half * _abs2(dl))
        else:
            out_var[i] = 0.5 * _abs2(resid[i])
    db = bal_resid - bal_mean
    out_scalars[0] = bal_mean + g * db
    out_scalars[1] = (1.0 - g) * (bal_var + g * db * db) if n > 1 else bal_resid**2
    out_scalars[2] = n
    sigma = np.empty(m)
    for i in range(m):
        sigma[i] = math.sqrt(max(out_var[i], floor[i]))
    if n > 2:
        sigma_bal = math.sqrt(max(out_scalars[1], (0.002 * t_i) ** 2, 1e-6))
    else:
        sigma_bal = 0.05 * abs(t_i)
    # whiten
    for i in range(m):
        for j in range(p):
            a[i, j] = design[i, j].real / sigma[i]
            a[m + i, j] = design[i, j].imag / sigma[i]
        y[i] = target[i].real / sigma[i]
        y[m + i] = target[i].imag / sigma[i]
    if use_drift and drift_var > 0:
        # this cycle's drift as a random effect (Sherman-Morrison; see core.monitor.monitor)
        dw = np.empty(2 * m)
        for i in range(m):
            dw[i] = d[i].real / sigma[i]
            dw[m + i] = d[i].imag / sigma[i]
        nd = 0.0
        for i in range(2 * m):
            nd += dw[i] * dw[i]
        s2 = drift_var * (0.5 * period) ** 2
        if nd > 0:
            c = (1.0 - 1.0 / math.sqrt(1.0 + s2 * nd)) / nd
            v = np.zeros(p)
            for i in range(2 * m):
                for j in range(p):
                    v[j] += dw[i] * a[i, j]
            for i in range(2 * m):
                for j in range(p):
                    a[i, j] = a[i, j] - c * (dw[i] * v[j])
            vy = 0.0
            for i in range(2 * m):
                vy += dw[i] * y[i]
            for i in range(2 * m):
                y[i] = y[i] - c * dw[i] * vy
    if math.isfinite(balance):
        for j in range(p):
            a[2 * m, j] = mean_row[j] / sigma_bal
        y[2 * m] = balance / sigma_bal
    else:  # no load: the mean is not measured this cycle; the row carries nothing
        for j in range(p):
            a[2 * m, j] = 0.0
        y[2 * m] = 0.0
    for i in range(m):
        inv_sigma[i] = 1.0 / sigma[i]
        inv_sigma[m + i] = 1.0 / sigma[i]
        h = harmonics[i]
        sh = complex(0.0 * h.real - freq[i] * h.imag, 0.0 * h.imag + freq[i] * h.real)  # 1j * freq * harmonics
        e = model_rel_error * math.hypot(sh.real, sh.imag)
        v2 = max(_abs2(out_mean[i]), e * e) / 2.0
        sys_var[i] = v2
        sys_var[m + i] = v2
    inv_sigma[2 * m] = 1.0 / sigma_bal
    sys_var[2 * m] = sys_balance


# ---- Eq. 6 sharing and its prior rows (core.monitor.sharing, core.monitor.monitor._with_share) --------------------------------


@numba.njit(cache=True)
def firing_into(t, fraction, fire):
    """frictionwatch.core.monitor.sharing.firing_mask into ``fire`` (bool, z); returns the number of firing cylinders."""
    z = t.shape[0]
    pos = np.empty(z)
    n = 0
    for k in range(z):
        if t[k] > 0:
            pos[n] = t[k]
            n += 1
    if n == 0:
        for k in range(z):
            fire[k] = False
        return 0
    srt = np.sort(pos[:n])
    med = srt[n // 2] if n % 2 else 0.5 * (srt[n // 2 - 1] + srt[n // 2])
    thr = fraction * med
    count = 0
    for k in range(z):
        fire[k] = t[k] > thr
        if fire[k]:
            count += 1
    return count


@numba.njit(cache=True)
def share_into(total, t_i, motored_friction, spread, motored_spread, fraction, out, sig, motored):
    """frictionwatch.core.monitor.sharing.share_mean_loss into out, sig (z,) and motored (bool, z)."""
    z = t_i.shape[0]
    fire = np.empty(z, dtype=np.bool_)
    n_fire = firing_into(t_i, fraction, fire)
    n_ml = z - n_fire
    for k in range(z):
        motored[k] = not fire[k]
    if n_ml == z:  # nothing fires: every cylinder gets the motored loss
        for k in range(z):
            out[k] = motored_friction
            sig[k] = motored_spread * abs(motored_friction)
        return
    tf = np.empty(n_fire)
    j = 0
    for k in range(z):
        if fire[k]:
            tf[j] = t_i[k]
            j += 1
    t_fire = pairwise_sum(tf, 0, n_fire)
    t_f_fire = total - n_ml * motored_friction
    for k in range(z):
        if fire[k]:
            out[k] = t_f_fire * t_i[k] / t_fire
            sig[k] = spread * abs(out[k])
        else:
            out[k] = motored_friction
            sig[k] = motored_spread * abs(motored_friction)


@numba.njit(cache=True)
def share_normal_into(n_base, r_base, rows, share, share_sigma, n_out, r_out):
    """Prior normal equations plus the share rows: n_base + W^T W, r_base + W^T (share / s), W = rows / s,
    s = max(share_sigma, 1e-6); rows (z, p_f) act on the first p_f of the P parameters. Returns False (outputs
    untouched) when a share is not finite: the caller then uses the base alone."""
    z, p_f = rows.shape
    for k in range(z):
        if not math.isfinite(share[k]):
            return False
    p = n_base.shape[0]
    w = np.empty((z, p_f))
    wt = np.empty(z)
    for k in range(z):
        s = max(share_sigma[k], 1e-6)
        for i in range(p_f):
            w[k, i] = rows[k, i] / s
        wt[k] = share[k] / s
    for i in range(p):
        for j in range(p):
            n_out[i, j] = n_base[i, j]
        r_out[i] = r_base[i]
    for i in range(p_f):
        for j in range(p_f):
            acc = 0.0
            for k in range(z):
                acc += w[k, i] * w[k, j]
            n_out[i, j] = n_base[i, j] + acc
        acc = 0.0
        for k in range(z):
            acc += w[k, i] * wt[k]
        r_out[i] = r_base[i] + acc
    return True


# ---- the reported estimate (core.monitor.estimate) -------------------------------------------------------------------


@numba.njit(cache=True)
def _quadratic_form(r, cov, tmp):
    """r^T C r over the leading len(r) rows/columns of cov (zero entries of r skipped)."""
    p = r.shape[0]
    for j in range(p):
        tmp[j] = 0.0
    for i in range(p):
        ri = r[i]
        if ri != 0.0:
            for j in range(p):
                tmp[j] += ri * cov[i, j]
    s = 0.0
    for j in range(p):
        s += tmp[j] * r[j]
    return s


@numba.njit(cache=True)
def estimate_into(theta, cov, cov_stat, cov_ref, group, prior, basis_mean, rows, resolve_rel, coefficient_snr,
                  min_data_gain, to_mep_cyl, to_mep_eng, t_mean, t_sig, fmep, fmep_sig, coef, coef_sig, coef_norm,
                  coef_norm_sig, resolved, coef_ok, gain, totals):
    """frictionwatch.core.monitor.estimate.friction_estimate's numbers. theta (>= p_f,), the covariances (>= p_f, >= p_f) of which the
    leading p_f = rows.shape[1] parameters are reported; totals <- [t_tot, t_tot_sig, fmep_tot, fmep_tot_sig]."""
    z, p_f = rows.shape
    n_terms = group.shape[1]
    # diagonal gain of the parameters (Posterior.diagonal_gain)
    ref_max = 0.0
    for i in range(p_f):
        ref_max = max(ref_max, cov_ref[i, i])
    pin = 1e-12 * max(ref_max, 1e-300) + 1e-300
    gain_p = np.empty(p_f)
    sd = np.empty(p_f)
    for i in range(p_f):
        ref = cov_ref[i, i]
        if ref <= pin:
            gain_p[i] = 1.0
        else:
            gain_p[i] = min(max(1.0 - cov_stat[i, i] / max(ref, 1e-300), 0.0), 1.0)
        sd[i] = math.sqrt(max(cov[i, i], 0.0))
    for k in range(z):
        for term in range(n_terms):
            g = group[k, term]
            if g < 0:
                g += p_f  # numpy's negative index (an unused term: its prior is 0)
            a = prior[k, term] * theta[g]
            a_s = prior[k, term] * sd[g]
            a_n = a * basis_mean[k, term]
            a_ns = a_s * basis_mean[k, term]
            ok = (a_n > coefficient_snr * a_ns) and (prior[k, term] > 0) and (gain_p[g] >= min_data_gain)
            coef_ok[k, term] = ok
            coef[k, term] = a if ok else np.nan
            coef_sig[k, term] = a_s
            coef_norm[k, term] = a_n if ok else np.nan
            coef_norm_sig[k, term] = a_ns
    tmp = np.empty(p_f)
    total_row = np.zeros(p_f)
    for k in range(z):
        for i in range(p_f):
            total_row[i] += rows[k, i]
    t_cyl = np.empty(z)
    for k in range(z):
        s = 0.0
        for i in range(p_f):
            s += rows[k, i] * theta[i]
        t_cyl[k] = s
        t_sig[k] = math.sqrt(max(_quadratic_form(rows[k], cov, tmp), 0.0))
    t_tot = 0.0
    for i in range(p_f):
        t_tot += total_row[i] * theta[i]
    t_tot_sig = math.sqrt(max(_quadratic_form(total_row, cov, tmp), 0.0))
    # what the speed adds is the split among cylinders: the deviation of each cylinder from the equal share
    dev = np.empty(p_f)
    post = np.empty(z)
    refs = np.empty(z)
    ref_max = 0.0
    for k in range(z):
        for i in range(p_f):
            dev[i] = rows[k, i] - total_row[i] / z
        post[k] = _quadratic_form(dev, cov_stat, tmp)
        refs[k] = _quadratic_form(dev, cov_ref, tmp)
        ref_max = max(ref_max, refs[k])
    pin = 1e-12 * max(ref_max, 1e-300) + 1e-300
    for k in range(z):
        if refs[k] <= pin:
            gain[k] = 1.0
        else:
            gain[k] = min(max(1.0 - post[k] / max(refs[k], 1e-300), 0.0), 1.0)
        ok = (t_sig[k] <= resolve_rel * abs(t_cyl[k])) and (gain[k] >= min_data_gain)
        resolved[k] = ok
        t_mean[k] = t_cyl[k] if ok else np.nan
        fmep[k] = t_cyl[k] * to_mep_cyl if ok else np.nan
        fmep_sig[k] = t_sig[k] * to_mep_cyl
    totals[0] = t_tot
    totals[1] = t_tot_sig
    totals[2] = t_tot * to_mep_eng
    totals[3] = t_tot_sig * to_mep_eng


# ---- the glue between the harmonic balance and the posteriors (core.monitor.monitor) -----------------------------------


@numba.njit(cache=True)
def shares_pair_into(t_i, pmax, ind_prev, first, g, total_s, total_c, rpm, motored_consts, spread, n_base, r_base,
                     rows, ind_mean, fric_s, sig_s, fric_c, sig_c, fire, n_s, r_s, n_c, r_c):
    """The sharing steps of core.monitor.monitor.process_cycle in one call (same operations, same order).

    t_i (z,) this cycle's indicated means; pmax (z,) peak pressures [Pa]; ind_prev (z,) the running mean before
    (``first``: this is the first cycle, the mean starts at t_i); g its EWMA gain; total_s / total_c the friction
    totals shared for the smoothed / this cycle's estimate; motored_consts [stroke, displacement_cyl, A, B, C, D]
    (core.monitor.sharing.motored_friction_per_cylinder); n_base (P, P), r_base (P,) the fixed priors' normal equations;
    rows (z, p_f). Writes the running mean ``ind_mean``, both shares with sigmas, the firing mask of t_i and both
    prior normal equations plus share rows (the base alone when a share is not finite). Returns the firing count."""
    z = t_i.shape[0]
    for k in range(z):
        ind_mean[k] = t_i[k] if first else ind_prev[k] + g * (t_i[k] - ind_prev[k])
    n_fire = firing_into(t_i, 0.15, fire)
    pmax_motored = 0.0
    if n_fire < z:  # np.mean of the motored cylinders' peaks
        pm = np.empty(z - n_fire)
        j = 0
        for k in range(z):
            if not fire[k]:
                pm[j] = pmax[k]
                j += 1
        pmax_motored = pairwise_sum(pm, 0, z - n_fire) / (z - n_fire)
    cbar = 2.0 * motored_consts[0] * rpm / 60.0
    fmep_bar = (motored_consts[2] + motored_consts[3] * pmax_motored / 1e5 + motored_consts[4] * cbar
                + motored_consts[5] * cbar * cbar)
    motored = fmep_bar * 1e5 * motored_consts[1] * 1.0 / (4.0 * math.pi)
    mot = np.empty(z, dtype=np.bool_)
    share_into(total_s, ind_mean, motored, spread, 0.3, 0.15, fric_s, sig_s, mot)
    share_into(total_c, t_i, motored, spread, 0.3, 0.15, fric_c, sig_c, mot)
    _share_normal_sym(n_base, r_base, rows, fric_s, sig_s, n_s, r_s)
    _share_normal_sym(n_base, r_base, rows, fric_c, sig_c, n_c, r_c)
    return n_fire


@numba.njit(cache=True)
def _share_normal_sym(n_base, r_base, rows, share, share_sigma, n_out, r_out):
    """``share_normal_into``'s numbers (the base itself when a share is not finite): each sum over cylinders is
    formed once for (i, j) and (j, i) (the same products in the same order: the same bits) from W^T stored row
    by row."""
    z, p_f = rows.shape
    p = n_base.shape[0]
    for i in range(p):
        for j in range(p):
            n_out[i, j] = n_base[i, j]
        r_out[i] = r_base[i]
    for k in range(z):
        if not math.isfinite(share[k]):
            return
    wt_rows = np.empty((p_f, z))
    wt = np.empty(z)
    for k in range(z):
        s = max(share_sigma[k], 1e-6)
        for i in range(p_f):
            wt_rows[i, k] = rows[k, i] / s
        wt[k] = share[k] / s
    for i in range(p_f):
        wi = wt_rows[i]
        for j in range(i, p_f):
            wj = wt_rows[j]
            acc = 0.0
            for k in range(z):
                acc += wi[k] * wj[k]
            n_out[i, j] = n_base[i, j] + acc
            n_out[j, i] = n_base[j, i] + acc
        acc = 0.0
        for k in range(z):
            acc += wi[k] * wt[k]
        r_out[i] = r_base[i] + acc


@numba.njit(cache=True)
def noise_rows_cycle(design, target, theta, omega, drift_harm, use_drift, st_mean, st_var, st_bal_mean, st_bal_var,
                     st_count, memory, balance, mean_row, residual_rms, n_edges, t_i, drift_var, period, harmonics,
                     model_rel_error, sys_balance, freq, drift_col, out_mean, out_var, out_scalars, a, y, inv_sigma,
                     sys_var):
    """``noise_rows`` with its inputs formed in the kernel: freq (M,) = 0.5 omega (1..M) (FlywheelMotion.freq)
    written to ``freq``, the tooth-fit floor freq^2 2 rms^2 / n_edges + 1e-12 and the statistics' scalars; also
    writes drift_col (M,) complex = 1j * freq * drift_harm as numpy multiplies complex numbers."""
    m = freq.shape[0]
    half = 0.5 * omega
    rms2 = residual_rms * residual_rms
    floor = np.empty(m)
    for i in range(m):
        freq[i] = half * float(i + 1)
        floor[i] = freq[i] * freq[i] * 2.0 * rms2 / n_edges + 1e-12
        h = drift_harm[i]
        drift_col[i] = complex(0.0 * h.real - freq[i] * h.imag, 0.0 * h.imag + freq[i] * h.real)
    st_scalars = np.empty(3)
    st_scalars[0] = st_bal_mean
    st_scalars[1] = st_bal_var
    st_scalars[2] = st_count
    noise_rows(design, target, theta, freq, drift_harm, use_drift, st_mean, st_var, st_scalars, memory, balance,
               mean_row, floor, t_i, drift_var, period, harmonics, model_rel_error, sys_balance, out_mean, out_var,
               out_scalars, a, y, inv_sigma, sys_var)

