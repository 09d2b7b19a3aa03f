"""Fired, motored and misfire on the TU/e 4GB10 group14 files (issue 25 item 4): motored cycles (ignition off,
coast-downs) carry the ``motored`` flag and are reported as their own regime, never as misfires; the partial burn of
E0NOLOAD4 (IMEP 0.11 bar among full burns of 0.9-2.0 bar) is a misfire.

The burn threshold (core.monitor.condition.ConditionSettings.burn_log_ratio) was calibrated on ENGINEOFF, ENGINEOFF2
and E0NOLOAD1..3 (and simulated logs); the files here are the others."""

from __future__ import annotations

import contextlib
import io
import json

import pytest
from frictionwatch.service.cli import main

FOLDER = "tue-4gb10-si-encoder-pressure"
IMPORT = ["--engine", "tue-4gb10", "--tdc-deg", "244.5", "--gain-bar-per-v", "12.4"]


def _analyze(realdata, tmp_path, name: str) -> dict:
    log = tmp_path / f"{name}.mcap"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["import-daq", str(realdata / FOLDER / f"group14_{name}.txt.gz"), *IMPORT, "-o", str(log)]) == 0
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["analyze", str(log), "--json"]) == 0
    return json.loads(buf.getvalue())


def _regimes(doc: dict) -> dict:
    return {g["regime"]: g for g in doc["regimes"]}


def test_ignition_off_splits_the_run_into_fired_then_motored(realdata, tmp_path):
    doc = _analyze(realdata, tmp_path, "E0FULLOAD4EngineOff")  # ignition off at ~rev 12 (the data's README)
    g = _regimes(doc)
    assert list(g) == ["fired", "motored"]
    assert g["fired"]["last_cycle"] + 1 == g["motored"]["first_cycle"]  # one switch, no cycle in between
    assert g["fired"]["imep_bar"] > 4.0 and g["motored"]["imep_bar"] < 0.0
    assert g["fired"]["misfire_cycles"] == g["motored"]["misfire_cycles"] == 0
    assert not any(k.startswith("misfire") for k in doc["flags"]["run"])
    assert doc["flags"]["run"]["motored"] == g["motored"]["cycles"] >= 3


@pytest.mark.parametrize("name", ["E5FULLOAD4EngineOff", "ENGINEOFF3", "ENGINEOFF4", "ENGINEOFF5", "ENGINEOFF6"])
def test_coast_downs_are_motored_not_misfires(realdata, tmp_path, name):
    doc = _analyze(realdata, tmp_path, name)
    assert [g["regime"] for g in doc["regimes"]] == ["motored"]
    assert doc["flags"]["run"]["motored"] == doc["cycles_ok"]
    assert not any(k.startswith("misfire") for k in doc["flags"]["run"])


@pytest.mark.parametrize("name", ["E0FULLOAD2", "E0FULLOAD3", "E0HALFLOAD1", "E0HALFLOAD2", "E0HALFLOAD3",
                                  "E0HALFLOAD4"])
def test_fired_files_have_no_motored_cycle_and_no_misfire(realdata, tmp_path, name):
    doc = _analyze(realdata, tmp_path, name)
    assert [g["regime"] for g in doc["regimes"]] == ["fired"] and doc["regimes"][0]["misfire_cycles"] == 0


def test_the_partial_burn_is_a_misfire(realdata, tmp_path):
    doc = _analyze(realdata, tmp_path, "E0NOLOAD4")
    g = _regimes(doc)
    assert list(g) == ["fired"] and g["fired"]["misfire_cycles"] == 1
    assert doc["flags"]["run"]["misfire_cyl1"] == 1 and "motored" not in doc["flags"]["run"]
