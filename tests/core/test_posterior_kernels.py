"""The posterior kernels (core.monitor.identify.posterior) against the LAPACK/scipy reference they replace.

References: ``core.monitor.identify.posterior.posterior_from_normal_reference`` and ``core.monitor.identify.bounded_solve.bounded_solve_nnls`` (the code
before the kernels, kept verbatim), numpy's cholesky / inv / solve for the helpers. Problems are built like the
monitor's (core.monitor.monitor): whitened rows of a few cycles accumulated with forgetting, a weak prior per parameter plus
a few share rows, the nuisances last and free (lower = -inf), the coefficients bounded below by 0, and badly scaled
columns (raw condition ~1e12, as the monitor's). Sizes: genset-v20 P=47 (24 nuisances), R=49; k9k-4cyl P=29,
deutz-1cyl P=28 (R=47).

Tolerances: 1e-10 relative to the largest element of each array (the task's bar); covariance entries also relative
to sqrt(C_ii C_jj) (the scale each entry lives on), theta also in posterior standard deviations. chi^2 reduced
cancels ~5 digits (y^T y ~ 1e5 chi^2): the reference's own rounding of it is up to ~7e-11 and the kernel's as large
(it makes the same BLAS calls, but its theta comes from another inverse), so without an active bound both are held
to P eps y^T y / chi^2 (``_chi2_rounding``: ~1e-9) of chi^2 from a long-double solve (``_chi2_reduced_truth``), not to
each other (their difference is the sum of two roundings, design note 52).

The SPD helpers and the bounded solve on their own (numpy's and scipy's answers, the reference's LAPACK bits):
tests/core/test_spd_and_bounded_solve.py.
"""

from dataclasses import replace

import numpy as np
import pytest
from frictionwatch.core.monitor.identify import bounded_solve as bs
from frictionwatch.core.monitor.identify import posterior as pk
from frictionwatch.core.monitor.identify import spd
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from frictionwatch.core.monitor.identify.bounded_solve import bounded_solve_nnls
from frictionwatch.core.monitor.identify.posterior import posterior_from_normal, posterior_from_normal_reference
from frictionwatch.core.monitor.identify.spd import (
    lapack_inverse_of_sum,
    lapack_spd_inverse_of_sum,
    spd_inverse,
    spd_inverse_decoupled,
)
from numpy.testing import assert_allclose, assert_array_equal

SIZES = {"genset-v20": (47, 24, 49), "k9k-4cyl": (29, 24, 47), "deutz-1cyl": (28, 22, 47)}
FIELDS = ("params", "covariance", "cov_statistical", "chi2_reduced", "weight", "cov_reference")


def _problem(seed, p, n_free, r, theta_true=None, cycles=6, noise=1.0, prior_rel=0.3):
    """A monitor-like accumulator, prior normal equations and bounds (seeded)."""
    rng = np.random.default_rng(seed)
    nb = p - n_free
    col_scale = np.concatenate([np.logspace(-4, 2, nb), np.logspace(-1, 1, n_free)])
    if theta_true is None:
        theta_true = np.concatenate([1.0 + 0.3 * rng.random(nb), rng.normal(size=n_free)])
    acc = Accumulator.empty(p, r)
    mix = np.eye(p) + 0.3 * rng.normal(size=(p, p))  # correlated columns: scaled condition ~1e2..1e4
    base = rng.normal(size=(r, p)) @ mix
    for _ in range(cycles):
        a = (base + 0.3 * rng.normal(size=(r, p))) * col_scale
        y = a @ theta_true + noise * rng.normal(size=r)
        inv_sigma = 1.0 / (0.5 + rng.random(r))
        acc = acc.update(a, y, inv_sigma, 0.98, reference_rows=1)
    # a prior per parameter (sd prior_rel around 1 for coefficients, 0 for nuisances), three share-like rows
    w = np.eye(p) / prior_rel
    theta0 = np.concatenate([np.ones(nb), np.zeros(n_free)])
    share = np.zeros((3, p))
    share[:, :nb] = rng.random((3, nb)) * col_scale[:nb]
    rows = np.vstack([w, share])
    tgt = np.concatenate([w @ theta0, share @ theta_true])
    n_pr = rows.T @ rows
    r_pr = rows.T @ tgt
    sys_var = (0.1 + rng.random(r)) ** 2
    lower = np.concatenate([np.zeros(nb), np.full(n_free, -np.inf)])
    return acc, n_pr, r_pr, sys_var, lower


