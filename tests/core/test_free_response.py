"""The chain's free response a random effect of a cycle's speed rows (core.monitor.identify.free_response, design
notes 105, 108): its columns are the speed harmonics of a free vibration in the monitor's convention, the kernel
equals its numpy reference, a large variance is the projection and zero nothing, the data give a mode's variance,
and genset-v20 at 1500 rpm carries its 2.4 and 19.6 Hz modes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from frictionwatch.core.model.dynamics import free_modes, shaft_model
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.identify.free_response import (
    carried_modes,
    coefficient_moments,
    free_response_columns,
    free_response_design,
    free_response_design_reference,
    free_response_kernel,
    free_response_moments,
    free_response_reference,
    free_response_variance,
)
from frictionwatch.core.monitor.identify.noise_model import ResidualStats
from numpy.testing import assert_allclose

GENSET_MODES = np.array([-3.79 + 14.8j, -14.6 + 122.0j])  # ~2.4 Hz (zeta 0.25) and ~19.6 Hz (zeta 0.12)


def test_columns_are_the_speed_harmonics_of_a_free_vibration():
    """Column 2j (2j + 1) is the speed harmonic S_k of w(t) = Re(c e^(lambda t)), c = 1 (c = i), in the
    monitor's convention w(t) = sum Re(S_k e^(+i k 2 pi t / T)): S_k = (2 / T) int_0^T w(t) e^(-i k 2 pi t / T) dt
    (trapezoid on 200,001 points, rtol 1e-7)."""
    period, m = 0.08, 24
    cols = free_response_columns(GENSET_MODES, period, m)
    t = np.linspace(0.0, period, 200_001)
    k = np.arange(1, m + 1)[:, None]
    basis = np.exp(-2j * np.pi * k * t[None, :] / period)
    for j, lam in enumerate(GENSET_MODES):
        for col, c in ((2 * j, 1.0), (2 * j + 1, 1j)):
            w = (c * np.exp(lam * t)).real
            s = 2.0 / period * np.trapezoid(w[None, :] * basis, t, axis=1)
            assert_allclose(cols[:, col], s, rtol=1e-7, atol=1e-9 * np.abs(s).max())


def _random_system(seed):
    """Random rows (2M + 1 + 6 extra, P) and whitened columns of two random modes (2M, 4); every fourth case a
    duplicated mode (a rank-deficient set of columns)."""
    rng = np.random.default_rng(seed)
    m, p = int(rng.integers(3, 25)), int(rng.integers(2, 48))
    r = 2 * m + 7
    a, y = rng.normal(size=(r, p)), rng.normal(size=r)
    w = rng.uniform(0.2, 5.0, 2 * m)
    lams = -rng.uniform(1.0, 20.0, 2) + 1j * rng.uniform(5.0, 200.0, 2)
    if seed % 4 == 0:
        lams = np.array([lams[0], lams[0]])
    cols = free_response_columns(lams, 0.08, m)
    dw = np.ascontiguousarray(np.concatenate([cols.real, cols.imag]) * w[:, None])
    return rng, m, a, y, dw


@pytest.mark.parametrize("seed", range(20))
def test_kernel_equals_reference(seed):
    """Random systems, each mode's prior variance drawn over 1e-6 to 1e6 of its columns' inverse size: the kernel's
    rows against the numpy reference's (the full 2M x 2M inverse square root by eigh) within 20 eps cond of the
    largest row, cond = 1 + the largest eigenvalue of G^T G: the reference's eigenvectors carry eps cond (seen
    0.1-4.3 eps cond over the 20; cond up to 2e7); the rows after the flywheel's untouched."""
    rng, m, a, y, dw = _random_system(seed)
    s = np.repeat(10.0 ** rng.uniform(-6, 6, 2), 2) / np.mean(dw**2, axis=0)
    g = dw * np.sqrt(s)
    tol = 20.0 * np.finfo(float).eps * (1.0 + np.linalg.eigvalsh(g.T @ g).max())
    ka, ky = free_response_kernel(a, y, dw, s)
    ra, ry = free_response_reference(a, y, dw, s)
    assert_allclose(ka, ra, rtol=0, atol=tol * np.abs(a).max())
    assert_allclose(ky, ry, rtol=0, atol=tol * np.abs(y).max())
    assert_allclose(ka[2 * m:], a[2 * m:], rtol=0, atol=0)
    assert_allclose(ky[2 * m:], y[2 * m:], rtol=0, atol=0)


