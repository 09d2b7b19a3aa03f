"""Effects as objects (core/model/effects/) and what each one does to a simulated engine (core/plant/simulate.py)."""

import dataclasses

import numpy as np
import pytest
from frictionwatch.core.model.effects import (
    EFFECTS,
    CylinderSetup,
    LoadRipple,
    RingWear,
    SensorSetup,
    check_instances,
    parse_effect,
    resolve_effects,
)
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.terms import rezeka_henein
from frictionwatch.core.model.thermo import cycle_params, cylinder_model, cylinder_pressure, imep
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.core.types import PressureFrame
from numpy.testing import assert_allclose

# ---- registry, parsing, instances ----------------------------------------------------------------------------------


def test_parse_effect_fills_defaults_and_types():
    e = parse_effect("ring_wear:cylinder=3,gain=1.4")
    assert e == RingWear(cylinder=3, gain=1.4) and e.name == "ring_wear"
    assert dict(e.values) == {"cylinder": 3, "gain": 1.4,
                              "mass_loss": EFFECTS["ring_wear"].parameters["mass_loss"].default, "from_cycle": 0,
                              "ramp_cycles": 0}
    assert isinstance(e["cylinder"], int)
    assert dict(parse_effect("variable_inertia").values) == {}
    assert parse_effect(" misfire : cylinder = 2 ")["cylinder"] == 2


@pytest.mark.parametrize("text,words", [
    ("ring_waer:cylinder=3", "unknown effect 'ring_waer'"),
    ("ring_wear:cyl=3", "no parameter 'cyl'"),
    ("ring_wear:cylinder=0", "out of range 1..24"),
    ("ring_wear:cylinder=2.5", "integer"),
    ("ring_wear:gain=abc", "gain='abc': expected a number"),
    ("misfire:probability=1.5", "probability=1.5 is out of range 0..1"),
    ("misfire:cylinder", "not key=value"),
    ("tdc_offset:deg=nan", "out of range"),
])
def test_parse_effect_errors_are_one_line(text, words):
    with pytest.raises(ValueError, match=words) as exc:
        parse_effect(text)
    assert "\n" not in str(exc.value)


def test_constructor_validates_and_instances_are_immutable():
    with pytest.raises(ValueError, match="ring_wear.: gain='1.4': expected a number"):
        RingWear(gain="1.4")
    with pytest.raises(ValueError, match="gain=9 is out of range 1..5"):
        RingWear(gain=9)
    with pytest.raises(ValueError, match="sigma given for unknown parameter 'gian'"):
        RingWear(sigma={"gian": 0.1})
    e = RingWear(cylinder=2, sigma={"gain": 0.05})
    assert e.sigma["gain"] == 0.05 and e.to_dict()["sigma"] == {"gain": 0.05}
    with pytest.raises(AttributeError):
        e.values = {}
    with pytest.raises(TypeError):
        e.values["gain"] = 2.0  # a read-only mapping


def test_resolve_effects_defaults_without_and_cylinder_check():
    on = resolve_effects(None, (), 4)
    assert {e.name for e in on} == {n for n, cls in EFFECTS.items() if cls.default_on}
    assert {"torsional_flexibility", "variable_inertia", "tooth_spacing_error"} <= {e.name for e in on}
    assert "tooth_spacing_error" not in {e.name for e in resolve_effects(None, {"tooth_spacing_error"}, 4)}
    given = resolve_effects({"tooth_spacing_error": {"sigma_deg": 0.1}}, (), 4)  # replaces the default one
    assert [e["sigma_deg"] for e in given if e.name == "tooth_spacing_error"] == [0.1]
    with pytest.raises(ValueError, match="4 cylinders"):
        resolve_effects({"misfire": {"cylinder": 5}}, (), 4)
    with pytest.raises(ValueError, match="both requested and excluded"):
        resolve_effects({"tooth_spacing_error": {}}, {"tooth_spacing_error"}, 4)
    with pytest.raises(ValueError, match="unknown effect"):
        resolve_effects(None, {"flexibility"}, 4)


