"""Issue 25 item 2: every friction sigma carries the calibration's uncertainty (core.model.calibration).

The sensitivity of the indicated work to a TDC error against a finite difference of the project's own IMEP
integral; the variance's algebra by hand; the model file's calibration section; and, on the product's path
(analyze_log: assembler, model view, monitor), a log whose wheel is mounted off by a TDC error the monitor is not
told of: the bare preset (uncalibrated) has the truth within 2 sigma and says it is uncalibrated, a model that
claims a commissioned calibration it does not have is many sigma off (the same figure: only the sigma moved).

The uncalibrated defaults (core.model.calibration) come from the literature and the issue's real-rig figures, not
from these logs; the logs here (maruti 3000 rpm, deutz 1500 rpm) are not the ones the numbers in the docs came from.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib

import numpy as np
import pytest
from frictionwatch.core.model.calibration import Calibration, calibration_from_dict, calibration_toml
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel, load_model
from frictionwatch.core.model.indicated import net_imep
from frictionwatch.core.model.kinematics import cylinder_kinematics_kernel
from frictionwatch.core.monitor.balance.mean_balance import indicated_tdc_sensitivity
from frictionwatch.core.monitor.identify.estimate import (
    CalibrationSensitivity,
    calibration_variance,
    calibration_variance_reference,
)
from frictionwatch.service.cli import main
from frictionwatch.service.pipeline import analyze_log
from numpy.testing import assert_allclose


def _pressure_like(grid: np.ndarray, phases: np.ndarray) -> np.ndarray:
    """A fired-looking pressure (z, n) [Pa]: a peak 12 deg after each cylinder's firing TDC on a 1 bar floor."""
    local = np.mod(grid[None, :] - phases[:, None] + 2 * np.pi, 4 * np.pi) - 2 * np.pi
    return 1e5 + 80e5 * np.exp(-0.5 * ((local - np.radians(12.0)) / np.radians(25.0)) ** 2)


@pytest.mark.parametrize("engine", ["k9k-4cyl", "genset-v20"])
def test_tdc_sensitivity_is_the_derivative_of_the_indicated_work(engine):
    spec = load_engine(engine)
    grid = np.linspace(0.0, 4 * np.pi, 1440, endpoint=False)
    phases = np.asarray(spec.firing_angles, dtype=np.float64)
    p = _pressure_like(grid, phases)
    z = spec.n_cyl
    dx, ddx = np.empty((z, grid.size)), np.empty((z, grid.size))
    cylinder_kinematics_kernel(grid, phases, np.ascontiguousarray(spec.kinematics_params()), dx, ddx)
    got = indicated_tdc_sensitivity(grid, p, ddx, spec.piston_area)
    # reference: the work with each cylinder's phase moved +-h (the true TDC h later), central difference
    h = np.radians(0.05)
    to_torque = spec.displacement_cyl / (4 * np.pi)
    params = spec.kinematics_params()
    plus = net_imep(grid, p, phases + h, params, spec.piston_area, spec.displacement_cyl) * to_torque
    minus = net_imep(grid, p, phases - h, params, spec.piston_area, spec.displacement_cyl) * to_torque
    assert_allclose(got, (plus - minus) / (2 * h), rtol=2e-3)
    # a true TDC later than stated leaves less of the peak after it as expansion work: the stated TDC reads the work
    # high, so friction high (the simulator: tdc_offset +1.0 deg read the K9K's friction +57 %)
    assert np.all(got < 0)


