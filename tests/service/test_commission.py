"""`frictionwatch commission`: a log whose wheel is mounted off and one of whose pressure channels reads high (effects
the monitor is not told of) is commissioned; `analyze --engine` with the model it wrote then reads friction near the
truth with a sigma that covers it, where the bare preset read it far off. The engine and operating point (k9k-4cyl
at 2200 rpm, load 0.7, seed 21) are not those the TDC finder's windows were tuned on (k9k 1700 rpm / 1.0, maruti
3000 rpm / 0.8, seed 1: core/monitor/calibration/tdc.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from frictionwatch.core.model.engine_model import load_model
from frictionwatch.service.cli import main
from frictionwatch.service.pipeline import analyze_log

WHEEL_DEG = 0.8
GAIN = 1.06  # cylinder 3 reads 6 % high


@pytest.fixture(scope="module")
def commissioned(tmp_path_factory):
    out = tmp_path_factory.mktemp("commission")
    log = out / "k9k.mcap"
    assert main(["simulate", "--engine", "k9k-4cyl", "--rpm", "2200", "--load", "0.7", "--cycles", "120", "--seed",
                 "21", "--effect", f"tdc_offset:deg={WHEEL_DEG},cylinder=0",
                 "--effect", f"pressure_gain:cylinder=3,gain={GAIN}", "-o", str(log)]) == 0
    model = out / "model.toml"
    assert main(["commission", str(log), "-o", str(model), "--json"]) == 0
    truth = json.loads((out / "k9k.truth.json").read_text())
    return log, model, truth


def test_commission_finds_the_wheel_and_the_channel(commissioned):
    _, model_path, _ = commissioned
    model = load_model(str(model_path))
    assert model.calibration.status == "commissioned"
    wheel = [e for e in model.effects if e.name == "tdc_offset" and e.values["cylinder"] == 0]
    assert len(wheel) == 1
    deg, sigma = wheel[0].values["deg"], wheel[0].sigma["deg"]
    assert abs(deg - WHEEL_DEG) <= max(2.0 * sigma, 0.15), f"wheel {deg:+.3f} +- {sigma:.3f} deg, truth {WHEEL_DEG}"
    gains = {e.values["cylinder"]: e.values["gain"] for e in model.effects if e.name == "pressure_gain"}
    assert list(gains) == [3], gains  # the faulty channel, and only it
    np.testing.assert_allclose(gains[3], GAIN, atol=0.015)
    # each cylinder's own sigmas are written (design note 170): the TDC's rms is the summary scalar; the corrected
    # channel's gain sigma holds its whole correction (a cylinder's own charge reads alike), its siblings' do not
    cal = model.calibration
    np.testing.assert_allclose(np.sqrt(np.mean(np.square(cal.tdc_cylinder_sigmas_deg))), cal.tdc_cylinder_sigma_deg,
                               rtol=2e-3)
    assert cal.gain_sigmas[2] >= abs(gains[3] - 1.0) and max(np.delete(cal.gain_sigmas, 2)) < 0.5 * abs(gains[3] - 1.0)


def test_analyze_with_the_commissioned_model_is_right_and_honest(commissioned):
    log, model_path, truth = commissioned
    t_true = truth["friction_torque_mean_nm"]
    bare = analyze_log(log).results[-1].smoothed
    done = analyze_log(log, engine=str(model_path)).results[-1].smoothed
    assert done.calibration == "commissioned" and bare.calibration == "uncalibrated"
    err_bare = abs(bare.total_friction_torque - t_true)
    err_done = abs(done.total_friction_torque - t_true)
    assert err_bare > 0.2 * t_true  # the hidden effects move the bare preset's friction a lot
    assert err_done < 0.5 * err_bare
    assert err_done <= 2.0 * done.total_friction_torque_sigma
    assert done.total_friction_torque_sigma < bare.total_friction_torque_sigma


def test_commission_refuses_too_few_cycles_and_writes_nothing(tmp_path, capsys):
    log = tmp_path / "short.mcap"
    assert main(["simulate", "--engine", "maruti-3cyl", "--rpm", "3000", "--load", "0.8", "--cycles", "8", "--seed",
                 "2", "-o", str(log)]) == 0
    model = tmp_path / "model.toml"
    assert main(["commission", str(log), "-o", str(model)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "fired" in err[0], err
    assert not model.exists() and not list(tmp_path.glob("*.tmp*"))


def test_commission_identifies_the_drive_train_from_the_second_wheel(tmp_path):
    """genset-v20 with its free-end wheel, every shaft section 15 % softer than its engine file says, seed 21 (not
    a seed the identification was explored on: 5, 7, 11): the written model carries the identified chain_mismatch
    (0.850 +- 0.001 seen) and its sigmas in the calibration section, and no cylinder TDC of its own (the TDCs are
    found after the drive train, with its twist: before, a -0.29 deg offset of cylinder 8 was written)."""
    from bench.drive_train_identification import TWO_WHEELS

    log = tmp_path / "g.mcap"
    assert main(["simulate", "--engine", str(TWO_WHEELS), "--rpm", "1500", "--load", "0.75", "--cycles", "80",
                 "--seed", "21", "--second-wheel", "--effect", "chain_mismatch:stiffness_scale=0.85,damping_scale=1.0",
                 "-o", str(log)]) == 0
    assert main(["commission", str(log), "--engine", str(TWO_WHEELS), "-o", str(tmp_path / "m.toml"), "--json"]) == 0
    model = load_model(str(tmp_path / "m.toml"))
    (chain,) = [e for e in model.effects if e.name == "chain_mismatch"]
    k, sk = chain.values["stiffness_scale"], chain.sigma["stiffness_scale"]
    assert abs(k - 0.85) <= 2.0 * sk, f"stiffness x {k} +- {sk}"
    np.testing.assert_allclose(model.calibration.stiffness_sigma, sk / k, rtol=0.02)
    assert [e.values["cylinder"] for e in model.effects if e.name == "tdc_offset"] == [0]
