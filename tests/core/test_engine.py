"""EngineSpec presets load, derived values match engines.md, and bad files name the bad field."""

import math
import re

import numpy as np
import pytest
from frictionwatch.core.model.engine import SpecError, available_presets, load_engine, spec_from_toml_text
from numpy.testing import assert_allclose


def test_presets_and_displacements():
    assert {"deutz-1cyl", "maruti-3cyl", "k9k-4cyl", "genset-v20"} <= set(available_presets())
    # engines.md §1 (CHK): displacement 1.461 / 0.796 / 0.567 / 124.75 L
    for name, litres in [("k9k-4cyl", 1.461), ("maruti-3cyl", 0.796), ("deutz-1cyl", 0.567), ("genset-v20", 124.75)]:
        assert_allclose(load_engine(name).displacement * 1e3, litres, rtol=2e-3)


def test_genset_firing_is_even_36_degrees_and_two_cylinders_per_throw():
    spec = load_engine("genset-v20")
    angles = np.sort(np.degrees(spec.firing_angles))
    assert_allclose(np.diff(angles), 36.0)
    assert np.all(np.bincount(spec.cylinder_node)[2:12] == 2)


def test_mep_torque_round_trip():
    spec = load_engine("genset-v20")
    # engines.md §4: FMEP 1.8 bar <-> T_fM 1.79 kN m
    assert_allclose(spec.mep_to_torque(1.8e5), 1787, rtol=2e-3)
    assert math.isclose(spec.torque_to_mep(spec.mep_to_torque(3.3e5)), 3.3e5)


def _k9k_text():
    return load_engine("k9k-4cyl").source_text


@pytest.mark.parametrize(
    "old,new,message",
    [
        ("bore_m = 0.076", "bore_m = -0.076", "geometry.bore_m = -0.076 is out of range; expected 0.01..1 m"),
        ("bore_m = 0.076", "", "missing field geometry.bore_m [m]"),
        ("count = 4", "count = 5", "cylinders.firing_angles_deg has 4 values; expected 5"),
        ('load_node = "dyno"', 'load_node = "brake"', "shaft.flywheel_node/load_node must name a node"),
        ("compression_rings = 2", "compression_rings = 2.5", "friction.compression_rings = 2.5; expected an integer"),
        ("[load]", "[loads]", "unknown key 'loads'; nearest known: 'load'"),  # a misspelt table is named
        ("[load]", "[brake]", "missing table [load]"),
        ('kind = "speed_power"', 'kind = "magic"', "load.kind = 'magic'; expected one of speed_power, grid"),
    ],
)
def test_bad_fields_are_named(old, new, message):
    text = _k9k_text().replace(old, new, 1)
    with pytest.raises(SpecError, match=message.replace("[", r"\[").replace("]", r"\]").replace(".", r"\.")):
        spec_from_toml_text(text, origin="bad.toml")


def test_unknown_preset_lists_the_known_ones():
    with pytest.raises(SpecError, match="presets: .*k9k-4cyl"):
        load_engine("v99-unicorn")


def test_not_toml():
    with pytest.raises(SpecError, match="not valid TOML"):
        spec_from_toml_text("name = ", origin="x.toml")


@pytest.mark.parametrize(
    "old,new,message",
    [  # design note 142: a firing order that is not one angle per cylinder would place a pressure trace wrongly
        ("[0.0, 540.0, 180.0, 360.0]", "[0.0, 0.0, 180.0, 360.0]",
         "cylinders.firing_angles_deg[1] = 0 is cylinder 1's angle too"),
        ("[0.0, 540.0, 180.0, 360.0]", "[0.0, 540.0, 180.0, 720.0]",
         "cylinders.firing_angles_deg[3] = 720 is cylinder 1's angle too"),
        ("[0.0, 540.0, 180.0, 360.0]", "[90.0, 630.0, 270.0, 450.0]",
         "cylinders.firing_angles_deg[0] = 90; cylinder 1 fires at 0 deg"),
        ('"throw3", "throw4", "flywheel"', '"throw3", "throw3", "flywheel"', "shaft.nodes names 'throw3' twice"),
    ],
)
def test_a_firing_order_or_shaft_that_is_not_one_of_each_is_named(old, new, message):
    text = _k9k_text()
    assert old in text
    with pytest.raises(SpecError, match=re.escape(f"bad.toml: {message}")):
        spec_from_toml_text(text.replace(old, new, 1), origin="bad.toml")


def test_the_genset_firing_order_with_a_small_rounding_still_loads():
    text = load_engine("genset-v20").source_text.replace("36.0,", "36.0000001,", 1)
    assert_allclose(np.degrees(spec_from_toml_text(text).firing_angles[1]), 36.0000001, rtol=1e-12)