def _random_modes(rng, period, m):
    """Six modes: two carried in band, one carried above the band, one that decays within the cycle, two random."""
    band = m * 2.0 * np.pi / period
    keep = -rng.uniform(0.5, 10.0, 2) + 1j * rng.uniform(5.0, 0.9 * band, 2)
    above = np.array([-1.0 + 1j * 1.2 * band])
    fast = np.array([-80.0 + 1j * rng.uniform(5.0, band)])
    other = -rng.uniform(0.5, 60.0, 2) + 1j * rng.uniform(5.0, 1.2 * band, 2)
    return np.concatenate([keep, above, fast, other])


@pytest.mark.parametrize("seed", range(12))
def test_design_kernel_equals_its_reference(seed):
    """The carried modes' whitened columns by the kernel against carried_modes + free_response_columns +
    whitened_columns (numpy), rtol 1e-12 of the largest entry: random modes about the carry and band limits, random
    row weights, with a drift random effect (every other case none, or a zero drift variance); carry 0 gives no
    column."""
    rng = np.random.default_rng(200 + seed)
    period, m = rng.uniform(0.03, 0.2), int(rng.integers(3, 30))
    modes = _random_modes(rng, period, m)
    inv_sigma = rng.uniform(0.2, 5.0, 2 * m)
    drift = (rng.normal(size=m) + 1j * rng.normal(size=m)) if seed % 2 else np.empty(0, dtype=np.complex128)
    drift_var = 0.0 if seed % 4 == 3 else 10.0 ** rng.uniform(-2, 3)
    k = free_response_design(modes, period, 0.1, inv_sigma, drift, drift_var)
    r = free_response_design_reference(modes, period, 0.1, inv_sigma, drift, drift_var)
    assert k.shape == r.shape and k.shape[1] >= 4
    assert_allclose(k, r, rtol=0, atol=1e-12 * np.abs(r).max())
    assert free_response_design(modes, period, 0.0, inv_sigma, drift, drift_var).shape == (2 * m, 0)


@pytest.mark.parametrize("seed", range(20))
def test_moments_kernel_equals_its_reference(seed):
    """One cycle's coefficient moments by the kernel's one SVD against lstsq + pinv (numpy) on the random systems
    above (every fourth one with a duplicated mode: rank-deficient columns, both cut the same null direction):
    rtol 1e-9 (the coefficients' rounding grows with the columns' condition number, up to ~1e4 here)."""
    rng, m, a, y, dw = _random_system(seed)
    params = rng.normal(size=a.shape[1])
    kc, kn = free_response_moments(dw, a, y, params)
    rc, rn = coefficient_moments(dw, y[:2 * m] - a[:2 * m] @ params)
    assert_allclose(kc, rc, rtol=1e-9)
    assert_allclose(kn, rn, rtol=1e-9)


@pytest.mark.parametrize("seed", range(4))
def test_large_variance_is_the_projection_and_zero_leaves_the_rows(seed):
    """A prior variance 1e12 times the columns' inverse size whitens the rows to within 1e-5 (relative, the
    (1 + s |d|^2)^(-1/2) left along each column) of orthogonal to the columns: note 105's projection is its limit;
    a zero variance leaves the rows as they were (exactly)."""
    _, m, a, y, dw = _random_system(seed)
    big = np.full(dw.shape[1], 1e12) / np.mean(dw**2, axis=0)
    ka, ky = free_response_kernel(a, y, dw, big)
    unit = dw / np.linalg.norm(dw, axis=0)
    assert_allclose(unit.T @ ka[:2 * m], 0.0, atol=1e-5 * np.abs(a).max())
    assert_allclose(unit.T @ ky[:2 * m], 0.0, atol=1e-5 * np.abs(y).max())
    za, zy = free_response_kernel(a, y, dw, np.zeros(dw.shape[1]))
    assert_allclose(za, a, rtol=0, atol=0)
    assert_allclose(zy, y, rtol=0, atol=0)