def test_several_instances_per_cylinder_and_refused_repeats():
    two = resolve_effects([RingWear(cylinder=1), RingWear(cylinder=3, gain=2.0)], (), 4)
    assert [e["cylinder"] for e in two if e.name == "ring_wear"] == [1, 3]
    for effects, words in [
        ([LoadRipple(), LoadRipple(order=2.0)], "effect 'load_ripple' is given twice; it applies once per engine"),
        ([parse_effect("tooth_spacing_error:sigma_deg=0.1"), parse_effect("tooth_spacing_error")],
         "'tooth_spacing_error' is given twice"),
        ([RingWear(cylinder=2), RingWear(cylinder=2, gain=2.0)], "'ring_wear' is given twice for cylinder 2"),
    ]:
        with pytest.raises(ValueError, match=words) as exc:
            check_instances(effects, 4)
        assert "\n" not in str(exc.value)


def test_hooks_return_new_setups_and_leave_their_input_alone():
    spec = load_engine("k9k-4cyl")
    cyl0 = CylinderSetup.nominal(spec, np.tile(spec.friction.coefficients, (4, 1)), rezeka_henein().names)
    before = {f.name: np.copy(getattr(cyl0, f.name)) for f in dataclasses.fields(cyl0)}
    cyl = cyl0
    for e in [RingWear(cylinder=2, gain=1.5), RingWear(cylinder=4, mass_loss=0.2),
              parse_effect("blow_by:cylinder=4,mass_loss=0.1"), parse_effect("misfire:cylinder=1,probability=0.3"),
              parse_effect("tdc_offset:cylinder=3,deg=2"), parse_effect("extra_friction:cylinder=2,amp_frac=0.5")]:
        cyl = e.apply_cylinders(cyl)
    for name, arr in before.items():
        assert np.array_equal(getattr(cyl0, name), arr), name  # nothing written into the input
    assert_allclose(cyl.coefficients[1, :3], 1.5 * spec.friction.coefficients[:3])
    assert_allclose(cyl.coefficients[3, :3], 1.4 * spec.friction.coefficients[:3])  # the default gain
    assert_allclose(cyl.coefficients[[0, 2]], cyl0.coefficients[[0, 2]])
    assert_allclose(cyl.mass_loss, [0, 0.12, 0, 1 - 0.8 * 0.9])  # two leaks in cylinder 4 compound
    assert_allclose(cyl.misfire, [0.3, 0, 0, 0])
    assert_allclose(cyl.firing_angles - cyl0.firing_angles, [0, 0, np.radians(2.0), 0])
    assert_allclose(cyl.extra_friction[1], [0.1, 0.5, 2.0, 0.0])
    s0 = SensorSetup.ideal(4)
    s = parse_effect("pressure_gain:cylinder=2,gain=1.1").apply_sensors(s0)
    s = parse_effect("pressure_offset:cylinder=2,pa=1e4").apply_sensors(s)
    assert_allclose(s.pressure_gain, [1, 1.1, 1, 1]) and np.array_equal(s0.pressure_gain, np.ones(4))
    assert_allclose(s.pressure_offset_pa, [0, 1e4, 0, 0])


def test_monitor_side_terms():
    spec = load_engine("k9k-4cyl")
    assert set(RingWear.scales_terms) <= set(rezeka_henein().names) and RingWear().monitor_terms(spec) == ()
    for text in ("tdc_offset", "pressure_gain", "pressure_offset", "misfire"):
        assert parse_effect(text).monitor_terms(spec) == ()  # corrected on the pressure side, not by a column
    (term,) = parse_effect("extra_friction:cylinder=2,mean_frac=0.2,amp_frac=0.5,order=1.5").monitor_terms(spec)
    assert term.name == "extra_friction_c2" and term.group == "engine" and term.prior == 0.0  # one T_ref, cylinder 2 only


