"""The TDC watch (core.monitor.calibration.tdc_watch) on the product's path: a TDC that moves after commissioning is
flagged on the right cylinder within two windows and withholds that cylinder's figures; a healthy engine at another
operating point raises nothing; an uncalibrated wheel far off is flagged. The thresholds are the sensor-health
stage's (0.3 deg) and sigma multiples stated in the module; the engine points here (k9k 2200 / 2000 rpm, seeds
31-33) are not those the TDC finder was tuned on (k9k 1700 rpm / 1.0, maruti 3000 rpm / 0.8, seed 1)."""

from __future__ import annotations

import math

import pytest
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.monitor.calibration.tdc import TdcEstimate
from frictionwatch.core.monitor.calibration.tdc_watch import tdc_flags
from frictionwatch.core.monitor.report.figure_status import friction_status
from frictionwatch.service.pipeline import analyze_log

from tests.sim_logs import commissioned_model, sensor_flags, simulate_log


def _est(deg: float, sigma: float = 0.2, stat: float = 0.03) -> TdcEstimate:
    return TdcEstimate(math.radians(deg), math.radians(sigma), 0.0, 100, "test", {"statistical_deg": stat})


def test_flags_against_the_calibration():
    uncal = Calibration()
    done = Calibration(status="commissioned", tdc_wheel_sigma_deg=0.15, tdc_cylinder_sigma_deg=0.04)
    # uncalibrated: a wheel within what the assumed installation allows is not flagged; far beyond it is
    assert tdc_flags(uncal, [_est(0.6)] * 4) == ()
    assert tdc_flags(uncal, [_est(1.5)] * 4) == ("sensor_tdc_offset",)
    # commissioned: the corrections are in, 0 is expected; a 0.5 deg move is beyond 3 x hypot(0.03, 0.1) deg
    assert tdc_flags(done, [_est(0.1)] * 4) == ()
    assert tdc_flags(done, [_est(0.5)] * 4) == ("sensor_tdc_offset",)
    # one cylinder's own: named, the wheel (the median) not moved by it
    assert tdc_flags(done, [_est(0.0), _est(0.55), _est(0.02), _est(-0.03)]) == ("sensor_tdc_offset_cyl2",)
    assert tdc_flags(done, [None, None]) == ()


def _simulate(path, rpm, load, seed, effect=None, cycles=150):
    simulate_log(path, "k9k-4cyl", rpm, load, seed, cycles, effect)


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    return commissioned_model(tmp_path_factory.mktemp("watch"), "k9k-4cyl", 2200, 0.7, 31, 120)


def test_a_cylinder_tdc_drift_after_commissioning_is_flagged_on_that_cylinder(model_path, tmp_path):
    log = tmp_path / "drift.mcap"
    _simulate(log, 2000, 0.8, 32, effect="tdc_offset:deg=0.5,cylinder=2", cycles=210)
    analysis = analyze_log(log, engine=str(model_path))
    flags, first = sensor_flags(analysis)
    assert flags == ["sensor_tdc_offset_cyl2"], flags
    assert 0 <= first <= 200
    last = analysis.results[-1]
    status = friction_status(last.smoothed, last.flags)
    assert status.cylinders[1].status == "withheld"
    assert all(c.status != "withheld" for k, c in enumerate(status.cylinders) if k != 1)


def test_healthy_at_another_operating_point_raises_nothing(model_path, tmp_path):
    log = tmp_path / "healthy.mcap"
    _simulate(log, 2000, 0.8, 33, cycles=210)
    flags, first = sensor_flags(analyze_log(log, engine=str(model_path)))
    assert flags == [] and first == -1
    flags, first = sensor_flags(analyze_log(log))  # and with the bare preset (uncalibrated)
    assert flags == [] and first == -1


@pytest.mark.parametrize("engine", ["maruti-3cyl", "genset-v20"])
def test_local_traces_cut_as_the_reference(engine):
    """All cylinders in one indexing (local_traces) against tdc.local_cycles, one cylinder at a time."""
    import types

    import numpy as np
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.monitor.calibration.tdc import local_cycles
    from frictionwatch.core.monitor.calibration.tdc_watch import local_traces

    spec = load_engine(engine)
    n = 720
    grid = np.linspace(0.0, 4 * np.pi, n, endpoint=False)
    rng = np.random.default_rng(3)
    prev = types.SimpleNamespace(index=7, grid=grid, pressure=rng.uniform(1e5, 1e7, (spec.n_cyl, n)))
    cur = types.SimpleNamespace(index=8, grid=grid, pressure=rng.uniform(1e5, 1e7, (spec.n_cyl, n)))
    got, angle = local_traces(prev, cur, spec.firing_angles)
    for k, phase in enumerate(spec.firing_angles):
        ref, ref_angle = local_cycles([prev, cur], k, float(phase))
        np.testing.assert_array_equal(got[k], ref[0])
        np.testing.assert_allclose(angle, ref_angle, rtol=0, atol=1e-12)
