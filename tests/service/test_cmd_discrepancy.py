"""`frictionwatch discrepancy` end to end on one small log with a hidden sensor gain: the JSON report, the augmented
model file that `analyze --engine` accepts, the offline HTML report; bad input is one line and exit code 2; the
service-facing run_discrepancy on records."""

from __future__ import annotations

import json

import numpy as np
import pytest
from frictionwatch.core.discrepancy import Options
from frictionwatch.core.model.engine_model import EngineModel, load_model
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.cli import main
from frictionwatch.service.cmd_discrepancy import discrepancy_of, run_discrepancy, with_baseline
from frictionwatch.service.pipeline import resolve_model

pytestmark = pytest.mark.slow  # collected first (tests/conftest.py): one of the suite's longest files


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("disc")
    log = out / "k9k-gain.mcap"
    assert main(["simulate", "--engine", "k9k-4cyl", "--rpm", "2500", "--load", "0.8", "--cycles", "84", "--seed",
                 "6", "--effect", "pressure_gain:cylinder=3,gain=1.06", "-o", str(log)]) == 0
    return out


@pytest.fixture(scope="module")
def report(run_dir):
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["discrepancy", str(run_dir / "k9k-gain.mcap"), "--json", "--max-steps", "1", "-o",
                   str(run_dir / "augmented.toml"), "--report", str(run_dir / "report")])
    assert rc == 0
    return json.loads(buf.getvalue())


def test_json_report_names_the_hidden_gain(report):
    assert {"found", "gap_before", "gap_after", "metric", "verdict", "localisation"} <= report.keys()
    assert len(report["found"]) == 1
    f = report["found"][0]
    assert {"effect", "cylinder", "parameters", "sigma", "evidence"} <= f.keys()
    assert (f["effect"], f["cylinder"]) == ("pressure_gain", 3)
    np.testing.assert_allclose(f["parameters"]["gain"], 1.06, atol=0.012)
    assert report["gap_after"] < report["gap_before"]


def test_augmented_model_reads_back_and_analyze_accepts_it(report, run_dir):
    path = run_dir / "augmented.toml"
    model = load_model(path)
    added = [e for e in model.effects if e.name == "pressure_gain"]
    assert len(added) == 1 and added[0]["cylinder"] == 3 and "gain" in added[0].sigma
    assert EngineModel.from_toml(path.read_text()) == model
    from frictionwatch.drivers.logs.mcap_log import LogReader

    with LogReader(run_dir / "k9k-gain.mcap") as reader:
        assert resolve_model(reader.engine_toml, str(path), "k9k-gain.mcap", reader.info) == model


def test_html_report_is_offline_and_has_the_plots(report, run_dir):
    text = (run_dir / "report" / "discrepancy.html").read_text()
    assert text.count("<svg") >= 2 and "pressure_gain" in text
    for fetch in ("src=\"http", "src='http", "<link", "url(http", "<script"):
        assert fetch not in text


def test_run_discrepancy_on_records(run_dir):
    sim = simulate(load_model("k9k-4cyl").spec, 2500, 0.8, 40, 3)
    doc, found = discrepancy_of((sim.info, sim.records), "k9k-4cyl", Options(max_steps=0))
    assert doc["found"] == [] and doc["cycles"] >= 38 and doc["engine"] == "k9k-4cyl"
    assert found.model == load_model("k9k-4cyl")
    assert run_discrepancy((sim.info, sim.records), "k9k-4cyl", Options(max_steps=0))["gap_before"] == pytest.approx(
        doc["gap_before"], rel=1e-12)  # the service's call: the same report, deterministic


def _fails_with_one_line(args, capsys, *needles):
    rc = main(args)
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err


def test_bad_input_is_one_line(run_dir, capsys, tmp_path):
    log = str(run_dir / "k9k-gain.mcap")
    _fails_with_one_line(["discrepancy", log, "--baseline", "stiff"], capsys, "--baseline")
    _fails_with_one_line(["discrepancy", log, "--baseline", "without:ring_wear"], capsys, "no effect ring_wear")
    _fails_with_one_line(["discrepancy", str(tmp_path / "none.mcap")], capsys, "none.mcap")
    _fails_with_one_line(["discrepancy", log, "--max-steps", "-1"], capsys, "--max-steps")
    _fails_with_one_line(["discrepancy", log, "--engine", "genset-v20"], capsys, "does not match")


def test_with_baseline_drops_the_named_defaults():
    model = load_model("k9k-4cyl")
    names = {e.name for e in with_baseline(model, "rigid").effects}
    assert "torsional_flexibility" not in names and "variable_inertia" not in names and "sensor_noise" in names
    assert with_baseline(model, "default") is model
