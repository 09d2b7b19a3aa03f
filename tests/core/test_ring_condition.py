"""The ring-condition figure (core.monitor.checks.ring_condition): the siblings' minority rule, the combination of the
evidence, the window, the change's sigma; worked numbers by hand in each test."""

import dataclasses

import numpy as np
import pytest
from frictionwatch.core.monitor.checks.ring_condition import (
    SIBLINGS,
    SINCE,
    RingCondition,
    RingConditionSettings,
    SiblingWindow,
    combine,
    friction_excess,
    friction_excess_reference,
    leak_change,
    leak_effect,
    ring_condition,
    ring_condition_reference,
    sibling_excess,
    sibling_excess_reference,
    update_window,
    window_sigma,
)
from numpy.testing import assert_allclose

NAN = np.nan


@pytest.mark.parametrize("seed", range(4))
def test_all_cylinders_at_once_equal_one_at_a_time(seed):
    """sibling_excess (every cylinder's others in one matrix) against its reference (one cylinder at a time): equal
    within rtol 1e-12 and NaN in the same places, over engine sizes, missing values and ties."""
    rng = np.random.default_rng(seed)
    for _ in range(300):
        z = int(rng.integers(1, 24))
        x, se = rng.normal(0.0, 0.003, z), rng.uniform(0.0, 3e-4, z)
        x[rng.random(z) < 0.3 * (seed % 2)] = NAN
        se[rng.random(z) < 0.05 * (seed // 2)] = NAN
        if rng.random() < 0.2:
            x = np.round(x, 3)  # ties at the median
        for got, want in zip(sibling_excess(x, se, 0.001), sibling_excess_reference(x, se, 0.001), strict=True):
            assert_allclose(got, want, rtol=1e-12, atol=0.0, equal_nan=True)


def test_sibling_medians_where_a_cylinder_shares_its_value_and_some_are_not_finite():
    """The kernel takes a cylinder's others as the sorted finite values without one place of its value (design note
    145): cylinders that share it, an infinite one and odd and even counts of others read as the reference does."""
    cases = [np.array([0.001, 0.001, 0.001, 0.002]), np.array([0.001, 0.001, 0.002, 0.002, 0.003]),
             np.array([np.inf, 0.001, -0.002, 0.001, 0.0005, np.nan]), np.array([-np.inf, 0.0, 0.0, 0.001]),
             np.round(np.random.default_rng(3).normal(0.0, 0.002, 20), 3)]
    for x in cases:
        se = np.linspace(1e-5, 3e-4, x.shape[0])
        for got, want in zip(sibling_excess(x, se, 0.001), sibling_excess_reference(x, se, 0.001), strict=True):
            assert_allclose(got, want, rtol=1e-12, atol=0.0, equal_nan=True)


@pytest.mark.parametrize("z", [4, 6, 20])
def test_one_outlier_among_many_is_named_and_moves_no_other(z):
    rng = np.random.default_rng(z)
    x = rng.normal(0.0, 2e-4, z)
    x[z // 2] += 0.004
    dev, sig = sibling_excess(x, np.full(z, 1e-4), allowance=0.001)
    zz = dev / sig
    assert int(np.argmax(zz)) == z // 2 and zz[z // 2] > 3.0
    assert np.all(np.delete(zz, z // 2) < 1.0)
    # the spread: the allowance (the others scatter less); the centre's share pi/2 * (MAD spread^2 + se^2) / (z - 1)
    k = z // 2
    o = np.delete(x, k)
    mad = 1.4826 * np.median(np.abs(o - np.median(o)))
    want = np.sqrt(1e-8 + 1e-6 + np.pi / 2 * (mad ** 2 + 1e-8) / (z - 1))
    assert_allclose(sig[k], want, rtol=1e-12)
    assert_allclose(dev[k], x[k] - np.median(o), rtol=1e-12)


def test_three_cylinders_a_minority_needs_the_other_two_to_agree():
    # cylinder 2 off two that agree: named
    dev, sig = sibling_excess(np.array([0.0, 0.004, 0.0]), np.zeros(3), 0.001)
    # the suspect: 4 / 1 (units of 0.001); each of the others: -2 against a spread 4/sqrt2, its square and half
    # its square for the centre: -2 / sqrt(8 + 4)
    assert_allclose(dev / sig, [-2.0 / np.sqrt(12.0), 4.0, -2.0 / np.sqrt(12.0)], rtol=1e-9)
    # the other two disagree by as much as the suspect stands off: their disagreement is the spread
    dev, sig = sibling_excess(np.array([0.0, 0.004, 0.004 * 2]), np.zeros(3), 0.001)
    assert np.all(dev / sig < 3.0)


@pytest.mark.parametrize("z", [1, 2])
def test_no_minority_with_fewer_than_three(z):
    dev, sig = sibling_excess(np.arange(z) * 0.01, np.zeros(z), 0.001)
    assert np.all(np.isnan(dev)) and np.all(np.isnan(sig))


def test_window_is_the_running_mean_then_an_ewma():
    s = RingConditionSettings(window=4.0)
    x = np.array([[1.0, 2.0], [3.0, NAN], [5.0, 6.0], [7.0, 8.0], [9.0, 10.0]])
    w = SiblingWindow.empty(2)
    for row in x:
        w = update_window(w, row, s)
    # cylinder 1: running mean of 1, 3, 5, 7 = 4, then g = 1/4: 4 + (9 - 4)/4 = 5.25
    assert_allclose(w.mean[0], 5.25, rtol=1e-12)
    # cylinder 2: the NaN leaves it unchanged (2 after two cycles), then 2 + (6-2)/3, + (8 - m)/4, + (10 - m)/4
    m = 2.0 + (6.0 - 2.0) / 3.0
    m = m + (8.0 - m) / 4.0
    m = m + (10.0 - m) / 4.0
    assert_allclose(w.mean[1], m, rtol=1e-12)
    assert w.count == 5
    g = 0.25
    assert_allclose(window_sigma(w, s), np.sqrt(w.var * g / (2 - g)), rtol=1e-12)


def test_leak_effect_and_its_change_sigma():
    assert_allclose(leak_effect(np.array([-0.002, 0.0]), np.array([0.003, 0.0])), [0.0025, 0.0], rtol=1e-12)
    cov = np.zeros((2, 4, 4))
    cov[:, 1, 1], cov[:, 2, 2], cov[:, 1, 2], cov[:, 2, 1] = 4e-6, 9e-6, 3e-6, 3e-6
    ewma = np.array([[0.0, 0.0], [-0.001, 0.0], [0.002, 0.0], [0.0, 0.0]])
    c, s = leak_change(ewma, cov, 0.02 / 1.98, 100)
    var = 0.25 * (4e-6 + 9e-6 - 6e-6)  # correlated exponents: one trapped-mass error moves both the same way
    assert_allclose(c, [0.0015, 0.0], rtol=1e-12)
    assert_allclose(s, np.sqrt(var * (0.02 / 1.98 + 0.01)), rtol=1e-12)


def test_friction_excess_needs_two_measured_siblings():
    e, s = friction_excess(np.array([6.0, 5.0, 5.0, 4.0]), np.full(4, 0.2), np.array([True, True, False, True]))
    assert_allclose(e, [6.0 / 4.5 - 1.0, 5.0 / 5.0 - 1.0, NAN, 4.0 / 5.5 - 1.0], rtol=1e-12)
    assert_allclose(s[0], np.sqrt(0.04 + 0.04 / 2) / 4.5, rtol=1e-12)
    e, _ = friction_excess(np.array([6.0, 5.0, 5.0]), np.full(3, 0.2), np.array([True, True, False]))
    assert np.all(np.isnan(e))


def _same_excess(a: tuple, b: tuple) -> None:
    """Two (excess, sigma): within rtol 1e-12, NaN and inf where the other has them."""
    for x, y in zip(a, b, strict=True):
        assert_allclose(x, y, rtol=1e-12, atol=0.0, equal_nan=True)


def _excess_sets(seed: int):
    """Random (torque, sigma, measured) of 3-24 cylinders: healthy sets, torques about zero (references of either
    sign), NaN / inf torques and sigmas, exact-zero references, a few measured."""
    rng = np.random.default_rng(seed)
    for _ in range(200):
        z = int(rng.integers(3, 25))
        t = 5.0 + 0.3 * rng.standard_normal(z) if rng.random() < 0.5 else rng.standard_normal(z)
        s = 0.05 + 0.02 * rng.random(z)
        bad = rng.random(z) if rng.random() < 0.5 else np.ones(z)
        t[bad < 0.06] = NAN
        t[(bad >= 0.06) & (bad < 0.09)] = np.inf
        t[(bad >= 0.09) & (bad < 0.11)] = -np.inf
        s[bad < 0.04] = NAN
        s[(bad >= 0.11) & (bad < 0.13)] = np.inf
        measured = rng.random(z) < rng.choice([0.3, 0.8, 1.0])
        yield t, s, measured
    yield np.array([1.0, -1.0, 0.0, 2.0]), np.full(4, 0.1), np.ones(4, bool)  # cylinder 4's siblings' mean: 0
    yield np.array([1.0, -1.0, 0.0, 0.0]), np.full(4, 0.1), np.ones(4, bool)  # 0 / 0
    yield np.array([-5.0, -5.0, -6.0]), np.full(3, 0.1), np.ones(3, bool)  # negative references


@pytest.mark.parametrize("screened", [True, False])
@pytest.mark.parametrize("seed", range(3))
def test_friction_excess_in_one_reduction_is_the_per_cylinder_loop(seed, screened):
    """friction_excess (every leave-one-out mean in one reduction) against its reference (a np.mean per cylinder),
    screened and not: within rtol 1e-12 and NaN / inf in the same places, with non-finite torques and sigmas, zero
    and negative references; the comparison fails on a 1e-9 change."""
    n_nan = n_finite = 0
    for t, s, measured in _excess_sets(seed):
        new = friction_excess(t, s, measured, screened=screened)
        ref = friction_excess_reference(t, s, measured, screened=screened)
        _same_excess(new, ref)
        n_nan += int(np.isnan(new[0]).sum())
        ok = np.isfinite(ref[0]) & (ref[0] != 0.0)
        n_finite += int(ok.sum())
        if ok.any():
            with pytest.raises(AssertionError):
                _same_excess((new[0] * (1.0 + 1e-9), new[1]), ref)
    assert n_nan > 100 and n_finite > 1000, (n_nan, n_finite)  # the sets reach both the masks and the sums


def test_friction_excess_screens_what_its_unscreened_form_divides_by():
    t, s = np.array([1.0, -1.0, 0.0, 2.0, NAN]), np.array([0.1, 0.1, 0.1, 0.1, 0.1])
    e, g = friction_excess(t, s, np.array([True, True, True, True, False]))
    # references: (-1 + 0 + 2) / 3, (1 + 0 + 2) / 3, (1 - 1 + 2) / 3, 0 / 3: the last one's excess is not defined
    assert_allclose(e[:3], [1.0 / (1.0 / 3.0) - 1.0, -1.0 / 1.0 - 1.0, 0.0 / (2.0 / 3.0) - 1.0], rtol=1e-12)
    assert np.isnan(e[3]) and np.isnan(g[3]) and np.isnan(e[4])
    e, g = friction_excess(t, s, np.ones(5, bool), screened=False)  # the NaN torque enters every other's reference
    assert np.isnan(e).all() and np.isnan(g[:4]).all()
    assert_allclose(g[4], np.sqrt(0.01 + 0.01 / 4) / 0.5, rtol=1e-12)  # its own: the siblings' mean is 2 / 4
    e, g = friction_excess(t[:4], s[:4], np.ones(4, bool), screened=False)
    assert e[3] == np.inf and g[3] == np.inf  # 2 / 0
    s[1] = np.inf
    e, _ = friction_excess(t[:4], s[:4], np.ones(4, bool))  # an infinite sigma: not measured
    assert np.isnan(e[1]) and np.isfinite(e[[0, 2]]).all()
    assert_allclose(e[0], 1.0 / 1.0 - 1.0, rtol=1e-12)


def test_combine_is_inverse_variance_in_units_of_the_floor():
    f, s = combine(np.array([[0.003, NAN, NAN], [0.3, 0.2, NAN]]), np.array([[0.001, 0.001, 0.001],
                                                                              [0.1, 0.05, 0.1]]),
                   np.array([0.001, 0.1]))
    # cylinder 1: 3 +- 1 and 3 +- 1 -> 3 +- 1/sqrt(2); cylinder 2: the friction alone, 2 +- 0.5; cylinder 3: nothing
    assert_allclose(f[:2], [3.0, 2.0], rtol=1e-12)
    assert_allclose(s[:2], [1.0 / np.sqrt(2.0), 0.5], rtol=1e-12)
    assert np.isnan(f[2]) and np.isnan(s[2])


def test_a_fault_from_the_first_cycle_reads_against_the_siblings_a_new_one_since_the_baseline():
    s = RingConditionSettings(window=50.0, warmup=10, leak_allowance=0.001)
    w = SiblingWindow(np.array([0.0, 0.004, 0.0002, -0.0002]), np.full(4, 1e-6), 200)
    nan4 = np.full(4, NAN)
    # from the first cycle: in the baseline, no change since; against the siblings it stands off
    rc = ring_condition(np.zeros(4), np.full(4, 1e-4), w, nan4, nan4, nan4, nan4, s)
    assert rc.reference[1] == SIBLINGS and rc.figure[1] > 3.0 and rc.z[1] > 3.0
    assert np.all(np.delete(rc.z, 1) < 1.0)
    # after commissioning: a change since the baseline, the siblings alike: the precise reference wins
    w0 = SiblingWindow(np.array([0.0, 0.0012, 0.0002, -0.0002]), np.full(4, 1e-6), 200)
    rc = ring_condition(np.array([0.0, 0.0012, 0.0, 0.0]), np.full(4, 1e-4), w0, nan4, nan4, nan4, nan4, s)
    assert rc.reference[1] == SINCE
    assert_allclose([rc.figure[1], rc.sigma[1]], [1.2, 0.1], rtol=1e-12)
    # before the sibling window's warm-up there is no sibling reference
    rc = ring_condition(nan4, nan4, SiblingWindow(w.mean, w.var, 5), nan4, nan4, nan4, nan4, s)
    assert np.all(rc.reference == -1) and np.all(np.isnan(rc.figure))


def test_the_measured_friction_adds_its_evidence():
    s = RingConditionSettings(window=50.0, warmup=10)
    w = SiblingWindow(np.zeros(4), np.zeros(4), 200)
    nan4 = np.full(4, NAN)
    fc = np.array([0.2, 0.0, NAN, 0.0])  # +20 % friction excess since its first measurement
    rc = ring_condition(np.array([0.0015, 0.0, 0.0, 0.0]), np.full(4, 0.0005), w, fc, np.full(4, 0.05),
                        nan4, nan4, s)
    # 1.5 +- 0.5 (leak) and 2.0 +- 0.5 (friction): 1.75 +- 0.354
    assert_allclose([rc.since[0], rc.since_sigma[0]], [1.75, 0.5 / np.sqrt(2.0)], rtol=1e-12)
    assert_allclose([rc.since[2], rc.since_sigma[2]], [0.0, 0.5], rtol=1e-12, atol=1e-15)


def test_against_the_siblings_a_friction_excess_alone_is_not_a_worn_ring():
    # a gain error of cylinder 1's sensor: +46 % friction against its siblings, its exponents like theirs
    s = RingConditionSettings(window=50.0, warmup=10, leak_allowance=0.001, friction_allowance=0.1)
    nan4 = np.full(4, NAN)
    w = SiblingWindow(np.array([-0.0002, 0.0001, 0.0, 0.0001]), np.full(4, 1e-6), 200)
    fn = np.array([0.46, -0.15, -0.15, -0.15])
    rc = ring_condition(nan4, nan4, w, nan4, nan4, fn, np.full(4, 0.05), s)
    assert np.all(rc.siblings < 1.0) and np.isnan(rc.friction_siblings[0])
    # with a leak there too the friction adds its evidence: (3 +- 1) and (4.6 +- 1.12) -> 3.71 +- 0.75
    w = SiblingWindow(np.array([0.003, 0.0, 0.0, 0.0]), np.zeros(4), 200)
    rc = ring_condition(nan4, nan4, w, nan4, nan4, fn, np.full(4, 0.05), s)
    sf = np.hypot(0.05, 0.1) / 0.1
    want = (3.0 + 4.6 / sf ** 2) / (1.0 + 1.0 / sf ** 2)
    assert_allclose([rc.siblings[0], rc.siblings_sigma[0]], [want, 1.0 / np.sqrt(1.0 + 1.0 / sf ** 2)], rtol=1e-9)


@pytest.mark.parametrize("z", [1, 2, 3, 4, 20])
@pytest.mark.parametrize("count", [0, 99, 100, 400])
@pytest.mark.parametrize("siblings", [True, False])
def test_the_ring_condition_kernel_is_its_numpy_reference(z, count, siblings):
    """ring_condition (one kernel) against ring_condition_reference on seeded evidence with NaN pieces, zero and
    negative sigmas and NaN window entries: every field within rtol 1e-14 (the same arithmetic in the same order),
    NaN where NaN, the references equal."""
    rng = np.random.default_rng(100 * z + count + siblings)
    for _ in range(30):
        ev = [rng.normal(0.0, 0.002, z), rng.uniform(0.0, 0.001, z), rng.normal(0.0, 0.2, z),
              rng.uniform(0.0, 0.1, z), rng.normal(0.0, 0.2, z), rng.uniform(0.0, 0.1, z)]
        for a in ev:
            a[rng.uniform(size=z) < 0.15] = np.nan
        ev[1][rng.uniform(size=z) < 0.1] = 0.0
        ev[3][rng.uniform(size=z) < 0.1] = -0.01
        window = SiblingWindow(rng.normal(0.0, 0.003, z), rng.uniform(-1e-7, 1e-5, z), count)
        window.mean[rng.uniform(size=z) < 0.1] = np.nan
        lc, lc_s, fc, fc_s, fn, fn_s = ev
        got = ring_condition(lc, lc_s, window, fc, fc_s, fn, fn_s, siblings=siblings)
        want = ring_condition_reference(lc, lc_s, window, fc, fc_s, fn, fn_s, siblings=siblings)
        for f in dataclasses.fields(RingCondition):
            assert_allclose(getattr(got, f.name), getattr(want, f.name), rtol=1e-14, atol=0, err_msg=f.name)
