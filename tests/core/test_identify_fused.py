"""identify_cycle's fused accumulation step against the chain it replaces (design note 63):
core.monitor.identify.identification.accumulate_cycle, one kernel (cycle terms, raw rows, fold, speed budget)
against accumulate_cycle_reference (Accumulator.cycle_terms, raw_rows, Accumulator.fold, speed_budget). The kernel
runs the same BLAS calls and single roundings, so it is held to rtol 1e-12 (what bench_monitor_against holds a whole
cycle's outcome to); the sizes are the monitor's (k9k-4cyl 47 rows x 29 parameters, genset-v20 49 x 47). And the
two shared posteriors (core.monitor.identify.shared_posterior.shared_posteriors, one kernel: the Eq. 6 shares, their
prior rows, both posteriors) against shared_posteriors_reference."""

from types import SimpleNamespace

import numpy as np
import pytest
from frictionwatch.core.monitor.identify.accumulate import Accumulator, ResidualStats
from frictionwatch.core.monitor.identify.accumulate_kernels import cycle_step_kernel
from frictionwatch.core.monitor.identify.identification import accumulate_cycle, accumulate_cycle_reference
from frictionwatch.core.monitor.identify.posterior_kernels import NEEDS_BOUND, OK
from frictionwatch.core.monitor.identify.priors import PriorNormal
from frictionwatch.core.monitor.identify.shared_posterior import (
    posterior_pair_kernel,
    shared_posteriors,
    shared_posteriors_reference,
)
from numpy.testing import assert_allclose, assert_array_equal

from tests.core.test_posterior_kernels import _problem

SIZES = {"k9k-4cyl": (47, 29), "genset-v20": (49, 47)}
RTOL = 1e-12


def _white(rng, r, p, zero_weight=True):
    m = (r - 1) // 2
    a = rng.normal(size=(r, p)) * np.logspace(-4, 2, p)
    inv_sigma = 1.0 / (0.5 + rng.random(r))
    if zero_weight:
        inv_sigma[3] = 0.0  # a row that is not there: zeros in the raw rows
        a[3] = 0.0
    stats = ResidualStats(np.zeros(m, complex), rng.random(m) * 1e-2, 0.0, 0.0, 5)
    return SimpleNamespace(a=a, y=rng.normal(size=r) * 10.0, inv_sigma=inv_sigma, sys_var=rng.random(r),
                           freq=np.linspace(50.0, 900.0, m), stats=stats)


def _running(rng, r, p, cycles=5, lam=0.97):
    """An accumulator with its raw rows kept, as the monitor's after its warm-up."""
    acc = Accumulator.empty(p, r)
    for _ in range(cycles):
        acc = accumulate_cycle_reference(acc, _white(rng, r, p), lam, True, np.zeros(p), 0.003, np.ones(1))[1]
    return acc


def _assert_same(got, want, name):
    if want is None or isinstance(want, (bool, np.bool_)):
        assert got == want, name
    elif np.ndim(want) == 0:
        assert_allclose(got, want, rtol=RTOL, err_msg=name)
    else:
        assert np.shape(got) == np.shape(want), name
        w = np.abs(np.asarray(want))
        big = float(np.max(w[np.isfinite(w)], initial=0.0))
        assert_allclose(got, want, rtol=RTOL, atol=RTOL * max(big, 1e-300), err_msg=name)  # NaN where NaN


def _assert_same_accumulator(got, want):
    for f in ("info", "rhs", "yty", "weight", "rows", "sys_map", "info_reference", "raw_rows", "raw_target",
              "raw_weight"):
        _assert_same(getattr(got, f), getattr(want, f), f)