def _minimiser_long_double(acc, n_pr, r_pr):
    """The reference's unconstrained minimiser (unit-diagonal form, its 1e-12 ridge), solved by Gaussian elimination
    with partial pivoting in long double (x87: eps ~1e-19, the float64 roundings vanish)."""
    p = acc.info.shape[0]
    a = (acc.info + n_pr).astype(np.longdouble)
    b = (acc.rhs + r_pr).astype(np.longdouble)
    d = 1.0 / np.sqrt(np.diag(a))
    m = np.concatenate([a * d[:, None] * d[None, :] + np.longdouble(1e-12) * np.eye(p, dtype=np.longdouble),
                        (b * d)[:, None]], axis=1)
    for k in range(p):
        piv = k + int(np.argmax(np.abs(m[k:, k])))
        m[[k, piv]] = m[[piv, k]]
        m[k + 1:] -= np.outer(m[k + 1:, k] / m[k, k], m[k])
    x = np.zeros(p, dtype=np.longdouble)
    for k in range(p - 1, -1, -1):
        x[k] = (m[k, p] - m[k, k + 1:p] @ x[k + 1:]) / m[k, k]
    return x * d


def _chi2_reduced_truth(acc, n_pr, r_pr):
    """chi^2 reduced at ``_minimiser_long_double``, in long double."""
    p = acc.info.shape[0]
    theta = _minimiser_long_double(acc, n_pr, r_pr)
    chi2 = (np.longdouble(acc.yty) - 2 * theta @ acc.rhs.astype(np.longdouble)
            + theta @ acc.info.astype(np.longdouble) @ theta)
    return float(chi2 / (acc.rows - p))


def _chi2_rounding(acc, chi2_reduced):
    """The relative rounding a float64 chi^2 = y^T y - 2 theta^T r + theta^T N theta can carry: its terms live on the
    scale of y^T y, so one rounding each of the P-term products is P eps y^T y, relative to chi^2 that much over
    chi^2 (a cancellation of ~3e4-1e5 here). Seen: up to 5.7 eps y^T y / chi^2 (genset-v20 seed 0, P 47, on an AMD
    EPYC's OpenBLAS; it varies from call to call with the buffers' alignment), so 1e-10 fixed was a machine's
    rounding, not a bound; a wrong theta shows in the posterior's own comparisons (1e-10 of its sigma)."""
    p = acc.info.shape[0]
    return p * np.finfo(float).eps * acc.yty / (chi2_reduced * (acc.rows - p))


def _assert_same_posterior(got, want, rtol=1e-10, skip=()):
    for f in FIELDS:
        if f in skip:
            continue
        g, w = np.asarray(getattr(got, f)), np.asarray(getattr(want, f))
        assert g.shape == w.shape, f
        assert_allclose(g, w, rtol=0, atol=rtol * max(float(np.max(np.abs(w))), 1e-300), err_msg=f)
    for f in ("covariance", "cov_statistical", "cov_reference"):
        g, w = getattr(got, f), getattr(want, f)
        s = np.sqrt(np.outer(np.abs(np.diag(w)), np.abs(np.diag(w))))
        assert np.max(np.abs(g - w) / s) < rtol, f
    sd = np.sqrt(np.diag(want.cov_statistical))
    assert np.max(np.abs(got.params - want.params) / sd) < rtol


@pytest.mark.parametrize("engine", list(SIZES))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_posterior_matches_reference_without_active_bound(engine, seed):
    p, n_free, r = SIZES[engine]
    acc, n_pr, r_pr, sys_var, lower = _problem(seed, p, n_free, r)
    status = pk.posterior_kernel(acc.info, acc.rhs, acc.yty, acc.rows, acc.sys_map, acc.info_reference, n_pr, r_pr,
                                 sys_var, lower, 1e12)[0]
    assert status == bs.OK  # the fast branch is what is tested here
    got = posterior_from_normal(acc, n_pr, r_pr, sys_var, lower)
    want = posterior_from_normal_reference(acc, n_pr, r_pr, sys_var, lower)
    _assert_same_posterior(got, want, skip=("chi2_reduced",))
    truth = _chi2_reduced_truth(acc, n_pr, r_pr)
    rtol = _chi2_rounding(acc, truth)
    assert_allclose(got.chi2_reduced, truth, rtol=rtol)
    assert_allclose(want.chi2_reduced, truth, rtol=rtol)
    assert np.all(got.params[: p - n_free] > 0)


