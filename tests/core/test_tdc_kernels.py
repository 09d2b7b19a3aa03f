"""The TDC fit's kernels against their numpy reference (core.monitor.calibration.tdc: ``_model_terms``,
``_gauss_newton_reference``) on seeded inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.calibration.tdc import (
    _constants,
    _gauss_newton,
    _gauss_newton_reference,
    _model_terms,
    _Setting,
)
from frictionwatch.core.monitor.calibration.tdc_kernels import residual_kernel, residuals_kernel

from tests.core.test_tdc_from_pressure import adiabatic_trace


def _window(engine: str, seed: int) -> tuple[object, np.ndarray, np.ndarray, np.ndarray]:
    """(spec, p (8, m), dp (8, m), angle (m,)): 8 noisy adiabatic compression-expansion cycles around TDC."""
    spec = load_engine(engine)
    cb = spec.combustion
    angle = np.radians(np.arange(cb.ivc_deg, cb.evo_deg, 1.0))
    base = adiabatic_trace(spec, angle, 1.2e5, cb.t_ivc_k)
    rng = np.random.default_rng(seed)
    p = base[None, :] * (1.0 + rng.normal(0.0, 2e-3, (8, 1))) + rng.normal(0.0, 3e3, (8, angle.shape[0]))
    return spec, p, np.gradient(p, angle, axis=1), angle


@pytest.mark.parametrize("engine", ["deutz-1cyl", "k9k-4cyl", "genset-v20"])
def test_residual_kernel_is_the_model_terms_sum(engine):
    """rtol 1e-12: the same operations per sample (only numpy's vectorised pow could round differently)."""
    spec, p, dp, angle = _window(engine, 3)
    st = _Setting(spec, 150.0, 1.2e5, math.radians(-5.0), 1.3)
    for delta, peg in ((0.0, 0.0), (0.012, -4e3), (-0.03, 7e3)):
        q, w = _model_terms(p[0], dp[0], angle, delta, peg, st)
        got = np.empty_like(angle)
        residual_kernel(p[0], dp[0], angle, delta, peg, _constants(st), got)
        np.testing.assert_allclose(got, q + w, rtol=1e-12, atol=1e-12 * np.max(np.abs(q)))


@pytest.mark.parametrize("engine", ["deutz-1cyl", "k9k-4cyl", "genset-v20"])
def test_residuals_at_several_peggings_are_each_alone(engine):
    """``residuals_kernel`` (the Gauss-Newton step's residual and its pegging column at one delta, the delta terms
    shared): each row the model terms' sum at its pegging (rtol 1e-12, as above) and the single-pegging kernel's
    numbers exactly (rtol 0: the same operations per sample, only evaluated once for both rows), on samples before
    and after the start of combustion and a pegging that takes the IVC pressure to its 1 kPa floor."""
    spec, p, dp, angle = _window(engine, 4)
    st = _Setting(spec, 180.0, 1.1e5, math.radians(-5.0), 1.1)
    c = _constants(st)
    for delta, pegs in ((0.0, (0.0, 2e3)), (0.02, (-4e3, 6e3, -1.5e5))):
        got = np.empty((len(pegs), angle.shape[0]))
        residuals_kernel(p[1], dp[1], angle, delta, np.array(pegs), c, got)
        for row, peg in zip(got, pegs, strict=True):
            q, w = _model_terms(p[1], dp[1], angle, delta, peg, st)
            np.testing.assert_allclose(row, q + w, rtol=1e-12, atol=1e-12 * np.max(np.abs(q)))
            alone = np.empty_like(angle)
            residual_kernel(p[1], dp[1], angle, delta, peg, c, alone)
            np.testing.assert_allclose(row, alone, rtol=0, atol=0)


@pytest.mark.parametrize("engine", ["deutz-1cyl", "k9k-4cyl", "genset-v20"])
@pytest.mark.parametrize("constant_loss", [False, True])
def test_gauss_newton_kernel_is_its_numpy_reference(engine, constant_loss):
    """From a start 1 deg and 5 kPa off: the fits agree to 1e-10 rad and 1e-6 relative pegging (the iterations'
    rounding, ~1e-14 rad on the k9k windows of the bench), and move from the start (the fit ran)."""
    spec, p, dp, angle = _window(engine, 5)
    st = _Setting(spec, 200.0, float(p[:, 0].mean()), math.radians(-5.0), 1.0)
    start = (math.radians(1.0), 5e3)
    want = _gauss_newton_reference(p, dp, angle, st, *start, constant_loss=constant_loss)
    got = _gauss_newton(p, dp, angle, st, *start, constant_loss=constant_loss)
    assert abs(got[0] - want[0]) < 1e-10
    assert got[1] == pytest.approx(want[1], rel=1e-6, abs=1e-6)
    assert abs(got[0] - start[0]) > 1e-6


@pytest.mark.parametrize("rows, step_deg, seed", [(5, 1.0, 0), (1, 1.0, 1), (8, 0.5, 2), (3, 2.0, 3)])
def test_smoothed_pressure_is_savgol_filter(rows, step_deg, seed):
    """The Savitzky-Golay operator against scipy's savgol_filter (mode="interp": the edges too), value and
    derivative: rtol 1e-12 of the trace's largest value (seen: 6e-15; the same least squares, another summation)."""
    from frictionwatch.core.monitor.calibration.tdc_smoothing import smoothed_pressure, smoothed_pressure_reference

    rng = np.random.default_rng(seed)
    angle = np.radians(np.arange(-180.0, 180.0, step_deg))
    p = (1e5 * (1.0 + 30.0 * np.exp(-(angle / 0.6) ** 2))[None, :] * (1.0 + 0.01 * rng.normal(size=(rows, 1)))
         + rng.normal(0.0, 3e3, (rows, angle.shape[0])))
    got, want = smoothed_pressure(p, math.radians(step_deg)), smoothed_pressure_reference(p, math.radians(step_deg))
    for g, w in zip(got, want, strict=True):
        assert g.shape == w.shape
        np.testing.assert_allclose(g, w, rtol=0, atol=1e-12 * np.max(np.abs(w)))


def test_a_smoothing_operator_made_once_smooths_as_one_made_per_call():
    """``smoothing(step)`` made once (the TDC watch: once a window close) gives ``smoothed_pressure``'s numbers
    exactly (rtol 0: the same operator, the same products); one made for another step is not used (the answer is
    that step's own, within the savgol test's tolerance of scipy)."""
    from frictionwatch.core.monitor.calibration.tdc_smoothing import (
        smoothed_pressure,
        smoothed_pressure_reference,
        smoothing,
    )

    rng = np.random.default_rng(9)
    step = math.radians(1.0)
    p = 1e5 * (1.0 + rng.uniform(0.0, 1.0, (5, 360)))
    once = smoothing(step)
    for got, want in zip(smoothed_pressure(p, step, once), smoothed_pressure(p, step), strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=0)
    other = smoothing(math.radians(0.5))
    for got, want in zip(smoothed_pressure(p, step, other), smoothed_pressure_reference(p, step), strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.max(np.abs(want)))


@pytest.mark.parametrize("m, n, seed", [(115, 2, 0), (115, 3, 1), (40, 3, 2), (3, 3, 3)])
def test_least_squares_kernel_is_lapack_gelsd(m, n, seed):
    """``least_squares_kernel`` (the Gauss-Newton step's dgelsd, called directly) against scipy's lstsq with the
    gelsd driver, the same LAPACK routine and library (scipy.linalg.cython_lapack), at the step's rcond: equal bit for
    bit (rtol 0) on a Jacobian's scales (columns ~1e6 and ~1e-2 apart), a rank-deficient one (a column repeated:
    dgelsd's minimum-norm answer) and a square one; a non-finite entry raises LinAlgError (tdc_window catches it)."""
    import scipy.linalg
    from frictionwatch.core.monitor.calibration.tdc_kernels import EPS, least_squares_kernel

    rng = np.random.default_rng(seed)
    a = rng.normal(size=(m, n)) * np.array([1e4, 1e-2, 1.0])[:n]
    b = rng.normal(size=m) * 1e3
    deficient = a.copy()
    deficient[:, -1] = deficient[:, 0]
    for jac in (a, deficient):
        rcond = EPS * max(m, n)
        want = scipy.linalg.lstsq(jac, b, cond=rcond, lapack_driver="gelsd")[0]
        np.testing.assert_allclose(least_squares_kernel(jac, b, rcond), want, rtol=0, atol=0)
    b[m // 2] = np.nan
    with pytest.raises(np.linalg.LinAlgError):
        least_squares_kernel(a, b, EPS * m)
