"""The CLI end to end: simulate -> analyze on a small log, and every expected failure is one line + exit code 2."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
from frictionwatch.service.cli import main

from tests.analyze_doc import assert_fmep_is_torque_over_displacement


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "k9k.mcap"
    rc = main(["simulate", "--engine", "k9k-4cyl", "--rpm", "1400", "--load", "0.6", "--cycles", "12", "--seed", "5",
               "-o", str(out)])
    assert rc == 0
    return out


def test_simulate_writes_log_and_truth(small_log):
    truth = json.loads(small_log.with_name("k9k.truth.json").read_text())
    assert small_log.stat().st_size > 10_000
    assert {"fmep_bar", "cylinders", "cycles", "effects"} <= truth.keys()
    assert len(truth["cylinders"]) == 4 and len(truth["cylinders"][0]["coefficients"]) == 6


def test_analyze_json_has_the_truth_keys_and_is_close(small_log, capsys, tmp_path):
    assert main(["analyze", str(small_log), "--json", "--csv", str(tmp_path / "c.csv"), "--plot",
                 str(tmp_path / "plots")]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert assert_fmep_is_torque_over_displacement(doc) >= 2
    truth = json.loads(small_log.with_name("k9k.truth.json").read_text())
    assert doc["cycles_ok"] >= 10 and isinstance(doc["cycles_skipped"], dict)
    for got, want in zip(doc["cylinders"], truth["cylinders"]):
        assert got["cylinder"] == want["cylinder"]
        assert set(want) & {"friction_torque_mean_nm", "fmep_bar", "imep_bar", "coefficients"} <= set(got)
        assert got["imep_bar"] == pytest.approx(want["imep_bar"], rel=0.01)
    # 12 cycles: fewer than the monitor's 20 warm-up cycles, so the smoothed estimate is the prior, labelled, and
    # no number under the measured key; the run mean of the measured balance is the measurement
    assert doc["friction"]["status"] == "prior" and doc["fmep_bar"] is None
    assert doc["friction_run_mean_balance"]["status"] == "measured"
    assert doc["friction_run_mean_balance"]["fmep_bar"] == pytest.approx(truth["fmep_bar"], rel=0.05)  # accuracy proper: tests/core
    assert len(list((tmp_path / "plots").glob("*.png"))) == 3
    assert len((tmp_path / "c.csv").read_text().splitlines()) == 1 + 4 * doc["cycles_ok"]


def test_analyze_prints_a_table(small_log, capsys):
    assert main(["analyze", str(small_log)]) == 0
    out = capsys.readouterr().out
    assert "FMEP" in out and len([ln for ln in out.splitlines() if ln.strip()[:1].isdigit()]) == 4


def _fails_with_one_line(args, capsys, *needles):
    rc = main(args)
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err


def test_bad_engine_file(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text((tmp_path / "x").as_posix() and 'name = "x"\n[geometry]\nbore_m = 7.0\n')
    _fails_with_one_line(["simulate", "--engine", str(bad), "--rpm", "1500", "--cycles", "2", "-o",
                          str(tmp_path / "o.mcap")], capsys, "geometry.bore_m = 7.0 is out of range")


def test_unknown_engine_and_effect_and_impossible_parameter(tmp_path, capsys):
    out = str(tmp_path / "o.mcap")
    base = ["simulate", "--engine", "k9k-4cyl", "--rpm", "1500", "--cycles", "2", "-o", out]
    _fails_with_one_line(["simulate", "--engine", "v99", "--rpm", "1500", "-o", out], capsys, "unknown engine 'v99'")
    _fails_with_one_line(base + ["--effect", "warp_drive"], capsys, "unknown effect 'warp_drive'")
    _fails_with_one_line(base + ["--effect", "ring_wear:cyl=2"], capsys, "has no parameter 'cyl'")
    _fails_with_one_line(base + ["--effect", "ring_wear:cylinder=9"], capsys, "cylinder")
    _fails_with_one_line(base + ["--without", "gravity"], capsys, "gravity")
    _fails_with_one_line(base + ["--effect", "ring_wear:gain=lots"], capsys, "gain='lots': expected a number")
    _fails_with_one_line(base + ["--effect", "load_ripple", "--effect", "load_ripple:order=2"], capsys,
                         "effect 'load_ripple' is given twice")
    _fails_with_one_line(base + ["--effect", "misfire:cylinder=2", "--effect", "misfire:cylinder=2"], capsys,
                         "effect 'misfire' is given twice for cylinder 2")
    _fails_with_one_line(["simulate", "--engine", "k9k-4cyl", "--rpm", "99999", "-o", out], capsys, "speed range")


def test_the_same_effect_in_two_cylinders_is_kept_twice(tmp_path):
    out = tmp_path / "worn.mcap"
    assert main(["simulate", "--engine", "k9k-4cyl", "--rpm", "1500", "--cycles", "2", "--effect",
                 "ring_wear:cylinder=1", "--effect", "ring_wear:cylinder=2,gain=1.2", "-o", str(out)]) == 0
    truth = json.loads(out.with_name("worn.truth.json").read_text())
    worn = [e["params"] for e in truth["effects"] if e["name"] == "ring_wear"]
    assert [(p["cylinder"], p["gain"]) for p in worn] == [(1, 1.4), (2, 1.2)]
    a0 = truth["cylinders"][2]["coefficients"][0]  # cylinder 3: untouched
    assert truth["cylinders"][0]["coefficients"][0] == pytest.approx(1.4 * a0)
    assert truth["cylinders"][1]["coefficients"][0] == pytest.approx(1.2 * a0)


def test_analyze_missing_and_non_mcap_file(tmp_path, capsys):
    _fails_with_one_line(["analyze", str(tmp_path / "nope.mcap")], capsys, "no such log")
    _fails_with_one_line(["analyze", str(tmp_path)], capsys, "is a folder, not a log")
    # serve's replay source opens the log itself (drivers.logs.mcap_reader): the same words, not "[Errno 2] ..."
    _fails_with_one_line(["serve", "--port", "0", "--source", f"mcap:{tmp_path / 'nope.mcap'}"], capsys,
                         "no such log")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"this is not an mcap file" * 100)
    _fails_with_one_line(["analyze", str(junk)], capsys)


def test_console_script_runs_as_a_process(small_log):
    proc = subprocess.run([sys.executable, "-m", "frictionwatch.service.cli", "analyze", str(small_log), "--json"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["engine"] == "k9k-4cyl"


def test_analyze_takes_a_model_file(tmp_path, capsys):
    """A model file (core.model.EngineModel.to_toml) given as --engine brings its loss terms into the monitor."""
    from frictionwatch.core.model import EngineModel, auxiliaries_quadratic, load_engine

    model = EngineModel.from_spec(load_engine("deutz-1cyl")).with_term(auxiliaries_quadratic(), 1e-5)
    path = tmp_path / "deutz-aux.toml"
    path.write_text(model.to_toml())
    log = Path(__file__).resolve().parents[2] / "replay_logs" / "deutz-1cyl.mcap"
    assert main(["analyze", str(log), "--engine", str(path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert_fmep_is_torque_over_displacement(doc)
    assert len(doc["cylinders"][0]["coefficients"]) == 7  # the six Rezeka-Henein terms and the added one