def test_every_effect_is_documented():
    from pathlib import Path
    doc = (Path(__file__).resolve().parents[2] / "docs" / "effects.md").read_text()
    for name, eff in EFFECTS.items():
        assert f"`{name}`" in doc
        for key in eff.parameters:
            assert f"`{key}`" in doc, (name, key)


# ---- what each effect does (K9K 1700 rpm full load, 3 cycles, no combustion variability) ------------------------

SPEC = load_engine("k9k-4cyl")
QUIET = {"cov_imep": 0.0}


@pytest.fixture(scope="module")
def base():
    return simulate(SPEC, 1700, 1.0, 3, 11, **QUIET)


def run(effects=None, without=(), **kw):
    return simulate(SPEC, 1700, 1.0, 3, 11, effects=effects, without=without, **{**QUIET, **kw})


def cyl(r, k, key):
    return r.truth["cylinders"][k - 1][key]


def test_misfire_cylinder_is_motored(base):
    r = run({"misfire": {"cylinder": 3}})
    model = cylinder_model(SPEC)
    p, _ = cylinder_pressure(model, cycle_params(SPEC, 1700 * np.pi / 30, 0.0))
    assert_allclose(cyl(r, 3, "imep_bar"), imep(model, p) / 1e5, atol=0.05)  # motored IMEP ~ -0.4 bar
    assert cyl(r, 3, "friction_torque_mean_nm") < 0.9 * cyl(base, 3, "friction_torque_mean_nm")
    assert_allclose(cyl(r, 1, "imep_bar"), cyl(base, 1, "imep_bar"), rtol=0.01)


def test_ring_wear_lowers_pmax_and_raises_friction(base):
    r = run({"ring_wear": {"cylinder": 2, "gain": 1.4}})
    drop = 1 - cyl(r, 2, "pmax_bar_mean") / cyl(base, 2, "pmax_bar_mean")
    assert 0.03 <= drop <= 0.08  # engines.md §4: worn rings p_max -3..-8 %
    assert cyl(r, 2, "friction_torque_mean_nm") > 1.1 * cyl(base, 2, "friction_torque_mean_nm")
    assert_allclose(cyl(r, 2, "coefficients")[:3], 1.4 * SPEC.friction.coefficients[:3])
    assert_allclose(cyl(r, 2, "coefficients")[3:], SPEC.friction.coefficients[3:])
    assert_allclose(cyl(r, 1, "pmax_bar_mean"), cyl(base, 1, "pmax_bar_mean"), rtol=0.002)


def test_blow_by_lowers_pmax_only(base):
    r = run({"blow_by": {"cylinder": 4}})
    assert 0.03 <= 1 - cyl(r, 4, "pmax_bar_mean") / cyl(base, 4, "pmax_bar_mean") <= 0.08
    assert cyl(r, 4, "imep_bar") < cyl(base, 4, "imep_bar")
    assert_allclose(cyl(r, 4, "coefficients"), SPEC.friction.coefficients)
    assert r.truth["operating"]["leak_area_m2"][3] > 0


def test_extra_friction_adds_its_torque(base):
    r = run({"extra_friction": {"cylinder": 1, "mean_frac": 0.2}})
    extra = cyl(r, 1, "extra_friction_torque_nm")
    assert_allclose(extra, 0.2 * cyl(base, 1, "friction_torque_mean_nm"), rtol=0.02)
    assert_allclose(cyl(r, 1, "friction_torque_mean_nm") - extra, cyl(base, 1, "friction_torque_mean_nm"), rtol=0.01)
    assert_allclose(sum(cyl(r, 1, "coefficients_normalised")) + extra, cyl(r, 1, "friction_torque_mean_nm"),
                    rtol=1e-9)


