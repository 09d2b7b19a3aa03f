"""Numba kernel of the reported estimate (core.monitor.identify.estimate.friction_estimate): coefficients and their sigmas,
per-cylinder and total friction torques with sigmas (quadratic forms through the covariance), the data gains and
the resolved masks, in one call (``estimate_kernel``). The numpy reference is ``friction_estimate_reference`` in
tests/core/test_monitor_kernels.py."""

from __future__ import annotations

import math

import numba
import numpy as np


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
def _gain(post, ref, out):
    """1 - post / ref clipped to [0, 1]; 1 where ref is pinned down already (the share the data contributed)."""
    ref_max = 0.0
    for i in range(ref.shape[0]):
        ref_max = max(ref_max, ref[i])
    pin = 1e-12 * max(ref_max, 1e-300) + 1e-300
    for i in range(ref.shape[0]):
        if ref[i] <= pin:
            out[i] = 1.0
        else:
            out[i] = min(max(1.0 - post[i] / max(ref[i], 1e-300), 0.0), 1.0)


@numba.njit(cache=True)
def coefficient_kernel(params, cov, cov_stat, cov_ref, group, prior, basis_mean, coefficient_snr, min_data_gain):
    """Coefficients a_kl = prior_kl params_g(k,l) (z, n_terms), their sigmas, normalised values a_kl <F_kl> [N m] and
    sigmas, and which are resolved (above ``coefficient_snr`` sigmas, prior > 0, data gain of their parameter at
    least ``min_data_gain``). params (p_f,) the friction scales; the covariances (>= p_f, >= p_f) are read over
    their leading p_f block (friction first, then nuisances)."""
    z, n_terms = group.shape
    p_f = params.shape[0]
    diag_stat = np.empty(p_f)
    diag_ref = np.empty(p_f)
    sd = np.empty(p_f)
    for i in range(p_f):
        diag_stat[i] = cov_stat[i, i]
        diag_ref[i] = cov_ref[i, i]
        sd[i] = math.sqrt(max(cov[i, i], 0.0))
    gain_p = np.empty(p_f)
    _gain(diag_stat, diag_ref, gain_p)
    coef = np.empty((z, n_terms))
    coef_sig = np.empty((z, n_terms))
    norm = np.empty((z, n_terms))
    norm_sig = np.empty((z, n_terms))
    ok = np.empty((z, n_terms), dtype=np.bool_)
    for k in range(z):
        for term in range(n_terms):
            g = group[k, term]
            if g < 0:
                g += p_f  # numpy's negative index (an unused term: its prior is 0)
            coef[k, term] = prior[k, term] * params[g]
            coef_sig[k, term] = prior[k, term] * sd[g]
            norm[k, term] = coef[k, term] * basis_mean[k, term]
            norm_sig[k, term] = coef_sig[k, term] * basis_mean[k, term]
            ok[k, term] = ((norm[k, term] > coefficient_snr * norm_sig[k, term]) and prior[k, term] > 0
                           and gain_p[g] >= min_data_gain)
    return coef, coef_sig, norm, norm_sig, ok


@numba.njit(cache=True)
def cylinder_kernel(params, cov, cov_stat, cov_ref, rows):
    """Per-cylinder friction torques rows @ params (z,) and their sigmas, the total and its sigma, and the data
    gain of each cylinder's deviation from the equal share (what the speed adds is the split among cylinders).
    rows (z, p_f) act on the leading p_f parameters; the covariances are read over their leading block."""
    z, p_f = rows.shape
    tmp = np.empty(p_f)
    total_row = np.zeros(p_f)
    for k in range(z):
        for i in range(p_f):
            total_row[i] += rows[k, i]
    t_cyl = np.empty(z)
    t_sig = np.empty(z)
    for k in range(z):
        s = 0.0
        for i in range(p_f):
            s += rows[k, i] * params[i]
        t_cyl[k] = s
        t_sig[k] = math.sqrt(max(_quadratic_form(rows[k], cov, tmp), 0.0))
    t_tot = 0.0
    for i in range(p_f):
        t_tot += total_row[i] * params[i]
    t_tot_sig = math.sqrt(max(_quadratic_form(total_row, cov, tmp), 0.0))
    dev = np.empty(p_f)
    post = np.empty(z)
    refs = np.empty(z)
    for k in range(z):
        for i in range(p_f):
            dev[i] = rows[k, i] - total_row[i] / z
        post[k] = _quadratic_form(dev, cov_stat, tmp)
        refs[k] = _quadratic_form(dev, cov_ref, tmp)
    gain = np.empty(z)
    _gain(post, refs, gain)
    return t_cyl, t_sig, t_tot, t_tot_sig, gain


@numba.njit(cache=True)
def estimate_kernel(params, cov, cov_stat, cov_ref, group, prior, basis_mean, rows, resolve_rel, coefficient_snr,
                    min_data_gain):
    """``coefficient_kernel`` and ``cylinder_kernel`` with the masks applied: unresolved coefficients and
    per-cylinder means are NaN. A per-cylinder mean is resolved when its sigma is at most ``resolve_rel`` of it and
    its data gain at least ``min_data_gain``.

    Returns coef_table (4, z, n_terms) = (coef, coef_sig, norm, norm_sig), coef_ok (z, n_terms), cylinder_table
    (3, z) = (t_mean, t_sig, gain), resolved (z,), t_tot, t_tot_sig (stacked: every array returned to Python
    costs about as much as a small kernel's arithmetic)."""
    coef, coef_sig, norm, norm_sig, coef_ok = coefficient_kernel(params, cov, cov_stat, cov_ref, group, prior,
                                                                 basis_mean, coefficient_snr, min_data_gain)
    z, n_terms = coef.shape
    coef_table = np.empty((4, z, n_terms))
    for k in range(z):
        for term in range(n_terms):
            masked = not coef_ok[k, term]
            coef_table[0, k, term] = np.nan if masked else coef[k, term]
            coef_table[1, k, term] = coef_sig[k, term]
            coef_table[2, k, term] = np.nan if masked else norm[k, term]
            coef_table[3, k, term] = norm_sig[k, term]
    t_cyl, t_sig, t_tot, t_tot_sig, gain = cylinder_kernel(params, cov, cov_stat, cov_ref, rows)
    cylinder_table = np.empty((3, z))
    resolved = np.empty(z, dtype=np.bool_)
    for k in range(z):
        resolved[k] = t_sig[k] <= resolve_rel * abs(t_cyl[k]) and gain[k] >= min_data_gain
        cylinder_table[0, k] = t_cyl[k] if resolved[k] else np.nan
        cylinder_table[1, k] = t_sig[k]
        cylinder_table[2, k] = gain[k]
    return coef_table, coef_ok, cylinder_table, resolved, t_tot, t_tot_sig