def test_calibration_variance_by_hand():
    cal = Calibration(tdc_wheel_sigma_deg=0.5, tdc_cylinder_sigma_deg=0.2, gain_sigma=0.03, gain_common_sigma=0.01,
                      inertia_sigma=0.05)
    s = np.array([10.0, -12.0, 11.0])  # N m / rad
    t_i = np.array([50.0, 55.0, 52.0])
    per, total = calibration_variance(cal, CalibrationSensitivity(s, t_i, kinetic=4.0))
    w, c = math.radians(0.5), math.radians(0.2)
    assert_allclose(per, s**2 * (w**2 + c**2) + t_i**2 * (0.03**2 + 0.01**2), rtol=1e-12)
    # the wheel's error and the common gain move every cylinder alike: their part of the total is (sum s)^2 and
    # (sum T_i)^2, not sums of squares
    assert_allclose(total, (s.sum() * w) ** 2 + np.sum(s**2) * c**2 + np.sum((0.03 * t_i) ** 2)
                    + (0.01 * t_i.sum()) ** 2 + (0.05 * 4.0) ** 2, rtol=1e-12)
    none = Calibration(status="commissioned", tdc_wheel_sigma_deg=0.0, tdc_cylinder_sigma_deg=0.0, gain_sigma=0.0,
                       gain_common_sigma=0.0, inertia_sigma=0.0)
    per0, total0 = calibration_variance(none, CalibrationSensitivity(s, t_i))
    assert_allclose(per0, 0.0) and math.isclose(total0, 0.0)


def test_each_channel_s_own_sigma_reaches_its_own_cylinder_only():
    """A channel whose gain commissioning knows worse (an uncorrected 2.5 % reading beside siblings at 0.4 %, design
    note 170) widens its own cylinder's friction sigma, by that channel's sigma, not the rms every channel shared."""
    s = np.array([10.0, -12.0, 11.0, 9.0])  # N m / rad
    t_i = np.array([50.0, 55.0, 52.0, 51.0])
    gains, tdcs = (0.004, 0.025, 0.004, 0.004), (0.02, 0.02, 0.12, 0.02)
    cal = Calibration(status="commissioned", tdc_wheel_sigma_deg=0.06, tdc_cylinder_sigma_deg=0.06, gain_sigma=0.013,
                      gain_common_sigma=0.01, inertia_sigma=0.05, gain_sigmas=gains, tdc_cylinder_sigmas_deg=tdcs)
    per, total = calibration_variance(cal, CalibrationSensitivity(s, t_i, kinetic=4.0))
    w, c = math.radians(0.06), np.radians(tdcs)
    g = np.array(gains)
    assert_allclose(per, s**2 * (w**2 + c**2) + t_i**2 * (g**2 + 0.01**2), rtol=1e-12)
    assert_allclose(total, (s.sum() * w) ** 2 + np.sum((s * c) ** 2) + np.sum((g * t_i) ** 2)
                    + (0.01 * t_i.sum()) ** 2 + (0.05 * 4.0) ** 2, rtol=1e-12)
    # against the one rms for every channel (0.013): cylinder 2's calibration sigma 1.6x wider, its siblings' narrower
    rms = calibration_variance(dataclasses.replace(cal, gain_sigmas=(), tdc_cylinder_sigmas_deg=()),
                               CalibrationSensitivity(s, t_i, kinetic=4.0))[0]
    assert_allclose(np.sqrt(per[1] / rms[1]), 1.64, atol=0.01)
    assert np.all(per[[0, 3]] < rms[[0, 3]])
    per_r, total_r = calibration_variance_reference(cal, CalibrationSensitivity(s, t_i, kinetic=4.0))
    assert_allclose(per, per_r, rtol=1e-14) and math.isclose(total, total_r, rel_tol=1e-14)


def test_per_cylinder_sigmas_are_checked_and_travel_in_the_model_file():
    cal = Calibration(status="commissioned", gain_sigmas=(0.004, 0.025, 0.004), tdc_cylinder_sigmas_deg=(0.02, 0.1,
                                                                                                          0.03))
    back = calibration_from_dict(tomllib.loads(calibration_toml(cal))["model"]["calibration"])
    assert back == cal
    with pytest.raises(ValueError, match="one number per cylinder"):
        Calibration(gain_sigmas=(0.01, 0.02), tdc_cylinder_sigmas_deg=(0.1, 0.1, 0.1))
    with pytest.raises(ValueError, match="gain_sigmas"):
        Calibration(gain_sigmas=(0.01, float("nan")))
    with pytest.raises(ValueError, match="3 per-cylinder sigmas for 4 cylinders"):
        cal.own_variances(4)