@pytest.mark.parametrize("engine", ["genset-v20", "deutz-1cyl"])
def test_posterior_with_an_active_bound_uses_nnls(engine):
    p, n_free, r = SIZES[engine]
    nb = p - n_free
    rng = np.random.default_rng(7)
    theta_true = np.concatenate([1.0 + 0.3 * rng.random(nb), rng.normal(size=n_free)])
    theta_true[[nb - 1, nb - 4]] = -3.0  # the data (large columns) want two coefficients below their bound
    acc, n_pr, r_pr, sys_var, lower = _problem(7, p, n_free, r, theta_true=theta_true, noise=0.01)
    status = pk.posterior_kernel(acc.info, acc.rhs, acc.yty, acc.rows, acc.sys_map, acc.info_reference, n_pr, r_pr,
                                 sys_var, lower, 1e12)[0]
    assert status == bs.NEEDS_BOUND
    got = posterior_from_normal(acc, n_pr, r_pr, sys_var, lower)
    want = posterior_from_normal_reference(acc, n_pr, r_pr, sys_var, lower)
    assert_array_equal(got.params, want.params)  # the same NNLS call
    assert got.params[nb - 1] == 0.0 and got.params[nb - 4] == 0.0
    _assert_same_posterior(got, want)


def test_posterior_fallbacks_are_the_reference_exactly():
    p, n_free, r = SIZES["k9k-4cyl"]
    acc, n_pr, r_pr, sys_var, lower = _problem(3, p, n_free, r)
    # no prior at all: the reference information (one mean-balance row per cycle) is singular -> pseudo-inverse
    zero = np.zeros((p, p))
    theta = bounded_solve_nnls(acc.info, acc.rhs, lower)
    status = pk.posterior_moments_kernel(acc.info, acc.rhs, acc.yty, acc.rows, acc.sys_map, acc.info_reference, zero,
                                         sys_var, theta, 1e12)[0]
    assert status == bs.FALLBACK
    got = posterior_from_normal(acc, zero, np.zeros(p), sys_var, lower)
    want = posterior_from_normal_reference(acc, zero, np.zeros(p), sys_var, lower)
    for f in FIELDS:
        assert_array_equal(getattr(got, f), getattr(want, f), err_msg=f)
    # positive definite but so nearly singular that the reference's trace bound is past its pseudo-inverse switch
    # (condition ~4e13 > REFERENCE_MAX_CONDITION): left to the reference
    weak = 1e-9 * n_pr
    ri = acc.info_reference + weak
    assert spd.cholesky(ri, np.empty((p, p))) < bs.PIVOT_RATIO_MIN
    got = posterior_from_normal(acc, weak, r_pr, sys_var, lower)
    want = posterior_from_normal_reference(acc, weak, r_pr, sys_var, lower)
    for f in FIELDS:
        assert_array_equal(getattr(got, f), getattr(want, f), err_msg=f)
    # an indefinite information matrix (np.linalg.inv path of the reference)
    bad = n_pr.copy()
    bad[0, 0] = -2.0 * acc.info[0, 0] - 1.0
    status = pk.posterior_kernel(acc.info, acc.rhs, acc.yty, acc.rows, acc.sys_map, acc.info_reference, bad, r_pr,
                                 sys_var, lower, 1e12)[0]
    assert status == bs.FALLBACK
    for lo in (lower, -np.inf):  # the NNLS path fails on the indefinite bounded block like the reference does
        try:
            want = posterior_from_normal_reference(acc, bad, r_pr, sys_var, lo)
        except np.linalg.LinAlgError:
            with pytest.raises(np.linalg.LinAlgError):
                posterior_from_normal(acc, bad, r_pr, sys_var, lo)
            continue
        got = posterior_from_normal(acc, bad, r_pr, sys_var, lo)
        for f in FIELDS:
            assert_array_equal(getattr(got, f), getattr(want, f), err_msg=f)


def _balance_against_priors(seed, p, n_free, r, cycles):
    """``_problem`` whose reference information is the mean-balance row of ``cycles`` cycles (no forgetting) on the
    coefficients only (the nuisances a decoupled diagonal tail, as the monitor's): its condition grows with the
    cycles against the fixed priors (design note 75)."""
    acc, n_pr, r_pr, sys_var, lower = _problem(seed, p, n_free, r)
    rng = np.random.default_rng(seed + 50)
    nb = p - n_free
    m = (1.0 + 1e-3 * rng.normal(size=(200, nb))) * np.logspace(-4, 2, nb)  # 200 rows stand for the cycles
    ref = np.zeros((p, p))
    ref[:nb, :nb] = (cycles / 200) * (m.T @ m) / 0.05**2
    return replace(acc, info_reference=ref), n_pr, r_pr, sys_var, lower


