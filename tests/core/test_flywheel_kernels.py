"""The flywheel-fit design kernel against its plain numpy definition (core.flywheel docstring: columns 1, u(u-1),
cos(w_m tau), sin(w_m tau), w_m = m Omega / 2). The recurrence is re-seeded every 8 harmonics: agreement to 1e-13."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from core.flywheel import fit_flywheel
from core.flywheel_kernels import _fit_design


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("n_drift", [1, 2])
@pytest.mark.parametrize("n_harm", [1, 7, 30])
def test_fit_design_matches_direct_trig(seed, n_drift, n_harm):
    rng = np.random.default_rng(seed)
    period = 0.08
    tau = np.sort(rng.uniform(0, period, 317))
    tau[0], tau[-1] = 0.0, period
    w = 0.5 * (4 * np.pi / period) * np.arange(1, n_harm + 1)
    want = np.empty((tau.size, n_drift + 2 * n_harm))
    want[:, 0] = 1.0
    if n_drift == 2:
        u = tau / period
        want[:, 1] = u * (u - 1.0)
    want[:, n_drift: n_drift + n_harm] = np.cos(np.outer(tau, w))
    want[:, n_drift + n_harm:] = np.sin(np.outer(tau, w))
    got = np.empty_like(want)
    _fit_design(tau, period, w[0], n_drift, n_harm, got)
    assert_allclose(got, want, rtol=0, atol=1e-13)


@pytest.mark.parametrize("seed", [0, 1])
def test_fit_flywheel_is_the_least_squares_fit(seed):
    """fit_flywheel (design kernel, factored normal equations, patterns) equals an SVD least squares on the
    directly built design (physics.md §14.4: the fit is linear least squares in the harmonics)."""
    rng = np.random.default_rng(seed)
    tick_hz = 1e7
    ang = np.radians(np.arange(0, 720.0 + 1e-9, 360.0 / 60.0))  # 60-position wheel, no gap, 121 edges
    period = 0.08
    t = ang / (4 * np.pi) * period + 2e-5 * np.sin(3 * ang) + 1e-5 * rng.standard_normal(ang.size)
    t[0], t[-1] = 0.0, period
    ticks = np.round(t * tick_hz).astype(np.int64)
    patterns = np.column_stack([np.cos(ang), np.sin(ang)])
    fly = fit_flywheel(ticks, tick_hz, ang, 10, patterns, 12, drift=True)
    tau = (ticks - ticks[0]) / tick_hz
    omega = 4 * np.pi / tau[-1]
    w = 0.5 * omega * np.arange(1, 13)
    u = tau / tau[-1]
    design = np.column_stack([np.ones_like(tau), u * (u - 1), np.cos(np.outer(tau, w)), np.sin(np.outer(tau, w))])
    phi = ang - ang[0] - omega * tau
    sol = np.linalg.lstsq(design, np.column_stack([phi, patterns]), rcond=None)[0]
    assert_allclose(fly.harmonics, sol[2:12, 0] - 1j * sol[14:24, 0], rtol=1e-8, atol=1e-12)
    assert_allclose(fly.pattern_harmonics, sol[2:12, 1:] - 1j * sol[14:24, 1:], rtol=1e-8, atol=1e-12)
    assert_allclose(fly.edge_residual, phi - design @ sol[:, 0], atol=1e-12)
    assert fly.drift == pytest.approx(sol[1, 0], rel=1e-8, abs=1e-14)
