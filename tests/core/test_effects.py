"""Effect registry (core/effects.py) and what each effect does to a simulated engine (core/simulate.py)."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from frictionwatch.core.model.effects import EFFECTS, parse_effect, resolve_effects
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.core.model.thermo import cycle_params, cylinder_model, cylinder_pressure, imep
from frictionwatch.core.types import PressureFrame

# ---- registry and parsing -----------------------------------------------------------------------------------------


def test_parse_effect_fills_defaults_and_types():
    name, params = parse_effect("ring_wear:cylinder=3,gain=1.4")
    assert name == "ring_wear"
    assert params == {"cylinder": 3, "gain": 1.4, "mass_loss": EFFECTS["ring_wear"].params["mass_loss"].default}
    assert isinstance(params["cylinder"], int)
    assert parse_effect("variable_inertia") == ("variable_inertia", {})
    assert parse_effect(" misfire : cylinder = 2 ")[1]["cylinder"] == 2


@pytest.mark.parametrize("text,words", [
    ("ring_waer:cylinder=3", "unknown effect 'ring_waer'"),
    ("ring_wear:cyl=3", "no parameter 'cyl'"),
    ("ring_wear:cylinder=0", "out of range"),
    ("ring_wear:cylinder=2.5", "integer"),
    ("ring_wear:gain=abc", "not a number"),
    ("misfire:probability=1.5", "out of range"),
    ("misfire:cylinder", "not key=value"),
    ("tdc_offset:deg=nan", "out of range"),
])
def test_parse_effect_errors_are_one_line(text, words):
    with pytest.raises(ValueError, match=words) as exc:
        parse_effect(text)
    assert "\n" not in str(exc.value)


def test_resolve_effects_defaults_without_and_cylinder_check():
    on = resolve_effects(None, (), 4)
    assert set(on) == {n for n, e in EFFECTS.items() if e.default_on}
    assert {"torsional_flexibility", "variable_inertia", "tooth_spacing_error"} <= set(on)
    assert "tooth_spacing_error" not in resolve_effects(None, {"tooth_spacing_error"}, 4)
    with pytest.raises(ValueError, match="4 cylinders"):
        resolve_effects({"misfire": {"cylinder": 5}}, (), 4)
    with pytest.raises(ValueError, match="both requested and excluded"):
        resolve_effects({"tooth_spacing_error": {}}, {"tooth_spacing_error"}, 4)
    with pytest.raises(ValueError, match="unknown effect"):
        resolve_effects(None, {"flexibility"}, 4)


def test_every_effect_is_documented():
    from pathlib import Path
    doc = (Path(__file__).resolve().parents[2] / "docs" / "effects.md").read_text()
    for name, eff in EFFECTS.items():
        assert f"`{name}`" in doc
        for key in eff.params:
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
    r = run({"pressure_offset": {"cylinder": 1, "pa": -2e5, "gain": 1.0}}, without={"sensor_noise"})
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
