"""A run asked for more cycles than a coast-down leaves before the engine stops ends with a one-line ValueError (the
CLI's exit 2), not a plant integrating a standstill for ever (core.plant.sim_run.STOPPED_RAD_S; design note 166:
``simulate k9k-4cyl --cycles 60 --effect coast_down:time_s=1.2`` had run > 300 s without an end)."""

from __future__ import annotations

import pytest
from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import simulate


def test_a_coast_down_past_standstill_is_refused_in_one_line():
    spec = load_engine("deutz-1cyl")
    with pytest.raises(ValueError, match=r"^the engine stopped \(below 30 rpm\) .* ask fewer cycles, or a later "):
        simulate(spec, 1500.0, 0.5, 400, 3, effects=[parse_effect("coast_down:time_s=0.1")])
