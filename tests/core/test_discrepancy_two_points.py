"""The discrepancy workflow on logs that step between two operating points, beyond the friction laws
(test_discrepancy_workflow_laws.py): a healthy two-point log names nothing where a fit of the model's own error
passes the plain held-out test (design note 155). Simulator logs as the matrix makes them (bench.discrepancy_cases),
the default realistic effects on, one run each."""

from __future__ import annotations

import dataclasses

import pytest
from frictionwatch.core.discrepancy import Options, discover
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles

from tests.sim_logs import two_point_steps

pytestmark = pytest.mark.slow  # collected first (tests/conftest.py): long, as test_discrepancy_workflow.py


def _two_point_log(engine: str, point: tuple, second: tuple, seed: int, cycles: int = 160,
                   blocks: tuple = (24, 16), effects=()):
    """The matrix's two-point log (bench.discrepancy_cases.two_point_steps): blocks of ``point`` and ``second`` in
    turn, the first point's first, a speed and a load step each."""
    (rpm, load), (rpm2, load2) = point, second
    steps = two_point_steps(rpm, load, rpm2, load2, cycles, blocks)
    spec = load_engine(engine)
    sim = simulate(spec, rpm, load, cycles, seed, effects=list(effects), load_steps=steps)
    return EngineModel.from_spec(spec), assembled_cycles(spec, sim.info, sim.records)[0]


def test_a_healthy_two_point_log_names_no_fit_of_the_models_own_error_inside_the_null():
    """maruti 1500 rpm 0.5 <-> 4000 rpm 0.8, seed 17, nothing hidden (the matrix's "two points: none" row that named
    a 0.40 N m load ripple at order 0.5, design notes 149 and 155). Nothing is beyond the null and the speed gap is
    1.9x a healthy log's (inside GAP_NULL, not quiet): the ripple passes the plain held-out test (delta chi^2 ~575,
    of it ~7 at order 0.5, the rest at orders 3.5-7 of the 1500 rpm point, inside their model-error floor) but with
    the floor allowed for its chi^2 falls by ~20 < min_delta_chi2: refused, said, nothing named. With note 61's gate
    (``floored_within_null=False``: the floored test only where the gap is within the *typical* healthy one) the
    same log names the ripple: the test can fail. No number here is tuned (min_delta_chi2 and GAP_NULL are the
    workflow's)."""
    model, cycles = _two_point_log("maruti-3cyl", (1500.0, 0.5), (4000.0, 0.8), 17)
    doc = discover(model, cycles, Options()).to_json()
    assert doc["found"] == [] and doc["outcome"] == "nothing"
    assert [r["candidate"] for r in doc["refused"]] == ["load_ripple[order 0.5]"]
    refused = doc["refused"][0]
    assert "inside the null" in refused["reason"] and refused["within_null_before"] and not refused["quiet_before"]
    assert refused["delta_chi2_heldout"] >= Options().min_delta_chi2 > refused["delta_chi2_heldout_floored"]
    old = discover(model, cycles, dataclasses.replace(Options(), floored_within_null=False)).to_json()
    assert [f["effect"] for f in old["found"]] == ["load_ripple"]


def test_a_cam_order_friction_at_two_points_is_not_named_a_worn_ring_by_a_fit_on_the_first_steps_cycles():
    """k9k 3000 rpm 0.9 <-> 1800 rpm 0.6, seed 17, an order-0.5 friction in cylinder 3 (the matrix's "two points:
    extra_friction cam 0.5" row, design note 155). Fitted on the first 24 cycles after the warm-up -- 11 at 3000 rpm
    and the first 6 at 1800, the speed still drifting after its step -- the cam-order stand-in read amplitude 1.48
    (truth 0.8) and lost the held-out test to a worn ring in cylinder 3, which was named (a wrong name; floored
    held-out chi^2 546 against the ring's 493). Fitted on the whole training half (Options.fit_all_points), which
    holds each point as the held-out half does, it reads ~0.95, explains the held-out cycles best (floored ~246
    against ~485) and, the speed not placing a cam-order friction in a cylinder, is said, not named: ambiguous,
    nothing added. With the first cycles alone (``fit_all_points=False``) the ring is named: the test can fail."""
    from frictionwatch.core.model.effects import make_effect

    cam = make_effect("extra_friction", {"cylinder": 3, "mean_frac": 0.5, "amp_frac": 0.8, "order": 0.5})
    model, cycles = _two_point_log("k9k-4cyl", (3000.0, 0.9), (1800.0, 0.6), 17, effects=[cam])
    doc = discover(model, cycles, Options()).to_json()
    assert doc["found"] == [] and doc["outcome"] == "ambiguous"
    assert doc["ambiguous"]["candidates"][0].startswith("extra_friction[order 0.5] in any one of the 4 cylinders")
    old = discover(model, cycles, dataclasses.replace(Options(), fit_all_points=False)).to_json()
    assert [(f["effect"], f["cylinder"]) for f in old["found"]] == [("ring_wear", 3)]
