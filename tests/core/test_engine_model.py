"""EngineModel (core/model/engine_model.py): construction, TOML round trip, refused keys, the effects' loss terms
against their numpy references, and simulate() on a model."""

import json

import numpy as np
import pytest
from frictionwatch.core.model.effects import (
    ExtraFriction,
    LoadRipple,
    RingWear,
    auxiliaries_quadratic,
    extra_friction_term,
    parse_effect,
)
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.terms import TermLibrary, cylinder_samples
from frictionwatch.core.plant.simulate import simulate
from numpy.testing import assert_allclose

SPEC = load_engine("k9k-4cyl")


def rich_model() -> EngineModel:
    m = EngineModel.from_spec(SPEC, effects=[RingWear(cylinder=2, sigma={"gain": 0.05}), RingWear(cylinder=4),
                                             ExtraFriction(cylinder=1, amp_frac=0.3, order=1.5, phase_deg=-20.0),
                                             LoadRipple(amplitude_nm=5.0)],
                              without={"sensor_noise"})
    coef = np.array(m.coefficients)
    coef[1, :3] *= 1.37  # a fitted model: per-cylinder coefficients differ
    m = EngineModel(m.spec, m.terms, coef, m.effects)
    return m.augmented().with_term(auxiliaries_quadratic(), np.array([1e-5, 2e-5, 3e-5, 4.5e-6]))


def test_from_spec_defaults():
    m = EngineModel.from_spec(SPEC)
    assert m.terms.names[:6] == ("ring_viscous", "ring_mixed", "skirt_viscous", "valve_train", "auxiliaries",
                                 "loaded_bearings")
    assert_allclose(m.coefficients, np.tile(SPEC.friction.coefficients, (4, 1)))
    assert {e.name for e in m.effects} == {"torsional_flexibility", "variable_inertia", "tooth_spacing_error",
                                           "sensor_noise"}
    with pytest.raises(ValueError, match=r"coefficients must be a \(4, 6\)"):
        EngineModel(SPEC, m.terms, np.ones((4, 5)), ())
    with pytest.raises(ValueError, match="given twice for cylinder 2"):
        m.with_effect(RingWear(cylinder=2)).with_effect(RingWear(cylinder=2, gain=2.0))
    with pytest.raises(ValueError, match="cylinder=7 but the engine has 4"):
        m.with_effect(RingWear(cylinder=7))


def test_with_term_and_augmented():
    m = rich_model()
    assert m.terms.names[6:] == ("extra_friction_c1", "auxiliaries_quadratic")
    assert m.coefficients.shape == (4, 8)
    assert_allclose(m.coefficients[:, 6], 0.0)  # the effect's term enters at its prior
    assert_allclose(m.coefficients[:, 7], [1e-5, 2e-5, 3e-5, 4.5e-6])
    assert m.augmented().terms.names == m.terms.names  # already augmented: nothing added twice
    assert not m.coefficients.flags.writeable


def test_toml_round_trip():
    m = rich_model()
    text = m.to_toml()
    back = EngineModel.from_toml(text)
    assert back == m
    assert_allclose(back.coefficients, m.coefficients, rtol=0)  # repr of a float reads back exactly
    worn = [e for e in back.effects if e.name == "ring_wear"]
    assert [dict(e.sigma) for e in worn] == [{"gain": 0.05}, {}] and back.terms.names == m.terms.names
    assert back.to_toml() == text  # the spec part is kept verbatim, the model part not repeated
    assert back != EngineModel.from_spec(SPEC)


def test_model_file_without_effects_gets_the_defaults():
    text = SPEC.source_text + '\n[model.terms]\nnames = ["ring_viscous", "ring_mixed", "skirt_viscous", ' \
        '"valve_train", "auxiliaries", "loaded_bearings"]\n'
    assert EngineModel.from_toml(text) == EngineModel.from_spec(SPEC)


@pytest.mark.parametrize("tail,words", [
    ("[model.coeficients]\nring_viscous = [1.0, 1.0, 1.0, 1.0]\n",
     "unknown key 'model.coeficients'; nearest known: 'model.coefficients'"),
    ("[model.terms]\nnames = [\"ring_viscous\", \"ring_mixed\", \"skirt_viscous\", \"valve_train\", \"auxiliaries\", "
     "\"loaded_bearings\", \"auxiliaries_quadratik\"]\n",
     "unknown loss term 'auxiliaries_quadratik' in model.terms.names; nearest known: 'auxiliaries_quadratic'"),
    ("[[model.effects]]\nname = \"ring_wear\"\ngian = 1.2\n",
     "unknown key 'model.effects\\[0\\].gian'; nearest known: 'model.effects\\[0\\].gain'"),
    ("[[model.effects]]\nname = \"ring_waer\"\n", "unknown effect 'ring_waer'; nearest known: 'ring_wear'"),
    ("[[model.effects]]\nname = \"ring_wear\"\ngain = \"1.4\"\n", "gain='1.4': expected a number"),
    ("[model.coefficients]\nring_viscous = [1.0, \"x\", 1.0, 1.0]\n", "ring_viscous = 'x': expected a number"),
    ("[[model.effects]]\nname = \"load_ripple\"\n[[model.effects]]\nname = \"load_ripple\"\n",
     "effect 'load_ripple' is given twice"),
    ("[modle]\n", "unknown key 'modle'; nearest known: 'model'"),
])
def test_bad_model_files_are_refused_in_one_line(tail, words):
    with pytest.raises(ValueError, match=words) as exc:
        EngineModel.from_toml(SPEC.source_text + "\n" + tail)
    assert "\n" not in str(exc.value)


