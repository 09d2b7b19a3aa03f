"""One compiled call for the identification steps of core.monitor.monitor.process_cycle (core.monitor.identify_step): noise model
and whitened rows, the cycle's normal-equation terms, their fold into the running accumulator, the Eq. 6 shares
with both prior normal equations, both posteriors and both reported estimates.

It calls the very kernels the separate steps call (core.monitor.monitor_kernels, core.monitor.accumulate_kernels,
core.monitor.posterior_kernels) with the same inputs in the
same order, so the numbers are the same bits; what it saves is the Python between them (about 20 argument
unboxings per kernel call, boxing of the returned arrays, views, the intermediate frozen objects). numba's fastmath
flags belong to each function: the callees keep theirs, so this function must not re-write their loops. Its cache
does not see a changed callee in another module: ``make clean-numba`` after editing one.

Whenever a step would take another path than its kernel (a posterior with an active bound or a near-singular
factor, shapes that do not fit), the kernel returns a non-zero status and writes nothing the caller keeps; the
caller then runs the separate steps, which stay the reference and the general path.
"""

from __future__ import annotations

import numba
import numpy as np

from frictionwatch.core.monitor.accumulate_kernels import _cycle_terms, _fold
from frictionwatch.core.monitor.monitor_kernels import estimate_into, noise_rows_cycle, shares_pair_into
from frictionwatch.core.monitor.posterior_kernels import BAD_SHAPE, OK, posterior_kernel

FUSED_OK = OK
FUSED_BAD_SHAPE = BAD_SHAPE  # cycle terms or fold: the arrays do not fit together
FUSED_POSTERIOR = 10  # + the posterior kernel's status (NEEDS_BOUND, FALLBACK, BAD_SHAPE) of the smoothed one
FUSED_POSTERIOR_CYCLE = 20  # + the status of this cycle's own posterior

_C = numba.types.Array(numba.complex128, 1, "C")
_C2 = numba.types.Array(numba.complex128, 2, "C")
_V = numba.types.Array(numba.float64, 1, "C")
_VR = numba.types.Array(numba.float64, 1, "C", readonly=True)
_M = numba.types.Array(numba.float64, 2, "C")
_M3 = numba.types.Array(numba.float64, 3, "C")
_B = numba.types.Array(numba.bool_, 1, "C")
_B2 = numba.types.Array(numba.bool_, 2, "C")
_B3 = numba.types.Array(numba.bool_, 3, "C")
_I2 = numba.types.Array(numba.int64, 2, "C")
_SIGNATURES = [
    numba.types.Tuple((numba.int64, _M, _M, _M, _M, _V, _M, _M))(
        # noise model: design, target, theta, pattern harmonics, harmonics, stats mean, var, mean row, scalars
        _C2, _C, _V, _C2, _C, _C, _V, _V, _V,
        # accumulator before: info, rhs, sys_map, info_reference; fold flag
        _M, _V, _M, _M, numba.bool_,
        # shares: indicated means, peaks, running means before, first cycle, motored consts, prior normal, rows
        _V, _V, _V, numba.bool_, _V, _M, _V, _M,
        # posteriors and estimates: lower bounds, group, prior, basis means, cylinder rows (leading p_f)
        lower, _I2, _M, _M, _M,
        # outputs
        _C2, _M, _M, _B, _V, _M, _M3, _B2, _B3, _V)
    for lower in (_V, _VR)
]