@pytest.mark.parametrize("z", [1, 3, 4, 20])
def test_calibration_variance_kernel_matches_its_numpy_reference(z):
    """Seeded sensitivities of both signs; the kernel sums in order where numpy sums pairwise: 1e-14 relative."""
    rng = np.random.default_rng(z)
    cal = Calibration(tdc_wheel_sigma_deg=0.4, tdc_cylinder_sigma_deg=0.15, gain_sigma=0.02, gain_common_sigma=0.015,
                      inertia_sigma=0.04)
    for kinetic in (float("nan"), -3.0, 7.5):
        sens = CalibrationSensitivity(rng.normal(0.0, 20.0, z), rng.normal(40.0, 30.0, z), kinetic)
        per, total = calibration_variance(cal, sens)
        per_r, total_r = calibration_variance_reference(cal, sens)
        assert_allclose(per, per_r, rtol=1e-14)
        assert_allclose(total, total_r, rtol=1e-14)
    # the load's term, read both ways, split by a share (or equally where the share is not one)
    for load, power in ((150.0, False), (2.0e4, True), (float("nan"), True)):
        for share in (rng.uniform(1.0, 5.0, z), np.full(z, np.nan), None):
            sens = CalibrationSensitivity(rng.normal(0.0, 20.0, z), rng.normal(40.0, 30.0, z), 1.0, load, power)
            per, total = calibration_variance(cal, sens, share)
            per_r, total_r = calibration_variance_reference(cal, sens, share)
            assert_allclose(per, per_r, rtol=1e-14)
            assert_allclose(total, total_r, rtol=1e-14)


def test_the_load_s_error_moves_the_total_whole_and_each_cylinder_by_its_part():
    """A load reading's relative error moves the balance's friction by that fraction of the load, all of it into the
    total and into each cylinder by its part of the friction."""
    none = Calibration(status="commissioned", tdc_wheel_sigma_deg=0.0, tdc_cylinder_sigma_deg=0.0, gain_sigma=0.0,
                       gain_common_sigma=0.0, inertia_sigma=0.0, load_torque_sigma=0.004, load_power_sigma=0.02)
    s, t_i, share = np.zeros(3), np.array([50.0, 55.0, 52.0]), np.array([2.0, 1.0, 1.0])
    per, total = calibration_variance(none, CalibrationSensitivity(s, t_i, load=300.0), share)
    assert_allclose(total, (0.004 * 300.0) ** 2, rtol=1e-12)
    assert_allclose(per, (0.004 * 300.0 * np.array([0.5, 0.25, 0.25])) ** 2, rtol=1e-12)
    per, total = calibration_variance(none, CalibrationSensitivity(s, t_i, load=300.0, load_from_power=True))
    assert_allclose(total, (0.02 * 300.0) ** 2, rtol=1e-12)
    assert_allclose(per, np.full(3, (0.02 * 300.0 / 3.0) ** 2), rtol=1e-12)


