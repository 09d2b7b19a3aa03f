"""The monitor's view of a model's effects and the discrepancy workflow's candidate library, on made-up inputs (no
monitor run): sensor corrections undone, a TDC offset as a kinematic phase, a reduced model's view, the friction laws
kept at their reference point, what the library offers and leaves out."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.core.discrepancy.candidates import candidate_library
from frictionwatch.core.model.effects import make_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.view import Reference, corrected_pressure, monitor_view, rigid_spec


def reference(spec, n=720):
    grid = np.linspace(0, 4 * np.pi, n, endpoint=False)
    p = np.array([1e5 + 40e5 * np.exp(-0.5 * ((np.mod(grid - a + np.pi, 4 * np.pi) - np.pi) / 0.3) ** 2)
                  for a in spec.firing_angles])
    return Reference(200.0, grid, p)


def test_sensor_errors_are_undone_and_a_tdc_offset_moves_the_kinematic_phase():
    spec = load_engine("k9k-4cyl")
    ref = reference(spec)
    model = EngineModel.from_spec(spec, effects=[make_effect("tdc_offset", {"cylinder": 2, "deg": 3.0}),
                                                 make_effect("tdc_offset", {"cylinder": 0, "deg": -1.0}),
                                                 make_effect("pressure_gain", {"cylinder": 3, "gain": 1.1}),
                                                 make_effect("pressure_offset", {"cylinder": 4, "pa": 2e4})])
    view = monitor_view(model, ref)
    read = ref.pressure.copy()
    read[2] = 1.1 * ref.pressure[2]
    read[3] = ref.pressure[3] + 2e4
    np.testing.assert_allclose(corrected_pressure(view, read), ref.pressure, rtol=1e-12, atol=1e-6)
    # the plant's throw of cylinder 2 is 3 deg later than stated, the whole wheel 1 deg earlier
    np.testing.assert_allclose(np.degrees(view.spec.firing_angles - spec.firing_angles), [-1.0, 2.0, -1.0, -1.0],
                               atol=1e-12)


def test_view_of_default_and_reduced_models():
    spec = load_engine("k9k-4cyl")
    ref = reference(spec)
    full = monitor_view(EngineModel.from_spec(spec), ref)
    assert full.variable_inertia and full.spec.stiffness.size == spec.stiffness.size
    assert not full.corrects_pressure
    bare = monitor_view(EngineModel.from_spec(spec, without={"torsional_flexibility", "variable_inertia"}), ref)
    assert not bare.variable_inertia and bare.spec.node_inertia.shape == (1,)
    np.testing.assert_allclose(rigid_spec(spec).node_inertia.sum(), spec.node_inertia.sum(), rtol=1e-12)
    worn = monitor_view(EngineModel.from_spec(spec, effects=[make_effect("ring_wear", {"cylinder": 2, "gain": 2.0})]),
                        ref)
    ratio = worn.coefficients / full.coefficients
    np.testing.assert_allclose(ratio[1, :3], 2.0)
    np.testing.assert_allclose(np.delete(ratio, 1, axis=0), 1.0)


def test_friction_law_keeps_the_mean_at_the_reference_point():
    spec = load_engine("k9k-4cyl")
    ref = reference(spec)
    from frictionwatch.core.model.view import basis_means

    base = monitor_view(EngineModel.from_spec(spec), ref)
    law = monitor_view(EngineModel.from_spec(spec, effects=[make_effect("bearings_load", {"fraction": 0.5})]), ref)
    mean_base = np.sum(base.coefficients * basis_means(base.spec, base.terms, ref), axis=1)
    mean_law = np.sum(law.coefficients * basis_means(law.spec, law.terms, ref), axis=1)
    np.testing.assert_allclose(mean_law, mean_base, rtol=1e-9)
    assert law.terms.names[-1] == "plant_bearings_load"


def test_library_leaves_out_what_the_model_holds():
    spec = load_engine("k9k-4cyl")
    model = EngineModel.from_spec(spec, effects=[make_effect("pressure_gain", {"cylinder": 3, "gain": 1.05})])
    labels = {c.label for c in candidate_library(model)}
    assert "pressure_gain[cyl 3]" not in labels and "pressure_gain[cyl 2]" in labels
    assert "torsional_flexibility" not in labels and "chain_mismatch" in labels
    rigid = EngineModel.from_spec(spec, without={"torsional_flexibility"})
    labels = {c.label for c in candidate_library(rigid)}
    assert "torsional_flexibility" in labels and "chain_mismatch" not in labels
    assert "torsional_flexibility+variable_inertia" not in labels  # one default effect left out: no combination
    bare = EngineModel.from_spec(spec, without={"torsional_flexibility", "variable_inertia"})
    both = next(c for c in candidate_library(bare) if c.label == "torsional_flexibility+variable_inertia")
    assert both.toggle and [e.name for e in both.model_at(bare, None).effects[-2:]] == list(both.names)
    cand = next(c for c in candidate_library(model) if c.label == "tdc_offset[cyl 0]")
    assert cand.model_at(model, np.array([0.0])) is model
    e = cand.effect_at(np.array([25.0]))  # clipped to the effect's range
    assert e["deg"] == pytest.approx(10.0) and e["cylinder"] == 0


def test_the_library_offers_load_ripples_at_half_orders_and_a_cam_order_friction_in_a_stand_in_cylinder():
    spec = load_engine("k9k-4cyl")
    lib = {c.label: c for c in candidate_library(EngineModel.from_spec(spec))}
    for order in (0.5, 1.5):
        ripple = lib[f"load_ripple[order {order:g}]"]
        assert ripple.params == ("in_phase_nm", "quadrature_nm") and ripple.cylinder is None
        assert ripple.effect_at(np.array([3.0, 4.0])).ripple() == pytest.approx((5.0, 0.0, order, np.arctan2(4, 3)))
        cam = lib[f"extra_friction[order {order:g}]"]
        assert not cam.places_cylinder and cam.cylinder is None and cam.fixed["cylinder"] == 1
        assert cam.effect_at(np.array([0.2, 0.0, 0.5])).shape() == pytest.approx((0.2, 0.5, order, np.pi / 2))
    assert "load_ripple[order 1]" not in lib  # an integer order is the tooth learner's
    # a constant extra friction is a stand-in too: no harmonic, the same from every cylinder (design note 39)
    const = lib["extra_friction"]
    assert not const.places_cylinder and const.cylinder is None and const.fixed["cylinder"] == 1
    assert const.params == ("mean_frac",) and const.effect_at(np.array([0.6])).shape() == pytest.approx((0.6, 0, 2, 0))
    assert not any(label.startswith("extra_friction[cyl") for label in lib)
    # the stand-in's cylinder already holds an extra friction: neither shape is offered (it could not be added)
    held = EngineModel.from_spec(spec, effects=[make_effect("extra_friction", {"cylinder": 1, "mean_frac": 0.1})])
    labels = {c.label for c in candidate_library(held)}
    assert not any(label.startswith("extra_friction") for label in labels) and "load_ripple[order 0.5]" in labels


def test_a_friction_swing_larger_than_the_friction_it_rides_on_is_not_friction():
    ef = make_effect("extra_friction", {"cylinder": 2, "mean_frac": 0.0, "cos_frac": 1.6, "sin_frac": 1.2})
    nan = float("nan")
    assert "would drive the engine" in ef.unphysical({}, nan)  # a swing of 2.0 on a friction of 1.0
    assert "would drive" in ef.unphysical({"cos_frac": 0.4, "sin_frac": 0.4}, nan)  # 1.0 over: 2.5 sigma (0.4)
    assert ef.unphysical({"cos_frac": 0.6, "sin_frac": 0.6}, nan) == ""  # 1.0 over: within 2 sigma (0.6)
    assert make_effect("extra_friction", {"cylinder": 2, "mean_frac": 1.2, "cos_frac": 1.6,
                                          "sin_frac": 1.2}).unphysical({}, nan) == ""
    # a load ripple beyond its load's mean torque; an unmeasured load bounds nothing
    ripple = make_effect("load_ripple", {"order": 1.5, "in_phase_nm": -60.8, "quadrature_nm": 40.4})
    assert "the load would drive the engine" in ripple.unphysical({"in_phase_nm": 0.8, "quadrature_nm": 0.8}, 40.0)
    assert ripple.unphysical({}, 80.0) == "" and ripple.unphysical({}, nan) == ""
    with pytest.raises(ValueError, match="not both"):
        make_effect("extra_friction", {"cylinder": 2, "amp_frac": 0.3, "cos_frac": 0.1})


def test_view_runs_with_the_callers_config():
    """The workflow pins the friction (pinned_config), analyze and serve do not: the pipeline takes either as given
    and adds what the view decides (the model's calibration, constant inertia without variable_inertia)."""
    from frictionwatch.core.discrepancy.residuals import PINNED_SIGMA, pinned_config
    from frictionwatch.core.monitor.pipeline import monitor_config
    from frictionwatch.core.monitor.state import MonitorConfig

    spec = load_engine("k9k-4cyl")
    ref = reference(spec)
    free = monitor_view(EngineModel.from_spec(spec), ref)
    assert monitor_config(free, None) == MonitorConfig()
    assert free.spec is spec and not free.corrects_pressure
    pinned = monitor_config(free, pinned_config())
    assert pinned.parameter_sigma == PINNED_SIGMA and pinned.warmup_cycles == 2 and pinned.variable_inertia
    bare = monitor_view(EngineModel.from_spec(spec, without={"variable_inertia"}), ref)
    assert not monitor_config(bare, pinned_config()).variable_inertia
    law = EngineModel.from_spec(spec, effects=[make_effect("bearings_load", {"fraction": 0.5})])
    with pytest.raises(ValueError, match="Reference"):
        monitor_view(law, None)
    assert monitor_view(EngineModel.from_spec(spec), None).spec is spec  # nothing to size: no reference needed


def test_an_effect_brings_its_own_monitor_view():
    """A new effect is one class: its ``apply_view`` and ``size_view`` reach the monitor's model without a line in
    core.model.view (a made-up sensor effect and a made-up friction shape sized at the reference point)."""
    from dataclasses import replace

    from frictionwatch.core.model.effects.base import Effect, Param, cylinder_param
    from frictionwatch.core.model.view import basis_means

    class DoubleReading(Effect):
        name = "double_reading"
        parameters = {"cylinder": cylinder_param()}

        def apply_view(self, setup):
            k = self.values["cylinder"] - 1
            gain = setup.gain.copy()
            gain[k] *= 2.0
            return replace(setup, gain=gain)

    class MoreOfTheFirstTerm(Effect):
        name = "more_of_the_first_term"
        parameters = {"frac": Param(0.5, "-", 0.0, 1.0)}
        sized_at_reference = True

        def size_view(self, setup, means):
            m = means(setup.spec, setup.terms)  # (z, L) at the reference point
            coef = setup.coefficients.copy()
            coef[:, 0] *= 1.0 + self.values["frac"]
            assert m.shape == coef.shape
            return replace(setup, coefficients=coef)

    spec = load_engine("k9k-4cyl")
    ref = reference(spec)
    base = EngineModel.from_spec(spec)
    model = EngineModel(spec, base.terms, base.coefficients, base.effects + (DoubleReading(cylinder=3),
                                                                             MoreOfTheFirstTerm(frac=0.25)))
    with pytest.raises(ValueError, match="Reference"):
        monitor_view(model, None)
    view = monitor_view(model, ref)
    np.testing.assert_allclose(view.gain, [1.0, 1.0, 2.0, 1.0], rtol=0)
    np.testing.assert_allclose(view.coefficients[:, 0], 1.25 * base.coefficients[:, 0], rtol=1e-12)
    np.testing.assert_allclose(view.coefficients[:, 1:], base.coefficients[:, 1:], rtol=1e-12)
    assert basis_means(view.spec, view.terms, ref).shape == view.coefficients.shape