def pressure_of(r, k):
    frames = [f for f in r.records if isinstance(f, PressureFrame)]
    row = frames[0].cylinders.index(k)
    return np.concatenate([f.values[row] for f in frames]), frames[0].period_ticks / r.info.tick_hz


def test_tdc_offset_one_cylinder_shifts_its_pressure_phase(base):
    r = run({"tdc_offset": {"deg": 3.0, "cylinder": 2}}, without={"sensor_noise"})
    ref = run(without={"sensor_noise"})
    p1, dt = pressure_of(r, 2)
    p0, _ = pressure_of(ref, 2)
    lag = np.argmax(np.correlate(p1 - p1.mean(), p0 - p0.mean(), "full")) - (p0.size - 1)
    expect = np.radians(3.0) / (1700 * np.pi / 30) / dt  # 3 deg later at 1700 rpm, in samples
    assert abs(lag - expect) <= 1.0
    assert r.info.first_tooth_deg == SPEC.sensors.first_tooth_deg  # the stated wheel is the nominal one


def test_tdc_offset_all_moves_the_true_wheel(base):
    r = run({"tdc_offset": {"deg": -1.5}})
    assert r.truth["wheel"]["first_tooth_deg_true"] == pytest.approx(SPEC.sensors.first_tooth_deg + 1.5)
    assert r.info.first_tooth_deg == SPEC.sensors.first_tooth_deg


def test_pressure_offset_shifts_the_reading(base):
    r = run({"pressure_offset": {"cylinder": 1, "pa": 50e3}})
    y, _ = pressure_of(r, 1)
    truth = r.diagnostics["pressure_true_pa"][:, 0]
    assert_allclose((y - truth).mean(), 50e3, atol=1e3)
    y2, _ = pressure_of(r, 2)
    assert abs((y2 - r.diagnostics["pressure_true_pa"][:, 1]).mean()) < 1e3


def test_pressure_saturation_clips_at_range():
    r = run({"pressure_offset": {"cylinder": 1, "pa": -2e5}}, without={"sensor_noise"})
    y, _ = pressure_of(r, 1)
    lsb = SPEC.sensors.pressure_range_pa / 2**SPEC.sensors.pressure_adc_bits
    low = r.diagnostics["pressure_true_pa"][:, 0] - 2e5 < 0.5 * lsb  # gas exchange at 1.6-1.8 bar reads 0
    assert low.any() and y.min() >= 0.0 and ((y == 0.0) == low).all()
    assert np.all(np.abs(y[~low] - (r.diagnostics["pressure_true_pa"][~low, 0] - 2e5)) <= 0.5 * lsb + 1e-6)
    from frictionwatch.core.plant.sensors import pressure_adc
    top = pressure_adc(np.array([1e5, 30e6]), SPEC.sensors, 0.0, np.random.default_rng(0))
    assert top[1] == SPEC.sensors.pressure_range_pa


def order_amplitude(w, order):
    """Mean amplitude [rad/s] of engine order ``order`` in the per-cycle flywheel speed (720 pts per 4 pi)."""
    spec = np.fft.rfft(w - w.mean(axis=1, keepdims=True), axis=1)
    return np.abs(spec[:, round(2 * order)]).mean() * 2 / w.shape[1]


def test_load_ripple_appears_at_its_order(base):
    r = run({"load_ripple": {"amplitude_nm": 20.0, "order": 1.5}})
    w0, w1 = base.diagnostics["flywheel_speed_grid_rad_s"], r.diagnostics["flywheel_speed_grid_rad_s"]
    assert order_amplitude(w1, 1.5) > order_amplitude(w0, 1.5) + 0.05
    assert r.truth["operating"]["load_ripple_nm"] == 20.0