@pytest.mark.parametrize("cycles", [10, 10_000, 50_000])
def test_reference_covariance_is_the_reference_bits_at_any_condition(cycles):
    """The reference information's factor was the kernel's FALLBACK below pivot ratio 1e-4 (k9k: 64 of 240 solves);
    now its inverse is the reference's own LAPACK calls: equal bits, however small the pivot ratio."""
    p, n_free, r = SIZES["k9k-4cyl"]
    acc, n_pr, r_pr, sys_var, lower = _balance_against_priors(5, p, n_free, r, cycles)
    ri = acc.info_reference + n_pr
    ratio = spd.cholesky(ri[: p - n_free, : p - n_free], np.empty((p - n_free, p - n_free)))
    if cycles >= 10_000:
        assert 0.0 < ratio < bs.PIVOT_RATIO_MIN  # the case that fell back
    got = np.empty((p, p))
    assert lapack_inverse_of_sum(acc.info_reference, n_pr, got, 1.0) == 0
    want = spd_inverse_decoupled(ri)
    assert_array_equal(got, want)
    # the reference itself: numpy's inverse to rounding x the scaled condition (eps x cond <~ 1e-8 here)
    d = np.sqrt(np.diag(ri))
    cond = np.linalg.cond(ri / np.outer(d, d))
    inv = np.linalg.inv(ri)
    assert np.max(np.abs(want - inv) / np.sqrt(np.outer(np.diag(inv), np.diag(inv)))) < 1e-14 * cond
    status = pk.posterior_kernel(acc.info, acc.rhs, acc.yty, acc.rows, acc.sys_map, acc.info_reference, n_pr, r_pr,
                                 sys_var, lower, 1e12)[0]
    assert status == bs.OK
    got = posterior_from_normal(acc, n_pr, r_pr, sys_var, lower)
    want = posterior_from_normal_reference(acc, n_pr, r_pr, sys_var, lower)
    _assert_same_posterior(got, want, skip=("chi2_reduced",))
    # cov_reference: the same inverse x max(1, chi2 reduced), the kernel's chi2 against the reference's (rounding)
    assert_allclose(got.cov_reference, want.cov_reference, rtol=1e-10, atol=0)


def test_reference_inverse_refuses_what_the_reference_refuses():
    """Not positive definite, in the coupled head (LAPACK's info) or in the decoupled tail: both refuse (the
    kernel's FALLBACK, the reference's pseudo-inverse)."""
    p, n_free, r = SIZES["k9k-4cyl"]
    acc, n_pr, _, _, _ = _balance_against_priors(2, p, n_free, r, 100)
    ri = acc.info_reference + n_pr
    out = np.empty((p, p))
    for i in (0, p - 1):  # a head entry, a tail entry
        b = n_pr.copy()
        b[i, i] = -ri[i, i] - 1.0 + n_pr[i, i]
        assert spd_inverse_decoupled(acc.info_reference + b) is None
        assert lapack_inverse_of_sum(acc.info_reference, b, out, 1.0) == -1


def _balance_in_information(seed, p, n_free, r, cycles):
    """``_problem`` with a mean-balance-like row of ``cycles`` cycles (no forgetting) in the accumulated information
    itself (rhs, y^T y and the row count with it): N's smallest pivot ratio falls ~1/cycles against the fixed
    priors, as genset-v20's does over a long run (design note 80)."""
    acc, n_pr, r_pr, sys_var, lower = _problem(seed, p, n_free, r)
    rng = np.random.default_rng(seed + 60)
    nb = p - n_free
    m = (1.0 + 1e-3 * rng.normal(size=(200, nb))) * np.logspace(-4, 2, nb)  # 200 rows stand for the cycles
    y = m @ (1.0 + 0.3 * rng.random(nb)) + 0.05 * rng.normal(size=200)
    w = (cycles / 200) / 0.05**2
    info, rhs = acc.info.copy(), acc.rhs.copy()
    info[:nb, :nb] += w * (m.T @ m)
    rhs[:nb] += w * (m.T @ y)
    return replace(acc, info=info, rhs=rhs, yty=acc.yty + w * (y @ y), rows=acc.rows + cycles), n_pr, r_pr, sys_var, lower


def _params_truth(acc, n_pr, r_pr):
    """``_minimiser_long_double`` rounded to float64."""
    return _minimiser_long_double(acc, n_pr, r_pr).astype(np.float64)