@pytest.mark.parametrize("engine", list(SIZES))
@pytest.mark.parametrize("fold", [True, False])
def test_accumulation_step_equals_its_chain(engine, fold):
    r, p = SIZES[engine]
    rng = np.random.default_rng(r + p + fold)
    acc = _running(rng, r, p)
    white = _white(rng, r, p)
    m = white.freq.shape[0]
    params = rng.uniform(0.5, 1.5, p)
    harmonics = rng.normal(size=m) + 1j * rng.normal(size=m)
    assert cycle_step_kernel(white.a, white.y, white.inv_sigma, 0.98, fold,
                             (acc.info, acc.rhs, acc.sys_map, acc.info_reference, acc.raw_rows, acc.raw_target),
                             acc.raw_weight, params, (white.sys_var, white.stats.var, white.freq, harmonics),
                             0.003)[0]  # the kernel's path is the one compared
    got = accumulate_cycle(acc, white, 0.98, fold, params, 0.003, harmonics)
    want = accumulate_cycle_reference(acc, white, 0.98, fold, params, 0.003, harmonics)
    for f in ("info", "rhs", "yty", "rows", "sys_map", "info_reference"):
        _assert_same(getattr(got[0], f), getattr(want[0], f), f)
    _assert_same_accumulator(got[1], want[1])
    if not fold:
        assert got[1] is acc
    _assert_same(got[2], want[2], "budget")
    # the budget is the persistent residual's for some speed rows and the model floor for others here
    assert np.any(got[2][:m] != white.sys_var[:m])


