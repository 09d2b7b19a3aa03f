"""A pressure sensor the monitor flags with a fault no candidate describes (a thermal shock) is one side of an
ambiguity, never the cause of a named effect (design note 161): the fits on its reading are said, not added."""

from __future__ import annotations

import pytest
from frictionwatch.core.discrepancy import discover
from frictionwatch.core.discrepancy.sensor_faults import (
    MIN_CYCLES,
    said_stood_in,
    stood_in_channels,
    undescribed_faults,
)
from frictionwatch.core.model.effects import make_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.discrepancy_report import render
from frictionwatch.service.pipeline import assembled_cycles

pytestmark = pytest.mark.slow  # collected first (tests/conftest.py): a simulated log and a whole workflow

# k9k 1800 rpm 0.6 seed 23, 120 cycles: no matrix seed (bench/discrepancy_cases.py), nothing tuned on it (the rule
# has no tuned number). Without the rule the workflow named "tdc_offset cylinder 1" here (design note 161)
ENGINE, RPM, LOAD, SEED, CYCLES, CYLINDER = "k9k-4cyl", 1800.0, 0.6, 23, 120, 2


def test_only_faults_no_candidate_describes_and_that_stood_count():
    counts = {"sensor_thermal_shock_cyl2": 21, "sensor_thermal_shock_cyl4": MIN_CYCLES - 1,
              "sensor_tdc_offset_cyl3": 40, "sensor_pressure_gain_cyl1": 40, "sensor_pressure_dead_cyl1": 50,
              "sensor_pressure_nonpositive_cyl3": 90, "sensor_pressure_drift_cyl3": MIN_CYCLES,
              "sensor_tdc_offset": 60, "misfire_cyl2": 30}
    got = undescribed_faults(counts, 120)
    assert [(f["cylinder"], f["kind"], f["cycles"], f["of"]) for f in got] == [
        (2, "thermal_shock", 21, 120), (3, "pressure_drift", MIN_CYCLES, 120)]
    stood = stood_in_channels(counts, 120)  # replaced by the siblings' pressure: said, not a rival
    assert [(f["cylinder"], f["kind"]) for f in stood] == [(1, "pressure_dead")]
    assert said_stood_in(stood).startswith("cylinder 1's pressure channel (flagged: no pressure (a dead channel) in 50")
    assert "nothing here judges that cylinder's own combustion" in said_stood_in(stood)


@pytest.fixture(scope="module")
def shocked_log():
    spec = load_engine(ENGINE)
    shock = make_effect("thermal_shock", {"cylinder": CYLINDER, "pa": 5e4})
    sim = simulate(spec, RPM, LOAD, CYCLES, SEED, effects=[shock])
    return EngineModel.from_spec(spec), assembled_cycles(spec, sim.info, sim.records)[0]


def test_a_flagged_thermal_shock_leaves_the_model_as_it_was_and_says_why(shocked_log):
    model, cycles = shocked_log
    found = discover(model, cycles)
    doc = found.to_json()
    assert [(f["cylinder"], f["kind"]) for f in doc["sensor_faults"]] == [(CYLINDER, "thermal_shock")]
    assert doc["found"] == [] and doc["outcome"] == "ambiguous" and doc["stood_in_channels"] == []
    assert found.model.effects == model.effects
    assert doc["ambiguous"]["fits"], "the fits found nothing: this log no longer tests the rule"
    assert f"cylinder {CYLINDER}'s pressure sensor (flagged: a thermal shock" in doc["verdict"]
    assert f"a reference pressure transducer on cylinder {CYLINDER}" in doc["verdict"]
    assert doc["gap_after"] == pytest.approx(doc["gap_before"], rel=1e-12)
    page = render(doc, found)  # the operator's report says the sensor, and the fits as not added
    assert f"the monitor doubts cylinder {CYLINDER}&#x27;s pressure sensor" in page
    assert "but on the reading of the sensor above; nothing was added" in page