def test_model_file_keeps_its_calibration_and_refuses_unknown_keys():
    model = load_model("k9k-4cyl")
    assert model.calibration.status == "uncalibrated" and "[model.calibration]" not in model.to_toml()
    cal = Calibration(status="commissioned", tdc_wheel_sigma_deg=0.04, tdc_cylinder_sigma_deg=0.03, gain_sigma=0.004,
                      inertia_sigma=0.02, source='commission "a" 2 files')
    commissioned = dataclasses.replace(model, calibration=cal)
    back = EngineModel.from_toml(commissioned.to_toml())
    assert back == commissioned and back.calibration == cal and back != model
    bad = commissioned.to_toml().replace("gain_sigma", "gain_sigmas")
    with pytest.raises(ValueError, match="gain_sigmas"):
        EngineModel.from_toml(bad)
    # the cylinders' own TDC readings travel with it (a TOML array each), one per cylinder or none
    read = dataclasses.replace(cal, tdc_cylinder_reading_deg=(0.0, -0.261, 0.05, 0.0),
                               tdc_cylinder_reading_sigma_deg=(0.01, 0.012, 0.5, 0.009))
    back = EngineModel.from_toml(dataclasses.replace(model, calibration=read).to_toml())
    assert back.calibration == read
    with pytest.raises(ValueError, match="3 numbers for 4 cylinders"):
        EngineModel.from_toml(dataclasses.replace(model, calibration=dataclasses.replace(
            read, tdc_cylinder_reading_deg=(0.0, 0.1, 0.2), tdc_cylinder_reading_sigma_deg=(0.01,) * 3)).to_toml())
    with pytest.raises(ValueError, match="two lists"):
        dataclasses.replace(read, tdc_cylinder_reading_sigma_deg=(0.01,))
    with pytest.raises(ValueError, match="not a reading"):
        dataclasses.replace(read, tdc_cylinder_reading_deg=(0.0, float("nan"), 0.0, 0.0))
    with pytest.raises(ValueError, match="status"):
        Calibration(status="calibrated")
    with pytest.raises(ValueError, match="gain_sigma"):
        Calibration(gain_sigma=-0.01)


CASES = [  # (engine, rpm, load, wheel TDC offset deg): not the operating points the docs' figures came from
    ("maruti-3cyl", 3000.0, 0.8, 0.6),
    ("deutz-1cyl", 1500.0, 0.8, -1.0),
]


@pytest.fixture(scope="module", params=CASES, ids=[f"{c[0]}-{c[3]:+.1f}deg" for c in CASES])
def offset_log(request, tmp_path_factory):
    engine, rpm, load, deg = request.param
    out = tmp_path_factory.mktemp("tdc")
    log = out / "log.mcap"
    assert main(["simulate", "--engine", engine, "--rpm", str(rpm), "--load", str(load), "--cycles", "60", "--seed",
                 "11", "--effect", f"tdc_offset:deg={deg},cylinder=0", "-o", str(log)]) == 0
    truth = json.loads((out / "log.truth.json").read_text())
    model = dataclasses.replace(load_model(engine), calibration=Calibration(
        status="commissioned", tdc_wheel_sigma_deg=0.02, tdc_cylinder_sigma_deg=0.02, gain_sigma=0.002, gain_common_sigma=0.002,
        inertia_sigma=0.01, source="a claim this test knows to be false"))
    (out / "claimed.toml").write_text(model.to_toml(), encoding="utf-8")
    return log, out / "claimed.toml", truth


def _engine_figure(analysis):
    est = analysis.results[-1].smoothed
    return est.total_friction_torque, est.total_friction_torque_sigma, est


def test_uncalibrated_sigma_covers_a_wheel_tdc_offset(offset_log):
    log, claimed, truth = offset_log
    t_true = truth["friction_torque_mean_nm"]
    t, s, est = _engine_figure(analyze_log(log))
    assert est.calibration == "uncalibrated" and est.total_calibration_sigma > 0.5 * s
    err = abs(t - t_true)
    assert err > 0.1 * t_true  # the offset does move friction a lot (else this test shows nothing)
    assert err < 2.0 * s, f"friction {t:.2f} +- {s:.2f} N m, truth {t_true:.2f}"
    # the same log under a model that claims a tight calibration: the same figure, a sigma that no longer covers it
    t2, s2, est2 = _engine_figure(analyze_log(log, engine=str(claimed)))
    assert est2.calibration == "commissioned"
    assert_allclose(t2, t, rtol=1e-9)
    assert abs(t2 - t_true) > 3.0 * s2