@pytest.mark.parametrize(("engine", "seed", "cycles"),
                         [("genset-v20", 1, 100_000), ("k9k-4cyl", 1, 10_000_000), ("genset-v20", 1, 10)])
def test_information_inverse_is_the_reference_bits_at_low_pivot_ratios(engine, seed, cycles):
    """N's factor was the kernel's FALLBACK below pivot ratio 1e-4 (a long genset-v20 run: every smoothed solve
    from cycle ~893 of 1,000); now N^-1 is the reference's own LAPACK calls: cov_statistical is the reference's bits
    x max(1, chi2), and params differ from the reference by roundings as large as the reference's own (both against a
    long-double solve: ~1e-15 x the unit-diagonal condition of max |params|, note 80)."""
    p, n_free, r = SIZES[engine]
    acc, n_pr, r_pr, sys_var, lower = _balance_in_information(seed, p, n_free, r, cycles)
    info = acc.info + n_pr
    inv = np.empty((p, p))
    ratio = lapack_spd_inverse_of_sum(acc.info, n_pr, inv, 1.0)
    assert_array_equal(inv, spd_inverse(info))
    assert_allclose(ratio, spd.cholesky(info, np.empty((p, p))), rtol=1e-8)  # the unit-diagonal factor's ratio
    if cycles >= 100_000:
        assert 0.0 < ratio < bs.PIVOT_RATIO_MIN  # the case that fell back
    status = pk.posterior_kernel(acc.info, acc.rhs, acc.yty, acc.rows, acc.sys_map, acc.info_reference, n_pr, r_pr,
                                 sys_var, lower, 1e12)[0]
    assert status == bs.OK
    got = posterior_from_normal(acc, n_pr, r_pr, sys_var, lower)
    want = posterior_from_normal_reference(acc, n_pr, r_pr, sys_var, lower)
    # the same inverse: cov_statistical / max(1, chi2) equal to the last bit, when both chi2 are <= 1 equal outright
    assert_allclose(got.cov_statistical / max(1.0, got.chi2_reduced), want.cov_statistical / max(1.0, want.chi2_reduced),
                    rtol=1e-15, atol=0)
    truth = _params_truth(acc, n_pr, r_pr)
    scale = np.max(np.abs(truth))
    err_kernel = np.max(np.abs(got.params - truth)) / scale
    err_reference = np.max(np.abs(want.params - truth)) / scale
    d = np.sqrt(np.diag(info))
    cond = np.linalg.cond(info / np.outer(d, d))
    # as exact as the reference: both within the bound of note 80, ~eps x the unit-diagonal condition, not the pivot
    # ratio (3.9e-13 at ratio 0.16): kernel 0.62-2.22, reference 0.54-1.18 x 1e-15 cond on these cases. Their
    # ratio is no bound: k9k's 10^7 cycles read 4.1 on an AMD EPYC's OpenBLAS with one thread, 1.35 with two
    bound = 4e-15 * cond
    assert err_kernel < bound and err_reference < bound
    # chi^2 is stationary at the minimiser: the params' roundings move it to second order only
    assert_allclose(got.chi2_reduced, want.chi2_reduced, rtol=1e-8)
    sd = np.sqrt(np.diag(want.cov_statistical))
    assert np.max(np.abs(got.params - want.params) / sd) < 1e-5


def test_posterior_rejects_wrong_shapes():
    p, n_free, r = SIZES["deutz-1cyl"]
    acc, n_pr, r_pr, sys_var, lower = _problem(0, p, n_free, r)
    with pytest.raises(ValueError, match="sys_var"):
        posterior_from_normal(acc, n_pr, r_pr, sys_var[:-1], lower)
    with pytest.raises(ValueError, match="n_pr"):
        posterior_from_normal(acc, n_pr[:-1], r_pr, sys_var, lower)


