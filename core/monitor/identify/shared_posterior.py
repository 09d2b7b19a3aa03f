"""A cycle's two posteriors with their Eq. 6 share priors, in one kernel call (design note 63).

identify_cycle solves two problems a cycle: the accumulated equations (the smoothed estimate, the share of the
running balance by the running indicated means) and this cycle's own (the share of its own balance by its own
indicated means). Each is share_mean_loss -> PriorNormal.with_share -> posterior_from_normal: three Python helpers,
a record and their checks around three small kernels (~40 us a k9k cycle for the two, ~15 us of it arithmetic).
``posterior_pair_kernel`` runs the same kernels (core.monitor.identify.sharing's share_kernel and share_rows_kernel,
core.monitor.identify.posterior_kernels' posterior_kernel) for both in one dispatch; ``shared_posteriors_reference``
is the chain it replaces, and the path taken when a bound is active or a factor is nearly singular
(posterior_from_normal's own NNLS and LAPACK fallbacks), so those cases are exactly the old ones.
"""

from __future__ import annotations

import numba
import numpy as np
from frictionwatch.core.monitor.identify.accumulate import (
    REFERENCE_MAX_CONDITION,
    Accumulator,
    Posterior,
    posterior_from_normal,
)
from frictionwatch.core.monitor.identify.posterior_kernels import BAD_SHAPE, OK, lower_vector, posterior_kernel
from frictionwatch.core.monitor.identify.priors import PriorNormal
from frictionwatch.core.monitor.identify.sharing import (
    FIRING_FRACTION,
    MOTORED_SPREAD,
    SharedLoss,
    share_kernel,
    share_mean_loss,
    share_rows_kernel,
)


@numba.njit(cache=True)
def _shared_posterior(equations, prior, total, t_i, sharing, lo, max_condition):
    """One problem: the Eq. 6 share of ``total`` by t_i (z,), the prior's normal equations with its rows (when the
    share is finite, as PriorNormal.with_share) and posterior_kernel on them; sharing = (motored friction, spread,
    motored spread, firing fraction)."""
    info, rhs, yty, rows, sys_map, info_reference, sys_var = equations
    p_info, p_rhs, cyl_rows = prior
    share, sigma, motored = share_kernel(total, t_i, sharing[0], sharing[1], sharing[2], sharing[3])
    n_pr, r_pr = p_info, p_rhs
    if np.isfinite(share).all():
        if cyl_rows.shape[1] > p_info.shape[0] or share.shape[0] != cyl_rows.shape[0]:
            e = np.empty(0)
            return (share, sigma, motored), (n_pr, r_pr), (BAD_SHAPE, e, 1.0, n_pr, n_pr, n_pr)
        n_pr, r_pr = share_rows_kernel(p_info, p_rhs, cyl_rows, share, sigma)
    post = posterior_kernel(info, rhs, yty, rows, sys_map, info_reference, n_pr, r_pr, sys_var, lo, max_condition)
    return (share, sigma, motored), (n_pr, r_pr), post


@numba.njit(cache=True)
def posterior_pair_kernel(smoothed, cycle, prior, totals, indicated, sharing, lo):
    """Both problems of a cycle: smoothed and cycle each (info, rhs, yty, rows, sys_map, info_reference, sys_var);
    prior (info, rhs, cylinder rows (z, p_f)); totals (the two balances [N m]); indicated (the two t_i (z,));
    sharing as ``_shared_posterior``'s; lo (P,) the bounds. Returns, per problem, ((share, sigma, motored), (n_pr,
    r_pr), posterior_kernel's (status, params, chi2_red, cov_stat, covariance, cov_reference))."""
    return (_shared_posterior(smoothed, prior, totals[0], indicated[0], sharing, lo, REFERENCE_MAX_CONDITION),
            _shared_posterior(cycle, prior, totals[1], indicated[1], sharing, lo, REFERENCE_MAX_CONDITION))