@numba.njit(cache=True)
def _shapes_fit(m, p, r, z, pn, p_f, n_terms, target, theta, pattern_harmonics, harmonics, st_mean, st_var,
                mean_row, scalars, acc_map, pmax, ind_prev, motored_consts, r_base, share_rows, lower, group, prior,
                basis_mean, cyl_rows, cplx_out, real_out, shares_out, fire, theta_s, per_cyl, per_term, resolved,
                coef_ok, numbers_out):
    """Every array's shape fits the design (M, P), z cylinders, pn = P prior rows, p_f friction parameters (the
    kernels called read without bounds checks)."""
    return (m >= 1 and target.shape[0] == m and theta.shape[0] == p and pattern_harmonics.shape[0] == m
            and pattern_harmonics.shape[1] >= 1 and harmonics.shape[0] == m and st_mean.shape[0] == m
            and st_var.shape[0] == m and mean_row.shape[0] == p and scalars.shape[0] == 28
            and acc_map.shape[0] == p and acc_map.shape[1] == r and pn == p and r_base.shape[0] == p
            and pmax.shape[0] == z and ind_prev.shape[0] == z and motored_consts.shape[0] == 6
            and share_rows.shape[0] == z and share_rows.shape[1] <= p and lower.shape[0] == p
            and group.shape[0] == z and prior.shape[0] == z and prior.shape[1] == n_terms
            and basis_mean.shape[0] == z and basis_mean.shape[1] == n_terms and cyl_rows.shape[0] == z
            and p_f <= p and cplx_out.shape[0] == 2 and cplx_out.shape[1] == m and real_out.shape[0] == 2
            and real_out.shape[1] == m and shares_out.shape[0] == 5 and shares_out.shape[1] == z
            and fire.shape[0] == z and theta_s.shape[0] == p and per_cyl.shape[0] == 10 and per_cyl.shape[1] == z
            and per_term.shape[0] == 8 and per_term.shape[1] == z and per_term.shape[2] == n_terms
            and resolved.shape[0] == 2 and resolved.shape[1] == z and coef_ok.shape[0] == 2
            and coef_ok.shape[1] == z and coef_ok.shape[2] == n_terms and numbers_out.shape[0] == 16)


