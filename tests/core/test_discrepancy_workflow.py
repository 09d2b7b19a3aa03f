"""The discrepancy workflow on simulator logs with a hidden effect (the workflow is never told which), the default
realistic effects on: the right effect named (and cylinder), its parameter within 20 %, the gap down >= 80 %; nothing
hidden: nothing found; a baseline without a default effect: that effect found. Small logs, one run each (module
fixtures); the full matrix of effects, operating points and seeds is bench/bench_discrepancy.py --matrix."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.core.discrepancy import Options, discover
from frictionwatch.core.model.effects import make_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles

ENGINE = "k9k-4cyl"
CYCLES = 84
OPTIONS = Options(max_steps=2)


def cycles_of(rpm, load, seed, effects=()):
    spec = load_engine(ENGINE)
    sim = simulate(spec, rpm, load, CYCLES, seed, effects=list(effects))
    return assembled_cycles(spec, sim.info, sim.records)[0]


@pytest.fixture(scope="module")
def healthy():
    return cycles_of(2500.0, 0.8, 5)


@pytest.fixture(scope="module")
def gain_fault():
    return cycles_of(2500.0, 0.8, 6, [make_effect("pressure_gain", {"cylinder": 3, "gain": 1.06})])


def test_nothing_hidden_nothing_found(healthy):
    model = EngineModel.from_spec(load_engine(ENGINE))
    found = discover(model, healthy, OPTIONS)
    doc = found.to_json()
    assert doc["found"] == [] and doc["verdict"] == "no significant missing effect"
    assert found.model == model
    assert doc["gap_after"] == doc["gap_before"]


def test_hidden_pressure_gain_is_named_and_fitted(gain_fault):
    found = discover(EngineModel.from_spec(load_engine(ENGINE)), gain_fault, OPTIONS)
    doc = found.to_json()
    first = doc["found"][0]
    assert (first["effect"], first["cylinder"]) == ("pressure_gain", 3), doc["found"]
    np.testing.assert_allclose(first["parameters"]["gain"] - 1.0, 0.06, rtol=0.2)
    assert 0.0 < first["sigma"]["gain"] < 0.02
    assert doc["gap_after"] <= 0.2 * doc["gap_before"]
    added = found.model.effects[-len(doc["found"]):]
    assert added[0].name == "pressure_gain" and added[0].sigma["gain"] == pytest.approx(first["sigma"]["gain"])


def test_rigid_baseline_finds_the_flexible_shaft_line(healthy):
    model = EngineModel.from_spec(load_engine(ENGINE), without={"torsional_flexibility"})
    doc = discover(model, healthy, OPTIONS).to_json()
    assert doc["found"] and doc["found"][0]["effect"] == "torsional_flexibility", doc["found"]
    assert doc["gap_after"] <= 0.2 * doc["gap_before"]


def test_too_few_cycles_is_refused(healthy):
    with pytest.raises(ValueError, match="at least"):
        discover(EngineModel.from_spec(load_engine(ENGINE)), healthy[:20])
