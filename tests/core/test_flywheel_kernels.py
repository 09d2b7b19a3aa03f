"""The flywheel-fit kernels against their plain numpy definitions (core.monitor.teeth.flywheel docstring: columns 1, u(u-1),
cos(w_m tau), sin(w_m tau), w_m = m Omega / 2; the recurrence agrees with direct trig to 1e-13), and the whole fit
against an SVD least squares."""

import numpy as np
import pytest
from frictionwatch.core.monitor.teeth.flywheel import fit_flywheel
from numpy.testing import assert_allclose


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


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("n_drift", [1, 2])
@pytest.mark.parametrize("n_harm", [1, 7, 24, 30])
def test_prepare_fit_design_and_normal_matrix(seed, n_drift, n_harm):
    """prepare_fit_kernel's design rows (recurrence across edges, no re-seed) match direct trig to 1e-13, and its
    normal inverse is that of D^T D on unit-scaled columns (power-sum identities, module docstring)."""
    from frictionwatch.core.monitor.teeth.flywheel_kernels import OK, prepare_fit_kernel

    rng = np.random.default_rng(seed)
    n = 317
    ticks = np.cumsum(rng.integers(2000, 3000, n)).astype(np.int64)
    tick_hz = 1e7
    tau = (ticks - ticks[0]) / tick_hz
    period = tau[-1]
    w = 0.5 * (4 * np.pi / period) * np.arange(1, n_harm + 1)
    cols = [np.ones(n)] + ([(tau / period) * (tau / period - 1.0)] if n_drift == 2 else [])
    want = np.column_stack(cols + [np.cos(np.outer(tau, w)), np.sin(np.outer(tau, w))])
    p = want.shape[1]
    got_tau, rows, scale, normal_inv = np.empty(n), np.empty((p, n)), np.empty(p), np.empty((p, p))
    status = prepare_fit_kernel(ticks, tick_hz, n_drift, n_harm, n_harm, np.zeros((n, 0)), 0, False,
                                (got_tau, rows, scale, normal_inv), np.empty((n_harm, 0), dtype=np.complex128))
    assert status == OK
    assert_allclose(got_tau, tau, rtol=0, atol=0)
    assert_allclose(rows.T, want, rtol=0, atol=1e-13)
    assert_allclose(scale, np.linalg.norm(want, axis=0), rtol=1e-13)
    d = want / np.linalg.norm(want, axis=0)
    # the kernel's normal matrix (power sums) is good to ~1e-12 absolute, so its inverse to ~cond * 1e-12 (cond ~1
    # for the Fourier columns alone, up to ~1e2 with the drift column)
    normal = d.T @ d
    assert_allclose(normal_inv @ normal, np.eye(p), rtol=0, atol=1e-12 * np.linalg.cond(normal))
    assert_allclose(normal_inv, normal_inv.T, rtol=0, atol=0)
