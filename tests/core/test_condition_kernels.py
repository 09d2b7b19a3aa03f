"""The condition stage's kernels (core/monitor/checks/condition.py, ring_pressure.py) against the plain numpy
references beside them, on seeded pressure traces of the presets' sizes (1, 3, 4 and 20 cylinders; 720 and 1440
grid points, a grid not starting at 0) with per-cylinder gains, noise, a non-positive sample and a NaN.

Tolerances: the samples and logs are the same arithmetic (1e-14 relative: an ulp of a log); the slopes, means and
medians sum in plain order where numpy sums pairwise or through BLAS, and a sibling deviation is a difference of two
exponents ~1.3 read to ~1e-3, so those are compared to 1e-12 absolute. Masks and flags are compared exactly."""

from dataclasses import replace

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.kinematics import kinematics
from frictionwatch.core.monitor.checks.condition import (
    DEFAULT_SETTINGS,
    _ewma,
    burn_ratio,
    combustion_flags,
    combustion_flags_reference,
    compression_rise,
    condition_tables,
    cycle_chi2_reduced,
    cycle_chi2_reduced_reference,
    sibling_deviation,
)
from frictionwatch.core.monitor.checks.condition_kernels import levels_kernel, median_without, numpy_sum, window_kernel
from frictionwatch.core.monitor.checks.ring_pressure import ring_indicators, ring_indicators_reference, ring_tables
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from frictionwatch.core.monitor.identify.posterior import Posterior
from numpy.testing import assert_allclose, assert_array_equal

ENGINES = ("deutz-1cyl", "maruti-3cyl", "k9k-4cyl", "genset-v20")


def _pressure(spec, grid, rng):
    """Polytropic traces with a burn bump after TDC, a gain per cylinder and 0.3 % noise [Pa]."""
    p = np.empty((spec.n_cyl, grid.shape[0]))
    for k in range(spec.n_cyl):
        local = np.mod(grid - spec.firing_angles[k] + 2 * np.pi, 4 * np.pi) - 2 * np.pi
        x, _, _ = kinematics(local, np.asarray(spec.kinematics_params()))
        vol = spec.clearance_volume + spec.piston_area * x
        burn = 1.0 + 2.0 * np.exp(-((local - 0.3) / 0.3) ** 2)
        p[k] = 1e5 * rng.uniform(0.95, 1.05) * (vol.max() / vol) ** 1.35 * burn
    return p * (1.0 + 0.003 * rng.standard_normal(p.shape))


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("n, start", [(720, 0.0), (1440, 0.01)])
def test_condition_levels_and_ring_indicators_match_their_references(engine, n, start):
    spec = load_engine(engine)
    grid = start + np.arange(n) * (4 * np.pi / n)
    rng = np.random.default_rng(n + spec.n_cyl)
    p = _pressure(spec, grid, rng)
    if spec.n_cyl > 2:
        p[1, ::7] = -1.0  # a cylinder with non-positive samples: NaN where they are read
    tab = condition_tables(spec, grid, DEFAULT_SETTINGS)
    pmax, work = p.max(axis=1), rng.uniform(-1.0, 50.0, spec.n_cyl)
    levels = levels_kernel(p, tab.cols, tab.frac, pmax, work)
    assert_allclose(levels[0], compression_rise(spec, grid, p, DEFAULT_SETTINGS), rtol=1e-14, atol=1e-15)
    assert_allclose(levels[1], np.log(np.maximum(pmax, 1.0)), rtol=1e-14)
    assert_allclose(levels[2], np.log(np.maximum(work, 1e-9)), rtol=1e-14)
    assert_allclose(levels[3], burn_ratio(spec, grid, p, DEFAULT_SETTINGS.burn_half_deg), rtol=1e-14, atol=1e-15)
    got, want = ring_indicators(spec, grid, p, tables=ring_tables(spec, grid)), ring_indicators_reference(spec, grid, p)
    for name in ("compression_pa", "n_compression", "n_expansion"):
        assert_allclose(getattr(got, name), getattr(want, name), rtol=1e-12, err_msg=name)
    for name in ("compression_ratio", "n_compression_dev", "n_expansion_dev", "expansion_deficit"):
        assert_allclose(getattr(got, name), getattr(want, name), rtol=0, atol=1e-12, err_msg=name)