@numba.njit(_SIGNATURES, cache=True)
def identify_step_kernel(design, target, theta, pattern_harmonics, harmonics, st_mean, st_var, mean_row, scalars,
                         acc_info, acc_rhs, acc_map, acc_ref, do_fold,
                         t_i, pmax, ind_prev, first, motored_consts, n_base, r_base, share_rows,
                         lower, group, prior, basis_mean, cyl_rows,
                         cplx_out, real_out, shares_out, fire, theta_s, per_cyl, per_term, resolved, coef_ok,
                         numbers_out):
    """The steps of core.monitor.monitor.process_cycle from ``noise_model_rows`` to the second
    ``friction_estimate_leading`` (see core.monitor.identify_step.identify_step for the packing of the arguments).

    scalars: [omega, stats balance_mean, balance_var, count, noise_memory, balance, residual_rms, n_edges, t_i,
    drift_var, period, model_rel_error, sys_balance, use_drift, lambda, g, total_s, total_c, rpm, share_spread,
    resolve_rel, coefficient_snr, min_data_gain, mep_cyl, mep_eng, max_condition, acc yty, acc rows]; acc_* the
    accumulator before (folded with lambda when ``do_fold``: Accumulator.fold's kernel); outputs: cplx_out
    (2, M) [stats mean, drift column], real_out (2, M) [stats var, freq], shares_out (5, z) [running indicated
    mean, share_s, sigma_s, share_c, sigma_c], fire (z,), theta_s (P,), per_cyl (10, z) [t_mean, t_sig, fmep, fmep_sig, gain of
    the smoothed estimate, the same of this cycle's], per_term (8, z, 6) [coef, coef_sig, coef_norm,
    coef_norm_sig of each], resolved (2, z), coef_ok (2, z, 6) (core.monitor.estimate.friction_estimate_leading's
    buffers), numbers_out (16,) [totals (4) and chi2_reduced of the smoothed estimate, the same of this cycle's,
    n_fire, yty and rows of the running accumulator, the statistics' balance_mean, balance_var, count].

    Returns (status, covariance, cov_statistical, cov_reference of the smoothed posterior, the running info, rhs,
    sys_map, info_reference: the folded ones when ``do_fold``, else the inputs themselves); status FUSED_OK, else
    the reason for the separate steps (then nothing written or returned is valid)."""
    m = design.shape[0]
    p = design.shape[1]
    r = 2 * m + 1
    s = scalars
    empty = np.empty((0, 0))
    none = (empty, empty, empty, empty, np.empty(0), empty, empty)
    z = t_i.shape[0]
    pn = n_base.shape[0]
    p_f = cyl_rows.shape[1]
    n_terms = group.shape[1]
    if not _shapes_fit(m, p, r, z, pn, p_f, n_terms, target, theta, pattern_harmonics, harmonics, st_mean, st_var,
                       mean_row, scalars, acc_map, pmax, ind_prev, motored_consts, r_base, share_rows, lower, group,
                       prior, basis_mean, cyl_rows, cplx_out, real_out, shares_out, fire, theta_s, per_cyl, per_term,
                       resolved, coef_ok, numbers_out):
        return (FUSED_BAD_SHAPE, *none)
    # noise model and whitened rows (core.monitor.monitor_glue.noise_model_rows)
    a = np.empty((r, p))
    y = np.empty(r)
    inv_sigma = np.empty(r)
    sys_var = np.empty(r)
    noise_rows_cycle(design, target, theta, s[0], np.ascontiguousarray(pattern_harmonics[:, -1]), s[13] != 0.0,
                     st_mean, st_var, s[1], s[2], s[3], s[4], s[5], mean_row, s[6], s[7], s[8], s[9], s[10],
                     harmonics, s[11], s[12], real_out[1], cplx_out[1], cplx_out[0], real_out[0], numbers_out[13:],
                     a, y, inv_sigma, sys_var)
    # this cycle's terms (Accumulator.cycle_terms, one reference row: the mean balance) and the fold
    ok, t_info, t_rhs, t_yty, t_map, t_ref = _cycle_terms(a, y, inv_sigma, 1)
    if not ok:
        return (FUSED_BAD_SHAPE, *none)
    lam = s[14]
    if do_fold:
        ok, run_info, run_rhs, run_map, run_ref = _fold(lam, acc_info, acc_rhs, acc_map, acc_ref, t_info, t_rhs,
                                                        t_map, t_ref)
        if not ok:
            return (FUSED_BAD_SHAPE, *none)
        run_yty = lam * s[26] + t_yty
        run_rows = lam * s[27] + float(r)
    else:
        run_info, run_rhs, run_map, run_ref = acc_info, acc_rhs, acc_map, acc_ref
        run_yty = s[26]
        run_rows = s[27]
    # Eq. 6 shares of both estimates with their prior normal equations (core.monitor.monitor_glue.shares_pair)
    normal = np.empty((2, pn, pn))
    rhs = np.empty((2, pn))
    n_fire = shares_pair_into(t_i, pmax, ind_prev, first, s[15], s[16], s[17], s[18], motored_consts, s[19], n_base,
                              r_base, share_rows, shares_out[0], shares_out[1], shares_out[2], shares_out[3],
                              shares_out[4], fire, normal[0], rhs[0], normal[1], rhs[1])
    # both posteriors (core.monitor.accumulate.posterior_from_normal's kernel path)
    st, th_s, chi2_s, cov_stat_s, cov_s, ref_s = posterior_kernel(
        run_info, run_rhs, run_yty, run_rows, run_map, run_ref, normal[0], rhs[0], sys_var, lower, s[25])
    if st != OK:
        return (FUSED_POSTERIOR + st, *none)
    st, th_c, chi2_c, cov_stat_c, cov_c, ref_c = posterior_kernel(
        t_info, t_rhs, t_yty, float(r), t_map, t_ref, normal[1], rhs[1], sys_var, lower, s[25])
    if st != OK:
        return (FUSED_POSTERIOR_CYCLE + st, *none)
    for i in range(th_s.shape[0]):
        theta_s[i] = th_s[i]
    # both reported estimates (core.monitor.estimate.friction_estimate_leading)
    for e in range(2):
        if e == 0:
            th, cov, cov_stat, cov_ref, chi2 = th_s, cov_s, cov_stat_s, ref_s, chi2_s
        else:
            th, cov, cov_stat, cov_ref, chi2 = th_c, cov_c, cov_stat_c, ref_c, chi2_c
        c0 = 5 * e
        t0 = 4 * e
        estimate_into(th, cov, cov_stat, cov_ref, group, prior, basis_mean, cyl_rows, s[20], s[21], s[22], s[23],
                      s[24], per_cyl[c0], per_cyl[c0 + 1], per_cyl[c0 + 2], per_cyl[c0 + 3], per_term[t0],
                      per_term[t0 + 1], per_term[t0 + 2], per_term[t0 + 3], resolved[e], coef_ok[e], per_cyl[c0 + 4],
                      numbers_out[c0:c0 + 4])
        numbers_out[c0 + 4] = chi2
    numbers_out[10] = n_fire
    numbers_out[11] = run_yty
    numbers_out[12] = run_rows
    return FUSED_OK, cov_s, cov_stat_s, ref_s, run_info, run_rhs, run_map, run_ref