def test_load_ripple_in_phase_and_quadrature_are_its_amplitude_and_phase():
    """The discrepancy workflow's form (A cos phase, A sin phase) makes the same plant as amplitude and phase; both
    forms at once are refused."""
    polar = run({"load_ripple": {"amplitude_nm": 20.0, "order": 1.5, "phase_deg": 120.0}})
    parts = run({"load_ripple": {"in_phase_nm": 20.0 * np.cos(np.radians(120.0)), "order": 1.5,
                                 "quadrature_nm": 20.0 * np.sin(np.radians(120.0))}})
    assert_allclose(parts.truth["operating"]["load_ripple_nm"], 20.0, rtol=1e-12)
    assert_allclose(parts.diagnostics["flywheel_speed_grid_rad_s"], polar.diagnostics["flywheel_speed_grid_rad_s"],
                    rtol=1e-9)
    with pytest.raises(ValueError, match="not both"):
        LoadRipple(amplitude_nm=5.0, in_phase_nm=1.0)


def test_the_monitor_takes_a_stated_load_ripple_as_a_known_torque_at_the_load_node():
    from frictionwatch.core.model.effects.base import ViewSetup
    from frictionwatch.core.monitor.balance.harmonic_balance import known_load_ripple, subtract_load_ripple

    view = LoadRipple(in_phase_nm=3.0, quadrature_nm=4.0, order=0.5).apply_view(
        ViewSetup.nominal(SPEC, rezeka_henein(), np.zeros((SPEC.n_cyl, 6))))
    assert_allclose(view.load_ripple, (5.0, 0.0, 0.5, np.arctan2(4.0, 3.0)), rtol=1e-12)
    # a fraction of the mean load: of the measured one; none where the load is not measured
    assert known_load_ripple((0.0, 0.1, 1.5, 0.0), float("nan"), 2) is None
    r = known_load_ripple((0.0, 0.1, 1.5, 0.3), -200.0, 2)
    assert r.node == 2 and r.amplitude == pytest.approx(20.0) and (r.order, r.phase) == (1.5, 0.3)
    known, theta = np.ones((3, 8)), np.linspace(0.0, 4.0 * np.pi, 8, endpoint=False)
    subtract_load_ripple(known, theta, np.array([0.0, 0.0, 0.01]), r)  # its static twist: 0.01 rad ahead of the flywheel
    assert_allclose(known[2], 1.0 - 20.0 * np.sin(1.5 * (theta + 0.01) + 0.3), rtol=1e-12)
    assert_allclose(known[:2], 1.0)


def test_tooth_spacing_error_sum_zero_and_rms(base):
    err = np.asarray(base.truth["wheel"]["tooth_errors_deg"])
    assert abs(err.sum()) < 1e-9 and 0.015 < err.std() < 0.05
    off = run(without={"tooth_spacing_error"})
    assert not np.any(off.truth["wheel"]["tooth_errors_deg"])


def test_rigid_and_constant_inertia_variants():
    rigid = run(without={"torsional_flexibility"})
    assert rigid.truth["damper_coupling_loss_nm"] == 0.0
    w = rigid.diagnostics["flywheel_speed_grid_rad_s"]
    # rigid K9K, all 0.395 + J_rec kg m^2 on one shaft: ~5.2 rad/s p-p (physics.md §4: 10.4 with the engine-side half)
    assert 4.0 < np.ptp(w, axis=1).mean() < 6.5
    const = simulate(SPEC, 4000, 1.0, 2, 11, without={"torsional_flexibility", "variable_inertia"}, **QUIET)
    var = simulate(SPEC, 4000, 1.0, 2, 11, without={"torsional_flexibility"}, **QUIET)
    # at 4000 rpm the order-2 mass torque dominates: ignoring it changes the order-2 speed ripple a lot
    a0 = order_amplitude(const.diagnostics["flywheel_speed_grid_rad_s"], 2)
    a1 = order_amplitude(var.diagnostics["flywheel_speed_grid_rad_s"], 2)
    assert abs(a1 - a0) > 0.3 * a1
    assert_allclose(const.truth["imep_bar"], var.truth["imep_bar"], rtol=0.01)