def test_posterior_with_a_decoupled_reference_tail_matches_reference():
    # the monitor's reference information: the mean-balance row has no nuisance columns and the nuisance priors
    # are diagonal, so the reference covariance is block diagonal (the kernel inverts the head only)
    p, n_free, r = SIZES["genset-v20"]
    nb = p - n_free
    acc, n_pr, r_pr, sys_var, lower = _problem(4, p, n_free, r)
    rng = np.random.default_rng(4)
    last = rng.normal(size=nb) * np.logspace(-4, 2, nb)
    ref_rows = np.zeros((1, p))
    ref_rows[0, :nb] = last
    acc = Accumulator(acc.info, acc.rhs, acc.yty, acc.weight, acc.rows, acc.sys_map, 3.0 * ref_rows.T @ ref_rows)
    assert spd.decoupled_tail(acc.info_reference, n_pr) == nb
    got = posterior_from_normal(acc, n_pr, r_pr, sys_var, lower)
    want = posterior_from_normal_reference(acc, n_pr, r_pr, sys_var, lower)
    # chi^2 > 1 here scales cov_statistical and cov_reference: they carry chi^2's rounding (1.2e-10 on an AMD EPYC's
    # OpenBLAS with one thread), which has its own bound; the rest is compared with it taken out
    assert_allclose(got.chi2_reduced, want.chi2_reduced, rtol=2.0 * _chi2_rounding(acc, want.chi2_reduced))
    k = max(1.0, want.chi2_reduced) / max(1.0, got.chi2_reduced)
    cov_stat = got.cov_statistical * k
    got = replace(got, chi2_reduced=want.chi2_reduced, cov_statistical=cov_stat, cov_reference=got.cov_reference * k,
                  covariance=got.covariance - got.cov_statistical + cov_stat)
    _assert_same_posterior(got, want)


def test_posterior_inputs_of_other_types_are_converted():
    p, n_free, r = SIZES["deutz-1cyl"]
    acc, n_pr, r_pr, sys_var, lower = _problem(5, p, n_free, r)
    want = posterior_from_normal(acc, n_pr, r_pr, sys_var, lower)
    f_acc = Accumulator(acc.info, acc.rhs, acc.yty, acc.weight, acc.rows, np.asfortranarray(acc.sys_map),
                        acc.info_reference)
    read_only = lower.copy()
    read_only.flags.writeable = False
    for args in ((f_acc, n_pr, r_pr, sys_var, lower), (acc, n_pr.tolist(), r_pr, sys_var, lower),
                 (acc, n_pr, r_pr, sys_var, read_only), (acc, np.asfortranarray(n_pr), r_pr, sys_var, lower)):
        _assert_same_posterior(posterior_from_normal(*args), want)
    # a scalar bound broadcasts (all bounded: here some coefficients would go negative -> NNLS, as the reference)
    _assert_same_posterior(posterior_from_normal(acc, n_pr, r_pr, sys_var, -10.0),
                           posterior_from_normal_reference(acc, n_pr, r_pr, sys_var, -10.0))
    status = pk.posterior_kernel(acc.info, acc.rhs, acc.yty, acc.rows, acc.sys_map, acc.info_reference, n_pr,
                                 r_pr, sys_var[:-1], lower, 1e12)[0]
    assert status == bs.BAD_SHAPE


def test_returned_arrays_are_new():
    p, n_free, r = SIZES["genset-v20"]
    acc, n_pr, r_pr, sys_var, lower = _problem(6, p, n_free, r)
    a = posterior_from_normal(acc, n_pr, r_pr, sys_var, lower)
    b = posterior_from_normal(acc, n_pr, r_pr, sys_var, lower)
    arrays = [a.params, a.covariance, a.cov_statistical, a.cov_reference]
    for x in arrays:
        for y in [b.params, b.covariance, b.cov_statistical, b.cov_reference, acc.info, acc.sys_map,
                  acc.info_reference, n_pr]:
            assert not np.shares_memory(x, y)
    for i, x in enumerate(arrays):
        for y in arrays[i + 1:]:
            assert not np.shares_memory(x, y)


def test_negative_or_nan_systematic_variance_is_formed_like_the_reference():
    # the square-root form W^T W needs S >= 0; otherwise (G S) G^T as the reference computes it (NaN propagates)
    p, n_free, r = SIZES["k9k-4cyl"]
    acc, n_pr, r_pr, sys_var, lower = _problem(8, p, n_free, r)
    negative = sys_var.copy()
    negative[3] = -0.5 * negative[3]
    _assert_same_posterior(posterior_from_normal(acc, n_pr, r_pr, negative, lower),
                           posterior_from_normal_reference(acc, n_pr, r_pr, negative, lower))
    bad = sys_var.copy()
    bad[0] = np.nan
    got = posterior_from_normal(acc, n_pr, r_pr, bad, lower)
    want = posterior_from_normal_reference(acc, n_pr, r_pr, bad, lower)
    assert_array_equal(np.isnan(got.covariance), np.isnan(want.covariance))
    assert_array_equal(got.cov_statistical, got.cov_statistical.T)