def test_effect_terms_match_their_references():
    consts = SPEC.friction_params()
    rng = np.random.default_rng(3)
    angle = np.linspace(-np.pi, 3 * np.pi, 721)[:-1]
    one = cylinder_samples(angle, 180.0 + 10 * rng.normal(size=720), 5e6 * np.exp(-angle**2), consts)
    samples = np.ascontiguousarray(np.stack([one] * SPEC.n_cyl, axis=1))  # (N_FIELDS, z, n): every cylinder alike
    lib = TermLibrary((auxiliaries_quadratic(), extra_friction_term(2, 0.2, 0.5, 1.5, 0.3)))
    basis = lib.evaluate(samples, consts)  # (z, 2, n)
    # same formula and operations: a few ulps
    assert_allclose(basis, lib.evaluate_reference(samples, consts), rtol=1e-12, atol=1e-15)
    assert_allclose(basis[:, 0], np.broadcast_to(one[5] ** 2, (SPEC.n_cyl, 720)), rtol=1e-15)
    assert_allclose([basis[1, 1].min(), basis[1, 1].max()], [0.2 - 0.5, 0.2 + 0.5], atol=1e-3)
    assert not np.any(basis[[0, 2, 3], 1])  # the extra friction of cylinder 2 is nobody else's


def test_an_extra_friction_shape_is_compiled_once_per_set_of_numbers():
    """The same shape asked for twice (the workflow's sizing asks twice; its unit directions recur in every fit) is
    the one compiled kernel; other numbers, another kernel, each its own shape (loss_terms._shape_kernel)."""
    a, b = extra_friction_term(2, 0.2, 0.5, 1.5, 0.3), extra_friction_term(2, 0.2, 0.5, 1.5, 0.3)
    c = extra_friction_term(2, 0.2, 0.5, 1.5, 0.4)
    assert a.kernel is b.kernel and c.kernel is not a.kernel
    consts = SPEC.friction_params()
    angle = np.linspace(-np.pi, 3 * np.pi, 64)
    one = cylinder_samples(angle, np.full(64, 180.0), np.zeros(64), consts)
    samples = np.ascontiguousarray(np.stack([one] * SPEC.n_cyl, axis=1))
    for term, phase in ((a, 0.3), (c, 0.4)):
        got = TermLibrary((term,)).evaluate(samples, consts)[1, 0]
        assert_allclose(got, 0.2 + 0.5 * np.cos(1.5 * one[0] + phase), rtol=1e-12)


def test_simulate_takes_a_model_and_applies_its_effects():
    effects = [parse_effect("ring_wear:cylinder=3"), parse_effect("misfire:cylinder=2")]
    model = EngineModel.from_spec(SPEC, effects=effects)
    a = simulate(model, 1700, 1.0, 2, 7, cov_imep=0.0)
    b = simulate(SPEC, 1700, 1.0, 2, 7, effects=effects, cov_imep=0.0)
    assert json.dumps(a.truth) == json.dumps(b.truth)  # the spec route wraps the same model
    assert_allclose(a.truth["cylinders"][2]["coefficients"][:3], 1.4 * SPEC.friction.coefficients[:3])
    with pytest.raises(ValueError, match="carries its own effects"):
        simulate(model, 1700, 1.0, 2, 7, effects=effects)


def test_simulate_runs_a_model_with_an_added_term():
    """The plant evaluates the model's whole term library: an added omega^2 term shows in the truth as its own
    friction share, about a omega^2 per cylinder, and adds that much to each cylinder's friction."""
    a = 2.0 / (1700 * np.pi / 30) ** 2  # ~2 N m per cylinder at 1700 rpm
    base = simulate(EngineModel.from_spec(SPEC), 1700, 1.0, 2, 7, cov_imep=0.0)
    more = simulate(EngineModel.from_spec(SPEC).with_term(auxiliaries_quadratic(), a), 1700, 1.0, 2, 7, cov_imep=0.0)
    omega = more.truth["rpm_mean"] * np.pi / 30
    for cb, cm in zip(base.truth["cylinders"], more.truth["cylinders"]):
        # the throw's speed ripple makes <omega^2> a little larger than omega_mean^2 (< 0.5 % here)
        assert_allclose(cm["friction_terms_nm"]["auxiliaries_quadratic"], a * omega**2, rtol=5e-3)
        assert "auxiliaries_quadratic" not in cb["friction_terms_nm"]
        assert_allclose(cm["friction_torque_mean_nm"] - cb["friction_torque_mean_nm"], 2.0, rtol=0.05)
