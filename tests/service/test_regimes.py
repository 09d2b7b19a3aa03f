"""A log mixing fired and motored cycles reports each regime (issue 25 item 4): the simulator's coast-down (ignition
off and the load disconnected at 0.4 s) on the tue-4gb10 preset. The motored cycles carry the engine's ``motored``
flag, never ``misfire``; each regime's IMEP and friction (the mean of its cycles' torque balances) against the
simulator's truth over the same cycles."""

from __future__ import annotations

import json

import numpy as np
import pytest
from frictionwatch.service.cli import main
from frictionwatch.service.cmd_analyze import SCHEMA_FILE

from tests.analyze_doc import assert_fmep_is_torque_over_displacement

jsonschema = pytest.importorskip("jsonschema")


@pytest.fixture(scope="module")
def coast(tmp_path_factory):
    out = tmp_path_factory.mktemp("coast") / "coast.mcap"
    assert main(["simulate", "--engine", "tue-4gb10", "--rpm", "3000", "--load", "0.6", "--cycles", "24", "--seed",
                 "3", "--effect", "coast_down:time_s=0.4", "-o", str(out)]) == 0
    return out, json.loads(out.with_name("coast.truth.json").read_text())


def test_each_regime_is_reported_and_motored_cycles_are_not_misfires(coast, capsys):
    log, truth = coast
    capsys.readouterr()
    assert main(["analyze", str(log), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    jsonschema.validate(doc, json.loads(SCHEMA_FILE.read_text()))
    assert_fmep_is_torque_over_displacement(doc)
    fired_truth = {c["index"] for c in truth["cycles"] if c["cylinders"][0]["imep_bar"] > 0}
    motored_truth = {c["index"] for c in truth["cycles"]} - fired_truth
    assert fired_truth and motored_truth  # the log does mix them
    regimes = {g["regime"]: g for g in doc["regimes"]}
    assert list(regimes) == ["fired", "motored"]
    assert doc["flags"]["run"].get("motored") == len(motored_truth) == regimes["motored"]["cycles"]
    assert regimes["fired"]["cycles"] == len(fired_truth)
    assert (regimes["motored"]["first_cycle"], regimes["motored"]["last_cycle"]) == (min(motored_truth),
                                                                                     max(motored_truth))
    assert not any(k.startswith("misfire") for k in doc["flags"]["run"])
    assert regimes["fired"]["misfire_cycles"] == regimes["motored"]["misfire_cycles"] == 0
    by_index = {c["index"]: c for c in truth["cycles"]}
    for name, cycles in (("fired", fired_truth), ("motored", motored_truth)):
        g = regimes[name]
        imep = np.mean([by_index[i]["cylinders"][0]["imep_bar"] for i in cycles])
        assert g["imep_bar"] == pytest.approx(imep, rel=0.02, abs=0.02)  # IMEP: tests/core hold the accuracy
        f = g["friction"]
        assert f["status"] == "measured"
        used = range(f["window"]["first_cycle"], g["last_cycle"] + 1)
        true_f = np.mean([by_index[i]["friction_torque_mean_nm"] for i in used])
        # within 3 sigma of the mean and 3 % (coast-down: 0.70 vs 0.699; fired: 0.79 vs 0.778 N m when written)
        assert abs(f["friction_torque_mean_nm"] - true_f) < 3 * f["friction_torque_sigma_nm"] + 0.03 * true_f
    assert regimes["fired"]["imep_cov"] is not None and regimes["motored"]["imep_cov"] is None
    # a healthy coast-down: its friction law is positive down to the engine's lowest speed, nothing implausible
    assert doc["transient"]["checks"] == [] and doc["implausible"] == []


def test_the_table_prints_each_regime(coast, capsys):
    log, _ = coast
    capsys.readouterr()
    assert main(["analyze", str(log)]) == 0
    out = capsys.readouterr().out
    assert "  fired: " in out and "  motored: " in out and "misfire in 0" in out