@pytest.mark.parametrize("seed", range(3))
def test_the_data_give_each_modes_variance(seed):
    """Rows of unit white noise plus the free response of the two genset modes (columns scaled to a largest entry
    of 1; one cycle's coefficient noise (D^T D)^-1 is 39-50 for the 2.4 Hz mode, 0.6-1.1 for the 19.6 Hz one),
    3,000 cycles through coefficient_moments and free_response_variance (memory 1 - 1/3000: the plain mean here).
    Coefficients of variance 100 and 4 per real component: both within 10 % (the estimates' spread over 3,000
    cycles, sqrt(2) (s + noise) / sqrt(6000), is 2.6 and 2.2 %); of variance 0: both below 3.5 of their spread
    (2.4 Hz < 3, 19.6 Hz < 0.06; the noise term takes out what noise alone gives)."""
    rng = np.random.default_rng(100 + seed)
    m = 24
    cols = free_response_columns(GENSET_MODES, 0.08, m)
    dw = np.concatenate([cols.real, cols.imag]) / np.abs(cols).max()
    for sd, check in (([10.0, 10.0, 2.0, 2.0], lambda v: assert_allclose(v, [100.0, 4.0], rtol=0.1)),
                      ([0.0] * 4, lambda v: np.testing.assert_array_less(v, [3.0, 0.06]))):
        stats = ResidualStats.empty(m)
        for _ in range(3000):
            resid = dw @ (np.array(sd) * rng.normal(size=4)) + rng.normal(size=2 * m)
            coef_sq, noise = coefficient_moments(dw, resid)
            sq, nz, n, var = free_response_variance(stats, coef_sq, noise, 1.0 - 1.0 / 3000)
            stats = replace(stats, free_coef_sq=sq, free_noise=nz, free_count=n)
        check(var)


def test_genset_carries_its_two_slow_modes_and_nothing_else():
    """genset-v20 at 1500 rpm (T 0.08 s, M 24): the modes kept over a cycle at carry 0.1 are the electromechanical
    one (2.4 Hz, 0.74 of its amplitude kept) and the chain's first flexible one (19.6 Hz, 0.32), within 0.1 Hz; the
    next in-band one (87 Hz) keeps 0.002; carry 0 takes none."""
    spec = load_engine("genset-v20")
    omega = 1500.0 * np.pi / 30.0
    modes = free_modes(shaft_model(spec, 0.0, omega))
    period = 4.0 * np.pi / omega
    kept = carried_modes(modes, period, 24, 0.1)
    assert_allclose(np.abs(kept) / (2.0 * np.pi), [2.43, 19.55], atol=0.1)
    assert_allclose(np.exp(kept.real * period), [0.739, 0.315], atol=0.005)
    assert carried_modes(modes, period, 24, 0.0).shape == (0,)


@pytest.mark.parametrize("seed", range(6))
def test_step_kernel_equals_its_reference_over_cycles(seed):
    """without_free_response (one free_response_step_kernel call) against without_free_response_reference (design,
    moments, the EWMA, the kernel one after another) over 12 chained random cycles: the first restarts the EWMA
    (none before), cycle 6 changes the carried modes' count (a restart), every other case without a drift column;
    rows within rtol 1e-12 of their largest entry, the EWMA within rtol 1e-12, its count equal; carry 0: the rows
    themselves."""
    from frictionwatch.core.monitor.identify.free_response import (
        without_free_response,
        without_free_response_reference,
    )
    from frictionwatch.core.monitor.identify.noise_model import WhitenedCycle

    rng = np.random.default_rng(500 + seed)
    period, m, p = 0.08, int(rng.integers(6, 25)), int(rng.integers(4, 40))
    stats = got_stats = ResidualStats.empty(m)
    changed = 0
    for cycle in range(12):
        modes = GENSET_MODES if cycle < 6 else GENSET_MODES[:1]
        drift = (rng.normal(size=m) + 1j * rng.normal(size=m)) if seed % 2 else None
        a, y = rng.normal(size=(2 * m + 1, p)), rng.normal(size=2 * m + 1)
        inv_sigma = rng.uniform(0.2, 5.0, 2 * m + 1)
        params = rng.normal(size=p)
        white = WhitenedCycle(stats, a, y, inv_sigma, np.ones(2 * m + 1), np.arange(1.0, m + 1), drift)
        args = (modes, period, 0.1, 3.0, 0.75)  # memory: the EWMA factor 0.25 from the fifth cycle on
        want = without_free_response_reference(white, stats, params, *args)
        got = without_free_response(replace(white, stats=got_stats), got_stats, params, *args)
        assert_allclose(got.a, want.a, rtol=0, atol=1e-12 * np.abs(want.a).max())
        assert_allclose(got.y, want.y, rtol=0, atol=1e-12 * np.abs(want.y).max())
        for field in ("free_coef_sq", "free_noise"):
            assert_allclose(getattr(got.stats, field), getattr(want.stats, field), rtol=1e-12)
        assert got.stats.free_count == want.stats.free_count == (cycle + 1 if cycle < 6 else cycle - 5)
        changed += not np.allclose(got.a, a)
        stats, got_stats = want.stats, got.stats
    assert changed >= 1  # the rows were whitened again (not by a variance of zero)
    assert without_free_response(white, stats, params, GENSET_MODES, period, 0.0, 3.0, 0.98) is white