def _equations(acc: Accumulator, sys_var: np.ndarray) -> tuple:
    return (acc.info, acc.rhs, float(acc.yty), float(acc.rows), acc.sys_map, acc.info_reference,
            np.asarray(sys_var, dtype=np.float64))


def shared_posteriors(accs: tuple[Accumulator, Accumulator], sys_vars: tuple[np.ndarray, np.ndarray],
                      prior: PriorNormal, cyl_rows: np.ndarray, totals: tuple[float, float],
                      indicated: tuple[np.ndarray, np.ndarray], motored: float, spread: float,
                      lower: float | np.ndarray) -> tuple[tuple[SharedLoss, Posterior], tuple[SharedLoss, Posterior]]:
    """((share, posterior) of the smoothed problem, of the cycle's): accs, sys_vars, totals and indicated each
    (smoothed, cycle); as ``shared_posteriors_reference`` (one kernel call; a bound or a near-singular factor: that
    problem's posterior by posterior_from_normal, its NNLS and LAPACK paths)."""
    p = accs[0].sys_map.shape[0]
    lo = lower_vector(lower, p)
    rows = np.ascontiguousarray(cyl_rows, dtype=np.float64)
    t_s, t_c = (np.ascontiguousarray(t, dtype=np.float64) for t in indicated)
    try:
        out = posterior_pair_kernel(
            _equations(accs[0], sys_vars[0]), _equations(accs[1], sys_vars[1]), (prior.info, prior.rhs, rows),
            (float(totals[0]), float(totals[1])), (t_s, t_c),
            (float(motored), float(spread), MOTORED_SPREAD, FIRING_FRACTION), lo)
    except TypeError:  # another dtype or layout: the reference converts
        return shared_posteriors_reference(accs, sys_vars, prior, cyl_rows, totals, indicated, motored, spread, lower)
    if out[0][2][0] == BAD_SHAPE or out[1][2][0] == BAD_SHAPE:  # the reference names what does not fit
        return shared_posteriors_reference(accs, sys_vars, prior, cyl_rows, totals, indicated, motored, spread, lower)
    return tuple(_pair_member(acc, sys_var, lo, *res) for acc, sys_var, res in zip(accs, sys_vars, out))


def _pair_member(acc: Accumulator, sys_var: np.ndarray, lo: np.ndarray, share: tuple, normal: tuple,
                 post: tuple) -> tuple[SharedLoss, Posterior]:
    status, params, chi2_red, cov_stat, cov, ref = post
    loss = SharedLoss(friction_mean=share[0], sigma=share[1], motored=share[2])
    if status != OK:  # a bound active, a nearly singular factor: posterior_from_normal's own paths decide
        return loss, posterior_from_normal(acc, normal[0], normal[1], sys_var, lo)
    return loss, Posterior(params=params, covariance=cov, cov_statistical=cov_stat, chi2_reduced=float(chi2_red),
                           weight=acc.weight, cov_reference=ref)


def shared_posteriors_reference(accs: tuple[Accumulator, Accumulator], sys_vars: tuple[np.ndarray, np.ndarray],
                                prior: PriorNormal, cyl_rows: np.ndarray, totals: tuple[float, float],
                                indicated: tuple[np.ndarray, np.ndarray], motored: float, spread: float,
                                lower: float | np.ndarray) -> tuple[tuple[SharedLoss, Posterior],
                                                                    tuple[SharedLoss, Posterior]]:
    """``shared_posteriors`` by its helpers: per problem share_mean_loss, PriorNormal.with_share and
    posterior_from_normal (its reference, and the general path)."""
    out = []
    for acc, sys_var, total, t_i in zip(accs, sys_vars, totals, indicated):
        share = share_mean_loss(total, t_i, motored, spread)
        out.append((share, posterior_from_normal(acc, *prior.with_share(cyl_rows, share), sys_var, lower)))
    return out[0], out[1]
