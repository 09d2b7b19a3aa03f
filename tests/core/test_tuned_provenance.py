"""The discrepancy workflow's tuned numbers carry their provenance and were not tuned on what validates them (issue
26 item 5): core/discrepancy/tuned.json, written by the benches that tune them."""

from __future__ import annotations

import importlib
import math
from datetime import date

import pytest
from frictionwatch.core.discrepancy import features, fit
from frictionwatch.core.discrepancy.tuned import round_up, tuned_constants

from bench import bench_discrepancy, discrepancy_null

TUNED = tuned_constants()


def log_of(text: str) -> tuple[str, float, float, int]:
    """'k9k-4cyl 1800 rpm 0.6 seed 1' -> (engine, rpm, load, seed)."""
    engine, rpm, _, load, _, seed = text.split()
    return engine, float(rpm), float(load), int(seed)


def matrix_logs() -> set[tuple]:
    return {(e, rpm, load, s) for e, spec in bench_discrepancy.ENGINES.items() for rpm, load in spec["points"]
            for s in bench_discrepancy.SEEDS}


@pytest.mark.parametrize("name", sorted(TUNED))
def test_each_number_says_how_it_was_tuned(name):
    t = TUNED[name]
    assert math.isfinite(t.value) and t.figure and t.on
    date.fromisoformat(t.date)
    module = t.tuned_by.split()[2]  # "python -m bench.x --tune --write": the bench that writes it exists
    assert t.tuned_by.startswith("python -m bench.") and "--write" in t.tuned_by
    importlib.import_module(module)
    [log_of(x) for x in t.on]


@pytest.mark.parametrize("name", sorted(TUNED))
def test_no_number_was_tuned_on_a_log_that_validates_it(name):
    tuned_on = {log_of(x) for x in TUNED[name].on}
    validating = matrix_logs() | {tuple(v[:4]) for v in discrepancy_null.VALIDATE + discrepancy_null.FAULTS}
    assert not tuned_on & validating, sorted(tuned_on & validating)


def test_the_code_uses_the_recorded_numbers():
    assert features.NULL_OWN == TUNED["NULL_OWN"].value and features.NULL_FLOOR == TUNED["NULL_FLOOR"].value
    assert features.NULL_BALANCE == TUNED["NULL_BALANCE"].value
    assert features.FLOOR_RMS == (TUNED["FLOOR_RMS_SPEED"].value, TUNED["FLOOR_RMS_BALANCE"].value)
    if "EFFECT_REL_ERROR" in TUNED:
        assert fit.EFFECT_REL_ERROR == TUNED["EFFECT_REL_ERROR"].value


def test_a_floor_is_rounded_up_never_down():
    assert round_up(0.0347) == 0.035 and round_up(0.0107) == 0.011 and round_up(1.2435) == 1.3
    assert round_up(0.012) == 0.012 and round_up(0.0) == 0.0 and round_up(-0.0347) == -0.035
