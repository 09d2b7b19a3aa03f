"""The discrepancy workflow on friction laws (the mismatch effects that change friction's shape, not its size):
named across two operating points, at the balance's share where the speed sizes one short, named where nothing is
beyond the null; not named at one point, where the verdict says why. Split from test_discrepancy_workflow.py (its
helpers as there); simulator logs with the default realistic effects on, one run each."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.core.discrepancy import Options, discover
from frictionwatch.core.model.effects import make_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles

from tests.sim_logs import two_point_steps

pytestmark = pytest.mark.slow  # collected first (tests/conftest.py): long, as test_discrepancy_workflow.py

ENGINE = "k9k-4cyl"
CYCLES = 84
OPTIONS = Options(max_steps=2)


def cycles_of(rpm, load, seed, effects=()):
    spec = load_engine(ENGINE)
    sim = simulate(spec, rpm, load, CYCLES, seed, effects=list(effects))
    return assembled_cycles(spec, sim.info, sim.records)[0]


def _healthy_or_with(engine, rpm, load, seed, n, effects=()):
    spec = load_engine(engine)
    sim = simulate(spec, rpm, load, n, seed, effects=list(effects))
    return EngineModel.from_spec(spec), assembled_cycles(spec, sim.info, sim.records)[0]


def _assert_law_named_by_the_balance_across_points(doc, effect):
    """The law alone named, sized by the torque balance across the points, its fraction within 20 % and 2 sigma of
    the truth (1)."""
    assert doc["outcome"] == "named" and [f["effect"] for f in doc["found"]] == [effect]
    hit = doc["found"][0]
    assert hit["evidence"]["channel"].startswith("torque balance across points (the speed's step read")
    value, sigma = hit["parameters"]["fraction"], hit["sigma"]["fraction"]
    np.testing.assert_allclose(value, 1.0, rtol=0.2)
    assert abs(value - 1.0) <= 2.0 * sigma


def test_a_friction_law_is_named_across_two_operating_points():
    """A log stepping between two speeds and loads (k9k 2800 rpm 0.85 <-> 1700 rpm 0.55, blocks of 20 and 14 cycles,
    seed 7: no matrix log) with speed^2 auxiliaries: at 1700 rpm the law's friction differs from the model's and the
    balance reads it; the law is named, its fraction within 20 % and 2 sigma of the truth (1), and the one-point
    sentence is not said. Measured when written (note 58): named by the balance point by point (core.discrepancy.
    laws), 0.917 +- 0.115, the constant's chi^2 19.1 against 0.1, the workflow's first step having named nothing.
    Since the tooth learner skips the steps' settling cycles (note 60) the speed residual no longer carries the
    pattern they taught it, and the first step names the law itself: 0.916 +- 0.133 by the speed, runner-up the
    bearing law. Since the balance agrees with the speed there (design note 69's kinetic term), the step is sized by
    the balance across the points (across_points.sized_by_balance; the speed's reading said beside it).
    laws.py on made-up points: tests/core/test_discrepancy_parts.py."""
    from frictionwatch.core.discrepancy.words import ONE_POINT

    spec = load_engine(ENGINE)
    steps = two_point_steps(2800.0, 0.85, 1700.0, 0.55, 120, (20, 14))
    sim = simulate(spec, 2800.0, 0.85, 120, 7, effects=[make_effect("auxiliaries_speed_squared", {"fraction": 1.0})],
                   load_steps=steps)
    found = discover(EngineModel.from_spec(spec), assembled_cycles(spec, sim.info, sim.records)[0], OPTIONS)
    doc = found.to_json()
    _assert_law_named_by_the_balance_across_points(doc, "auxiliaries_speed_squared")
    assert not doc["one_operating_point"] and ONE_POINT not in doc["verdict"]


def test_a_friction_law_at_one_operating_point_is_not_named_and_the_verdict_says_why():
    """The same law at one point (2800 rpm 0.85, seed 7, 84 cycles): sized there to the model's mean friction, it
    differs only in shape inside the model's own error; nothing is named and the verdict says that a run across
    speeds and loads would separate the friction laws (words.ONE_POINT; the bench judges a one-point friction-law row
    by it, design note 58)."""
    from frictionwatch.core.discrepancy.words import ONE_POINT

    found = discover(EngineModel.from_spec(load_engine(ENGINE)),
                     cycles_of(2800.0, 0.85, 7, [make_effect("auxiliaries_speed_squared", {"fraction": 1.0})]),
                     OPTIONS)
    assert not found.steps and found.one_operating_point
    assert ONE_POINT in found.verdict()


def test_a_friction_law_named_right_where_nothing_is_beyond_the_null_still_is():
    """maruti 4000 rpm 0.8 seed 2 with a Stribeck ring at fraction 1 (the matrix's row, named right before design
    note 61 with no order nor the balance beyond the null, note 39): the speed gap is ~2.6 of a healthy log's, not
    quiet, so the floored test does not judge it (its floored fall, ~43, would pass anyway); still named, 1.0 +-
    0.42 when written."""
    model, cycles = _healthy_or_with("maruti-3cyl", 4000.0, 0.8, 2, 120,
                                     [make_effect("stribeck_ring", {"fraction": 1.0})])
    doc = discover(model, cycles, OPTIONS).to_json()
    assert [f["effect"] for f in doc["found"]] == ["stribeck_ring"]
    hit = doc["found"][0]
    np.testing.assert_allclose(hit["parameters"]["fraction"], 1.0, rtol=0.2)
    assert abs(hit["parameters"]["fraction"] - 1.0) <= 2.0 * hit["sigma"]["fraction"]
    assert hit["evidence"]["quiet_before"] is False


def test_a_law_the_speed_sizes_short_is_named_at_the_balances_share():
    """maruti 4000 rpm 0.8 <-> 1500 rpm 0.5 (blocks of 24 and 16, 160 cycles, the matrix's two-point log but seed 7:
    no matrix log), a side-thrust skirt at 1. The speed steps size it at 0.683 +- 0.110 (2.9 sigma short: the speed's
    own pull at 1500 rpm, design note 65 (b)); the balance across the points, with the kinetic term no longer off by
    the settling speed (note 69), reads 1.02 +- 0.16. Within 2 sigma of each other: the law is named at the
    balance's share, the speed's reading said beside it. Before note 69: the balance read 1.79 +- 0.19 and the two
    channels disagreed (ambiguous, nothing named); before note 65: named 0.657 +- 0.073 by the speed (4.7 sigma)."""
    spec = load_engine("maruti-3cyl")
    steps = two_point_steps(4000.0, 0.8, 1500.0, 0.5, 160, (24, 16))
    sim = simulate(spec, 4000.0, 0.8, 160, 7, effects=[make_effect("side_thrust_skirt", {"fraction": 1.0})],
                   load_steps=steps)
    doc = discover(EngineModel.from_spec(spec), assembled_cycles(spec, sim.info, sim.records)[0], Options()).to_json()
    _assert_law_named_by_the_balance_across_points(doc, "side_thrust_skirt")
