"""frictionwatch.core.monitor.report.cycle_report.speed_series against its plain-numpy reference: the code it replaced in
core.monitor.report.cycle_report.build_result (speed_residual, speed_power and two inverse series by irfft), copied here. Seeded
inputs of the real sizes (genset-v20: M = 24, P = 47 with 24 nuisances, 256 time samples) and small ones.
Tolerance: the direct sums differ from the FFT by rounding, 1e-13 of the series' size; the rest bit for bit."""

import numpy as np
import pytest
from frictionwatch.core.monitor.report.cycle_report import speed_power, speed_residual, speed_series, trig_tables
from frictionwatch.core.monitor.teeth.flywheel import harmonic_series
from numpy.testing import assert_allclose


def speed_series_reference(design, target, theta, p_f, drift, use_drift, freq, harmonics, omega_fly):
    m = target.shape[0]
    series = np.empty((2, m), dtype=np.complex128)
    resid_sq = speed_residual(design, target, theta, p_f, drift, use_drift, series)
    pattern, resid_t = harmonic_series(series, omega_fly.shape[0])
    omega_meas = omega_fly - pattern
    return series[1].copy(), omega_meas, omega_meas - resid_t, resid_sq, speed_power(freq, harmonics)


@pytest.mark.parametrize("m,p_f,p,n_t", ((24, 23, 47, 256), (24, 23, 47, 512), (16, 5, 21, 256), (12, 6, 18, 128)))
@pytest.mark.parametrize("use_drift", (True, False))
def test_speed_series_matches_reference(m, p_f, p, n_t, use_drift):
    rng = np.random.default_rng(m + n_t)
    design = 1e-3 * (rng.normal(size=(m, p)) + 1j * rng.normal(size=(m, p)))
    target = 1e-2 * (rng.normal(size=m) + 1j * rng.normal(size=m))
    theta = rng.uniform(0.5, 1.5, p)
    drift = rng.normal(size=m) + 1j * rng.normal(size=m)
    freq = 0.5 * 157.0 * np.arange(1, m + 1)
    harmonics = 1e-4 * (rng.normal(size=m) + 1j * rng.normal(size=m))
    omega_fly = 157.0 + 0.5 * np.sin(np.arange(n_t) * (2 * np.pi / n_t))
    tables = trig_tables(m, n_t)
    resid = np.empty(m, dtype=np.complex128)
    extra = np.empty((2, n_t))
    sq, power = speed_series(design, target, theta, p_f, drift, use_drift, freq, harmonics, omega_fly, tables.table,
                             resid, extra)
    r_resid, r_meas, r_model, r_sq, r_power = speed_series_reference(design, target, theta, p_f, drift, use_drift,
                                                                     freq, harmonics, omega_fly)
    # the same residual kernel on both sides: equal to rounding (1e-14 relative)
    assert_allclose(resid, r_resid, rtol=1e-14, atol=1e-14 * np.abs(r_resid).max())
    assert sq == pytest.approx(r_sq, rel=1e-14) and power == pytest.approx(r_power, rel=1e-14)
    scale = np.abs(omega_fly).max()
    assert_allclose(extra[0], r_meas, rtol=0, atol=1e-15 * scale)
    assert_allclose(extra[1], r_model, rtol=0, atol=1e-15 * scale)
    # and the ripple itself (the part that is not the mean speed) to 1e-12 of its size
    ripple = np.abs(r_model - omega_fly).max()
    assert_allclose(extra[1] - omega_fly, r_model - omega_fly, rtol=0, atol=1e-12 * ripple)


def test_trig_tables_are_read_only_cos_and_sin():
    tables = trig_tables(5, 64)
    c, s = tables.table
    assert tables.shape == (5, 64)
    assert not tables.table.flags.writeable
    assert_allclose(s[2], np.sin(2 * np.pi * 3 * np.arange(64) / 64), atol=1e-15)
    k = np.arange(64)
    assert_allclose(c[2], np.cos(2 * np.pi * 3 * k / 64), atol=1e-15)