def test_misfire_with_probability_gives_some_motored_cycles():
    r = simulate(SPEC, 1700, 1.0, 8, 11, effects=[parse_effect("misfire:cylinder=3,probability=0.5")], **QUIET)
    model = cylinder_model(SPEC)
    motored = imep(model, cylinder_pressure(model, cycle_params(SPEC, 1700 * np.pi / 30, 0.0))[0]) / 1e5
    im3 = np.array([c["cylinders"][2]["imep_bar"] for c in r.truth["cycles"]])
    im1 = np.array([c["cylinders"][0]["imep_bar"] for c in r.truth["cycles"]])
    dead = np.abs(im3 - motored) < 0.1  # a cycle without combustion: the motored IMEP (~ -0.4 bar)
    assert 0 < dead.sum() < dead.size  # seed 11 draws some of each
    assert np.all(im3[~dead] > 0.9 * im1.mean()) and np.all(im1 > 10.0)


def test_ring_wear_in_two_cylinders_both_act_and_both_are_in_the_truth(base):
    r = run([RingWear(cylinder=1, gain=1.3), RingWear(cylinder=3, gain=1.6)])
    listed = [e for e in r.truth["effects"] if e["name"] == "ring_wear"]
    assert [(e["params"]["cylinder"], e["params"]["gain"]) for e in listed] == [(1, 1.3), (3, 1.6)]
    for k, gain in ((1, 1.3), (3, 1.6)):
        assert_allclose(cyl(r, k, "coefficients")[:3], gain * SPEC.friction.coefficients[:3])
        assert cyl(r, k, "friction_torque_mean_nm") > 1.1 * cyl(base, k, "friction_torque_mean_nm")
        assert cyl(r, k, "pmax_bar_mean") < 0.97 * cyl(base, k, "pmax_bar_mean")
    assert_allclose(cyl(r, 2, "coefficients"), SPEC.friction.coefficients)
    assert {e["name"] for e in r.truth["effects"]} >= {"torsional_flexibility", "sensor_noise"}  # defaults listed
    with pytest.raises(ValueError, match="given twice for cylinder 3"):
        run([RingWear(cylinder=3), RingWear(cylinder=3)])


def test_pressure_gain_scales_the_reading():
    r = run({"pressure_gain": {"cylinder": 2, "gain": 1.05}}, without={"sensor_noise"})
    lsb = SPEC.sensors.pressure_range_pa / 2**SPEC.sensors.pressure_adc_bits
    y, _ = pressure_of(r, 2)
    truth = r.diagnostics["pressure_true_pa"][:, 1]
    assert np.all(np.abs(y - 1.05 * truth) <= 0.5 * lsb + 1e-6)  # only ADC rounding left without noise
    y1, _ = pressure_of(r, 1)
    assert np.all(np.abs(y1 - r.diagnostics["pressure_true_pa"][:, 0]) <= 0.5 * lsb + 1e-6)


def test_tdc_offset_moves_the_pressure_peak_by_the_offset():
    r = run({"tdc_offset": {"deg": 4.0, "cylinder": 1}}, without={"sensor_noise"})
    ref = run(without={"sensor_noise"})
    p1, dt = pressure_of(r, 1)
    p0, _ = pressure_of(ref, 1)
    w = 1700 * np.pi / 30
    # per cycle the peak sample of cylinder 1: 4 deg later at 1700 rpm = 0.39 ms = 7.8 samples at 20 kHz
    per_cycle = round(4 * np.pi / w / dt)
    n = min(p1.size, p0.size) // per_cycle
    shift = [np.argmax(p1[i * per_cycle:(i + 1) * per_cycle]) - np.argmax(p0[i * per_cycle:(i + 1) * per_cycle])
             for i in range(n)]
    assert_allclose(np.median(shift), np.radians(4.0) / w / dt, atol=1.0)