@pytest.mark.parametrize("z", [1, 2, 3, 4, 20])
def test_the_window_kernel_is_the_ewma_of_sibling_deviations(z):
    rng = np.random.default_rng(z)
    window = np.zeros((2, 3, z))
    for cycle in range(6):
        levels = rng.standard_normal((4, z))
        if cycle == 3 and z > 1:
            levels[0, 0] = np.nan  # a cylinder's compression rise not read: its row's median is NaN
        g, first = max(1.0 / 50.0, 1.0 / (cycle + 1)), cycle == 0
        want = np.array([_ewma(window[0, r], window[1, r], sibling_deviation(levels[r]), g, first)
                         for r in range(3)]).transpose(1, 0, 2)
        window = window_kernel(levels, window, g, first)
        assert_allclose(window, want, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("z", [1, 2, 3, 4, 20])
def test_combustion_flags_match_the_reference(z):
    """The siblings' medians from one sort against one np.median per cylinder: equal (same two samples averaged)."""
    rng = np.random.default_rng(100 + z)
    ref, n = np.full(z, np.nan), np.zeros(z, dtype=np.int64)
    ref_r, n_r = ref.copy(), n.copy()
    for cycle in range(40):
        burn = rng.choice([-0.1, 0.05, 0.5, 0.8, np.nan], size=z, p=[0.1, 0.1, 0.4, 0.35, 0.05])
        work = rng.uniform(0.0, 3.0, z) * rng.choice([0.05, 1.0], size=z, p=[0.15, 0.85])
        if cycle % 5 == 0:
            work = np.round(work)  # ties among the siblings
        if cycle == 7:
            work[0] = np.nan
        flags, ref, n = combustion_flags(burn, work, ref, n, DEFAULT_SETTINGS)
        flags_r, ref_r, n_r = combustion_flags_reference(burn, work, ref_r, n_r, DEFAULT_SETTINGS)
        assert flags == flags_r
        assert_array_equal(n, n_r)
        assert_allclose(ref, ref_r, rtol=1e-15)



def test_combustion_sibling_medians_from_one_sort_are_np_median_of_the_siblings():
    """``median_without`` (the median of a sorted list without one element) against np.median of the list without
    it, bit for bit, for every element of lists of 1-20 values with ties and signed zeros; and the flags, references
    and counts of ``combustion_flags`` against its reference on draws whose works sit about the partial-burn fraction
    of their siblings' medians (where the median decides), with one and two NaN works."""
    rng = np.random.default_rng(7)
    for trial in range(300):
        n = int(rng.integers(1, 21))
        v = np.round(rng.uniform(-1.0, 3.0, n), int(rng.integers(0, 3)))
        if trial % 5 == 0:
            v[rng.integers(0, n)] = -0.0
        s = np.sort(v)
        assert_array_equal(median_without(s, n, -1), np.median(v))
        for r in range(n if n > 1 else 0):
            assert_array_equal(median_without(s, n, r), np.median(np.delete(s, r)))
    frac = DEFAULT_SETTINGS.partial_fraction
    for trial in range(300):
        z = int(rng.integers(2, 21))
        burn = np.where(rng.random(z) < 0.85, 0.6, -0.2)
        work = np.round(rng.uniform(1.0, 2.0, z), 1) * np.where(rng.random(z) < 0.3, frac, 1.0)
        for _ in range(int(rng.integers(1, 3)) if trial % 4 == 0 else 0):
            work[rng.integers(0, z)] = np.nan
        ref0 = np.where(rng.random(z) < 0.5, np.nan, 1.5)
        cycles0 = rng.integers(0, 5, z)
        got = combustion_flags(burn, work, ref0, cycles0, DEFAULT_SETTINGS)
        want = combustion_flags_reference(burn, work, ref0, cycles0, DEFAULT_SETTINGS)
        assert got[0] == want[0]
        assert_array_equal(got[1], want[1])
        assert_array_equal(got[2], want[2])


@pytest.mark.parametrize("n", [1, 2, 3, 7, 8, 9, 16, 17, 128, 129, 300, 841, 2209, 5000])
def test_numpy_sum_is_np_sum_bit_for_bit(n):
    rng = np.random.default_rng(n)
    for _ in range(20):
        a = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3, n)
        assert numpy_sum(a, 0, n) == np.sum(a)


@pytest.mark.parametrize("p", [2, 5, 29, 47])
def test_cycle_chi2_reduced_is_its_reference_bit_for_bit(p):
    """On posteriors of the monitor's sizes (k9k 29, genset-v20 47 parameters), chi2_reduced below and above 1,
    a NaN one, and a dof at or below 0 (then 1)."""
    rng = np.random.default_rng(p)
    for trial in range(40):
        a = rng.standard_normal((p + 3, p)) * 10.0 ** rng.uniform(-2, 3, p)
        y = rng.standard_normal(p + 3)
        terms = Accumulator.empty(p, p + 3).cycle_terms(a, y, np.ones(p + 3), 1)
        terms = Accumulator.of_terms(terms)
        cov = np.linalg.inv(terms.info + np.diag(rng.uniform(0.1, 10.0, p)))
        cov = 0.5 * (cov + cov.T)
        chi2_red = [0.5, 2.5, np.nan][trial % 3]
        params = np.linalg.solve(terms.info + np.eye(p), terms.rhs) * rng.uniform(0.9, 1.1, p)
        post = Posterior(params=params, covariance=cov, cov_statistical=cov * (chi2_red if chi2_red > 1 else 1.0),
                         chi2_reduced=chi2_red, weight=1.0, cov_reference=cov)
        if trial == 5:
            terms = replace(terms, rows=0.5)  # dof <= 0
        assert cycle_chi2_reduced(terms, post) == cycle_chi2_reduced_reference(terms, post)
    assert_array_equal(cycle_chi2_reduced(None, post), post.chi2_reduced)