@pytest.mark.parametrize("fold", [True, False])
def test_accumulation_step_from_a_fresh_accumulator_is_the_chain(fold):
    """A fresh (or an old saved) accumulator keeps no raw rows: the warm-up's steps (no fold: the budget is the
    noise model's) and the first fold (raw rows started from that cycle's) take the kernel too, and so does the
    accumulator the kernel made."""
    r, p = SIZES["k9k-4cyl"]
    rng = np.random.default_rng(3)
    harmonics = np.ones((r - 1) // 2, complex)
    acc = Accumulator.empty(p, r)
    for _ in range(3):
        white = _white(rng, r, p)
        arrays = (acc.info, acc.rhs, acc.sys_map, acc.info_reference,
                  *((acc.raw_rows, acc.raw_target) if acc.raw_rows is not None else (np.empty((0, 0)), np.empty(0))))
        assert cycle_step_kernel(white.a, white.y, white.inv_sigma, 0.98, fold, arrays, 1.0, np.ones(p),
                                 (white.sys_var, white.stats.var, white.freq, harmonics), 0.003)[0]
        got = accumulate_cycle(acc, white, 0.98, fold, np.ones(p), 0.003, harmonics)
        want = accumulate_cycle_reference(acc, white, 0.98, fold, np.ones(p), 0.003, harmonics)
        _assert_same_accumulator(got[1], want[1])
        _assert_same(got[2], want[2], "budget")
        acc = got[1]
    assert (acc.raw_rows is not None) == fold


def test_accumulation_step_with_wrong_inputs_raises_as_the_chain():
    r, p = SIZES["k9k-4cyl"]
    rng = np.random.default_rng(3)
    white = _white(rng, r, p)
    harmonics = np.ones(white.freq.shape[0], complex)
    acc = _running(rng, r, p)
    with pytest.raises(ValueError, match="rows must have shape"):
        accumulate_cycle(acc, _white(rng, r, p + 1), 0.98, True, np.ones(p), 0.003, harmonics)
    with pytest.raises(ValueError, match="forgetting factor"):
        accumulate_cycle(acc, white, 1.5, True, np.ones(p), 0.003, harmonics)


def _shared_inputs(seed, p, n_free, r, z, theta_true=None):
    acc, n_pr, r_pr, sys_var, lower = _problem(seed, p, n_free, r, theta_true=theta_true)
    rng = np.random.default_rng(seed + 100)
    cycle = Accumulator.of_terms(Accumulator.empty(p, r).cycle_terms(
        acc.sys_map.T * rng.uniform(0.5, 2.0, r)[:, None], rng.normal(size=r), 1.0 / (0.5 + rng.random(r)), 1))
    prior = PriorNormal((0.3, 0.1, 0.15), n_pr, r_pr)
    nb = p - n_free
    cyl_rows = rng.random((z, nb)) * np.logspace(-2, 1, nb)
    return acc, cycle, sys_var, prior, cyl_rows, lower, rng


def _assert_same_shared(got, want):
    for (share_g, post_g), (share_w, post_w) in zip(got, want, strict=True):
        for f in ("friction_mean", "sigma"):
            _assert_same(getattr(share_g, f), getattr(share_w, f), f)
        assert_array_equal(share_g.motored, share_w.motored)
        for f in ("params", "covariance", "cov_statistical", "chi2_reduced", "weight", "cov_reference"):
            _assert_same(getattr(post_g, f), getattr(post_w, f), f)


@pytest.mark.parametrize("engine, sizes", [("k9k-4cyl", (29, 24, 47, 4)), ("genset-v20", (47, 24, 49, 20))])
@pytest.mark.parametrize("balance", [1.0, float("nan")])
def test_shared_posteriors_equal_their_chain(engine, sizes, balance):
    p, n_free, r, z = sizes
    acc, cycle, sys_var, prior, cyl_rows, lower, rng = _shared_inputs(1, p, n_free, r, z)
    t_s, t_c = rng.uniform(20.0, 30.0, z), rng.uniform(20.0, 30.0, z)
    t_c[0] = 0.5  # a motored cylinder in this cycle
    sys_c = rng.random(r)
    if np.isfinite(balance):  # a balance near what the rows give at parameters near 1 (no bound active)
        balance = float((cyl_rows @ np.full(p - n_free, 1.15)).sum())
    # a balance that is not finite: no share rows (the prior alone) in both problems
    args = ((acc, cycle), (sys_var, sys_c), prior, cyl_rows, (balance, balance), (t_s, t_c), 1.7, 0.15, lower)
    statuses = [res[2][0] for res in posterior_pair_kernel(
        (acc.info, acc.rhs, acc.yty, acc.rows, acc.sys_map, acc.info_reference, sys_var),
        (cycle.info, cycle.rhs, cycle.yty, cycle.rows, cycle.sys_map, cycle.info_reference, sys_c),
        (prior.info, prior.rhs, cyl_rows), (balance, balance), (t_s, t_c), (1.7, 0.15, 0.3, 0.15), lower)]
    assert statuses[0] == OK  # the kernel's own posterior is compared (the cycle's may need its bound)
    got = shared_posteriors(*args)
    want = shared_posteriors_reference(*args)
    _assert_same_shared(got, want)
    assert got[1][0].motored[0] and not got[1][0].motored[1:].any()
    assert np.isfinite(got[0][0].friction_mean).all() == np.isfinite(balance)


def test_shared_posteriors_with_an_active_bound_take_the_nnls_path():
    p, n_free, r, z = 47, 24, 49, 20
    nb = p - n_free
    rng = np.random.default_rng(7)
    theta_true = np.concatenate([1.0 + 0.3 * rng.random(nb), rng.normal(size=n_free)])
    theta_true[[nb - 1, nb - 4]] = -3.0  # the data want two coefficients below their bound
    acc, cycle, sys_var, prior, cyl_rows, lower, rng = _shared_inputs(7, p, n_free, r, z, theta_true=theta_true)
    t = rng.uniform(20.0, 30.0, z)
    args = ((acc, cycle), (sys_var, rng.random(r)), prior, cyl_rows * 1e-6, (1.0, 1.0), (t, t), 1.7, 0.15, lower)
    status = posterior_pair_kernel(
        (acc.info, acc.rhs, acc.yty, acc.rows, acc.sys_map, acc.info_reference, sys_var),
        (cycle.info, cycle.rhs, cycle.yty, cycle.rows, cycle.sys_map, cycle.info_reference, args[1][1]),
        (prior.info, prior.rhs, args[3]), (1.0, 1.0), (t, t), (1.7, 0.15, 0.3, 0.15), lower)[0][2][0]
    assert status == NEEDS_BOUND
    got = shared_posteriors(*args)
    _assert_same_shared(got, shared_posteriors_reference(*args))
    assert got[0][1].params[nb - 1] == 0.0 and got[0][1].params[nb - 4] == 0.0


def test_shared_posteriors_with_wrong_shapes_raise_as_the_chain():
    p, n_free, r, z = 29, 24, 47, 4
    acc, cycle, sys_var, prior, cyl_rows, lower, rng = _shared_inputs(2, p, n_free, r, z)
    t = rng.uniform(20.0, 30.0, z)
    with pytest.raises(ValueError, match="cylinder rows"):
        shared_posteriors((acc, cycle), (sys_var, sys_var), prior, cyl_rows[:3], (40.0, 40.0), (t, t), 1.7, 0.15,
                          lower)
    with pytest.raises(ValueError, match="sys_var"):
        shared_posteriors((acc, cycle), (sys_var[:-1], sys_var), prior, cyl_rows, (40.0, 40.0), (t, t), 1.7, 0.15,
                          lower)
