"""The discrepancy workflow on what the matrix's tuning never saw (issue 27, design note 101): a fit whose size its
own sigma cannot tell from none is not named, whatever the held-out chi^2 gains; an effect outside the library is
said as a discrepancy, not named as another; a flywheel heavier than its record, outside the library until design
note 109, is named as itself."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from frictionwatch.core.discrepancy import discover
from frictionwatch.core.discrepancy.candidates import candidate_library
from frictionwatch.core.discrepancy.choice import unresolved
from frictionwatch.core.discrepancy.fit import Trial
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles


def test_a_fit_not_resolved_from_none_is_refused_on_a_loud_residual_too():
    """choice.unresolved without ``quiet``: a friction law at its share's bound 1 +- 1 (maruti 4000/0.8 seed 1, the
    flywheel 5 % heavier than its record: side_thrust_skirt named before design note 101) is within 2 sigma of none:
    refused, said why; 1 +- 0.4 (2.5 sigma) is resolved and left to the held-out test; a load ripple with both parts
    within 2 sigma of none is refused, one part beyond it is not."""
    lib = {c.label: c for c in candidate_library(EngineModel.from_spec(load_engine("maruti-3cyl")))}

    def trial(label, x, s):
        return Trial(lib[label], np.atleast_1d(np.asarray(x, float)), np.atleast_1d(np.asarray(s, float)), 0.0, 1.0, 0)

    why = unresolved(trial("side_thrust_skirt", 1.0, 1.0))
    assert why.startswith("fraction 1 +- 1: its size is not resolved from none")
    assert "not named" in why
    assert unresolved(trial("side_thrust_skirt", 1.0, 0.4)) == ""
    assert unresolved(trial("side_thrust_skirt", 1.0, 0.499)) == ""  # 2.004 sigma: resolved
    ripple = next(label for label in lib if label.startswith("load_ripple"))
    assert unresolved(trial(ripple, [0.5, -0.4], [0.3, 0.3])) != ""
    assert unresolved(trial(ripple, [0.7, -0.1], [0.3, 0.3])) == ""


@pytest.fixture(scope="module")
def heavier_flywheel():
    """maruti-3cyl 4000 rpm 0.8, seed 1, 120 cycles (a matrix point, a tuning seed of design note 109): the plant's
    flywheel 5 % heavier than the engine record the monitor's model keeps (the record edited, as note 101 made it)."""
    spec = load_engine("maruti-3cyl")
    inertia = spec.node_inertia.astype(float).copy()
    inertia[spec.flywheel_node] *= 1.05
    sim = simulate(dataclasses.replace(spec, node_inertia=inertia), 4000.0, 0.8, 120, 1)
    return EngineModel.from_spec(spec), assembled_cycles(spec, sim.info, sim.records)[0]


def test_a_heavier_flywheel_is_named_as_the_inertia_not_a_friction_law(heavier_flywheel):
    """Before design note 101: "Found side_thrust_skirt (fraction=1 +- 1)" with a gap of 5.4 left, 6.8x a healthy
    log's; note 101 refused it ("unexplained"). With the inertia a candidate (design note 109) it is named: 1.048 +-
    0.0022 (the truth 0.8 sigma off), the held-out gap 9.0 -> 1.7, nothing else named."""
    model, cycles = heavier_flywheel
    doc = discover(model, cycles).to_json()
    assert [f["effect"] for f in doc["found"]] == ["flywheel_inertia"]
    (hit,) = doc["found"]
    x, sigma = hit["parameters"]["inertia_scale"], hit["sigma"]["inertia_scale"]
    assert abs(x - 1.05) <= 2.0 * sigma
    np.testing.assert_allclose(x, 1.05, atol=0.01)  # the matrix's rule: 20 % of the excess
    assert doc["gap_before"] > 3.0 and doc["gap_after"] < 0.3 * doc["gap_before"]
