"""The discrepancy workflow on simulator logs with a hidden effect (the workflow is never told which), the default
realistic effects on: the right effect named (and cylinder), its parameter within 20 %, the gap down >= 80 %; nothing
hidden: nothing found; a baseline without a default effect: that effect found. Small logs, one run each (module
fixtures); the full matrix of effects, operating points and seeds is bench/bench_discrepancy.py --matrix."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.core.discrepancy import Options, discover
from frictionwatch.core.model.effects import make_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.discrepancy_report import render
from frictionwatch.service.pipeline import assembled_cycles

pytestmark = pytest.mark.slow  # collected first (tests/conftest.py): one of the suite's longest files

ENGINE = "k9k-4cyl"
CYCLES = 84
OPTIONS = Options(max_steps=2)


def cycles_of(rpm, load, seed, effects=()):
    spec = load_engine(ENGINE)
    sim = simulate(spec, rpm, load, CYCLES, seed, effects=list(effects))
    return assembled_cycles(spec, sim.info, sim.records)[0]


@pytest.fixture(scope="module")
def healthy():
    return cycles_of(2500.0, 0.8, 5)


@pytest.fixture(scope="module")
def gain_fault():
    return cycles_of(2500.0, 0.8, 6, [make_effect("pressure_gain", {"cylinder": 3, "gain": 1.06})])


def test_nothing_hidden_nothing_found(healthy):
    model = EngineModel.from_spec(load_engine(ENGINE))
    found = discover(model, healthy, OPTIONS)
    doc = found.to_json()
    assert doc["found"] == [] and doc["outcome"] == "nothing" and doc["remainder"] is None
    assert doc["verdict"].startswith(("No significant missing effect", "No missing effect beyond the model's own"))
    assert not doc["step_limit_reached"]
    assert found.model == model
    assert doc["gap_after"] == doc["gap_before"]


def test_hidden_pressure_gain_is_named_and_fitted(gain_fault):
    found = discover(EngineModel.from_spec(load_engine(ENGINE)), gain_fault, OPTIONS)
    doc = found.to_json()
    first = doc["found"][0]
    assert (first["effect"], first["cylinder"]) == ("pressure_gain", 3), doc["found"]
    np.testing.assert_allclose(first["parameters"]["gain"] - 1.0, 0.06, rtol=0.2)
    assert 0.0 < first["sigma"]["gain"] < 0.02
    assert doc["gap_after"] <= 0.2 * doc["gap_before"]
    added = found.model.effects[-len(doc["found"]):]
    assert added[0].name == "pressure_gain" and added[0].sigma["gain"] == pytest.approx(first["sigma"]["gain"])
    assert doc["outcome"] == "named" and doc["verdict"].startswith("Found pressure_gain (cylinder 3, gain=")
    # a channel reading 6 % high overstates the indicated work and so the measured friction: corrected, it falls
    ev = first["evidence"]
    before, after = ev["measured_friction_before"], ev["measured_friction_after"]
    assert after["mean_nm"] < before["mean_nm"] - 3 * after["sigma_nm"]
    np.testing.assert_allclose(after["fmep_bar"] * 1e5, load_engine(ENGINE).torque_to_mep(after["mean_nm"]), rtol=1e-12)


def test_the_step_limit_is_said(gain_fault):
    """One step allowed and one taken: the report says the limit was reached and that more may be missing."""
    doc = discover(EngineModel.from_spec(load_engine(ENGINE)), gain_fault, Options(max_steps=1)).to_json()
    assert len(doc["found"]) == 1 and doc["step_limit_reached"]
    assert "the step limit (1) was reached" in doc["verdict"]


def test_rigid_baseline_finds_the_flexible_shaft_line(healthy):
    model = EngineModel.from_spec(load_engine(ENGINE), without={"torsional_flexibility"})
    doc = discover(model, healthy, OPTIONS).to_json()
    assert doc["found"] and doc["found"][0]["effect"] == "torsional_flexibility", doc["found"]
    assert doc["gap_after"] <= 0.2 * doc["gap_before"]


def test_too_few_cycles_is_refused(healthy):
    with pytest.raises(ValueError, match="at least"):
        discover(EngineModel.from_spec(load_engine(ENGINE)), healthy[:20])


def _residuals(harmonics, balance):
    from frictionwatch.core.discrepancy.residuals import ANGLE_POINTS, Residuals

    n = harmonics.shape[0]
    return Residuals(np.arange(n), np.full(n, 250.0), np.full(n, 50.0), harmonics, balance,
                     np.zeros((n, ANGLE_POINTS)), np.linspace(0, 4 * np.pi, ANGLE_POINTS, endpoint=False))


def test_a_step_that_makes_a_channel_worse_is_named_so():
    """channel_worse judges each channel on its own, against its noise and the null: a speed gap traded for a
    torque-balance offset is refused; a step that explains the speed but leaves a coherent residual at an order that
    was clean before is refused; noise-sized changes are not (made-up residuals, unit per-cycle noise, 40 cycles)."""
    from frictionwatch.core.discrepancy.choice import channel_worse

    rng = np.random.default_rng(3)
    n, m = 40, 6
    noise = rng.standard_normal((n, m)) + 1j * rng.standard_normal((n, m))
    coherent = np.zeros(m, complex)
    coherent[:3] = 2.0
    before = _residuals(noise + coherent, rng.standard_normal(n))
    scale = np.ones(2 * m + 1)
    traded = _residuals(noise, rng.standard_normal(n) + 1.5)  # speed explained, balance now off by 1.5 sigma
    assert "torque balance" in channel_worse(before, traded, scale)
    fine = _residuals(noise, rng.standard_normal(n))  # speed explained, balance noise only
    assert channel_worse(before, fine, scale) == ""
    moved = np.zeros(m, complex)
    moved[4] = 5.0  # the first orders explained, a larger coherent residual where there was none
    assert "flywheel speed" in channel_worse(before, _residuals(noise + moved, rng.standard_normal(n)), scale)


def test_a_parameter_on_its_bound_is_not_physical():
    from frictionwatch.core.discrepancy.candidates import candidate_library
    from frictionwatch.core.discrepancy.choice import off_physics as _off_physics
    from frictionwatch.core.discrepancy.fit import Trial

    lib = {c.label: c for c in candidate_library(EngineModel.from_spec(load_engine(ENGINE)))}
    tdc = lib["tdc_offset[cyl 2]"]
    assert "bound" in _off_physics(Trial(tdc, np.array([10.0]), np.array([0.1]), 1.0, 2.0, 1))
    assert _off_physics(Trial(tdc, np.array([1.1]), np.array([0.1]), 1.0, 2.0, 1)) == ""
    law = lib["stribeck_ring"]  # a share: 1.0 (all of the base term) is a physical value
    assert _off_physics(Trial(law, np.array([1.0]), np.array([0.1]), 1.0, 2.0, 1)) == ""


def test_two_explanations_within_the_noise_are_said_both_and_neither_added():
    """_rival: the runner-up counts as a second explanation when it is significant too and its held-out chi^2 is
    within AMBIGUOUS_DCHI2 of the best; the verdict then names both and what would separate them."""
    from frictionwatch.core.discrepancy.candidates import candidate_library
    from frictionwatch.core.discrepancy.choice import AMBIGUOUS_DCHI2
    from frictionwatch.core.discrepancy.choice import rival as _rival
    from frictionwatch.core.discrepancy.discovery import Discovery
    from frictionwatch.core.discrepancy.fit import Trial

    lib = {c.label: c for c in candidate_library(EngineModel.from_spec(load_engine(ENGINE)))}
    tdc, gain = lib["tdc_offset[cyl 2]"], lib["pressure_gain[cyl 2]"]
    trial = [Trial(c, np.array([x]), np.array([0.1]), 1.0, 2.0, 1) for c, x in ((tdc, 0.8), (gain, 1.05))]
    chi2 = {"a": 30.0, "b": 30.0 + 0.5 * AMBIGUOUS_DCHI2, "c": 30.0 + 2.0 * AMBIGUOUS_DCHI2}
    yes = lambda r: True  # noqa: E731
    of = lambda c: chi2[c[3]]  # noqa: E731  (a confirmed entry: gap, trial, model, run)
    assert _rival([(1.0, trial[0], None, "a"), (1.1, trial[1], None, "b")], yes, of) is trial[1]
    assert _rival([(1.0, trial[0], None, "a"), (1.3, trial[1], None, "c")], yes, of) is None
    assert _rival([(1.0, trial[0], None, "a"), (1.1, trial[1], None, "b")], lambda r: r == "a", of) is None
    model = EngineModel.from_spec(load_engine(ENGINE))
    found = Discovery(model, model, [], 5.0, 5.0, {}, {},
                      ambiguous={"candidates": [tdc.label, gain.label], "separated_by": [tdc.separated_by]})
    assert found.outcome == "ambiguous"
    assert "tdc_offset[cyl 2] and pressure_gain[cyl 2] explain the rest equally well" in found.verdict()
    assert "motored stretch" in found.verdict()


def test_the_pressure_channel_counts_what_a_model_leaves_of_the_tdc_reading():
    """tdc_chi2: the pressure read every cylinder 1.5 deg late (sigma 0.2): a model that moves the wheel by 1.5 deg
    leaves nothing, one that moves nothing leaves 4 x (1.5 / 0.2)^2; tdc_offsets_deg reads a model's TDC effects."""
    import dataclasses

    from frictionwatch.core.discrepancy.pressure_channel import tdc_chi2, tdc_offsets_deg

    spec = load_engine(ENGINE)
    model = EngineModel.from_spec(spec, effects=[make_effect("tdc_offset", {"cylinder": 0, "deg": 1.5}),
                                                 make_effect("tdc_offset", {"cylinder": 3, "deg": -0.4})])
    np.testing.assert_allclose(tdc_offsets_deg(model), [1.5, 1.5, 1.1, 1.5], rtol=0, atol=1e-12)
    from tests.core.test_discrepancy_parts import made_up

    res = dataclasses.replace(made_up(10, 4, np.zeros(4, complex), 0.0), tdc_deg=np.full(4, 1.5),
                              tdc_sigma_deg=np.full(4, 0.2))
    np.testing.assert_allclose(tdc_chi2(res, np.full(4, 1.5)), 0.0, atol=1e-12)
    np.testing.assert_allclose(tdc_chi2(res, np.zeros(4)), 4 * (1.5 / 0.2) ** 2, rtol=1e-12)
    assert tdc_chi2(dataclasses.replace(res, tdc_deg=None), np.zeros(4)) == 0.0


def test_the_pressure_names_a_pegging_offset_and_a_misfiring_cylinder():
    """pressure_findings on made-up readings: a pegging of +1.5 bar to add on cylinder 2 (sampling sigma 500 Pa) is a
    sensor reading 1.5 bar low, its sigma with the method's floor; 0.1 bar is under the 0.2 bar threshold; cylinder 3
    misfired in 30 of 100 cycles, in both halves: probability 0.3 +- binomial; cylinder 1's two misfires, and
    cylinder 4's ten all in the first half, are not a pattern."""
    import dataclasses

    from frictionwatch.core.discrepancy.pressure_channel import PEG_FLOOR_PA, pressure_findings

    from tests.core.test_discrepancy_parts import made_up

    n = 100
    misfired = np.zeros((n, 4), dtype=bool)
    misfired[::10, 2] = misfired[1::10, 2] = misfired[2::10, 2] = True  # 30, spread over the log
    misfired[[5, 60], 0] = True
    misfired[:10, 3] = True
    res = dataclasses.replace(made_up(n, 4, np.zeros(4, complex), 0.0), misfired=misfired,
                              pegging_pa=np.array([0.0, 1.5e5, 0.1e5, np.nan]), pegging_sigma_pa=np.full(4, 500.0))
    found = {f.label: f for f in pressure_findings(res)}
    assert sorted(found) == ["misfire[cyl 3]", "pressure_offset[cyl 2]"]
    peg, mis = found["pressure_offset[cyl 2]"], found["misfire[cyl 3]"]
    np.testing.assert_allclose([peg.value, peg.sigma], [-1.5e5, np.hypot(500.0, PEG_FLOOR_PA)], rtol=1e-12)
    np.testing.assert_allclose([mis.value, mis.sigma], [0.3, np.sqrt(0.3 * 0.7 / n)], rtol=1e-12)
    assert "30 of 100" in mis.reading and "-1.50 bar" in peg.reading


@pytest.fixture(scope="module")
def pressure_faults():
    """k9k-4cyl 2200 rpm / 0.7, seed 8: cylinder 2 misfires in 30 % of its cycles and cylinder 4's sensor reads
    1.5 bar high (neither moves the speed much: the monitor reads both in the pressure it measures)."""
    return cycles_of(2200.0, 0.7, 8, [make_effect("misfire", {"cylinder": 2, "probability": 0.3}),
                                      make_effect("pressure_offset", {"cylinder": 4, "pa": 1.5e5})])


def test_pegging_and_misfire_are_named_from_the_pressure(pressure_faults):
    found = discover(EngineModel.from_spec(load_engine(ENGINE)), pressure_faults, OPTIONS)
    doc = found.to_json()
    pressure = {(f["effect"], f["cylinder"]): f for f in doc["found"] if f["evidence"]["channel"] == "pressure"}
    assert sorted(pressure) == [("misfire", 2), ("pressure_offset", 4)], doc["verdict"]
    pa, mis = pressure[("pressure_offset", 4)], pressure[("misfire", 2)]
    np.testing.assert_allclose(pa["parameters"]["pa"], 1.5e5, rtol=0.1)
    assert abs(pa["parameters"]["pa"] - 1.5e5) <= 3 * pa["sigma"]["pa"] + 0.05e5
    np.testing.assert_allclose(mis["parameters"]["probability"], 0.3, atol=0.1)  # ~70 scored cycles: +-0.055
    assert mis["evidence"]["pressure_reading"].startswith("the pressure shows no full burn in")
    assert "misfire (cylinder 2" in doc["verdict"] and "pressure_offset (cylinder 4" in doc["verdict"]
    assert not any(f["effect"] == "tdc_offset" for f in doc["found"])  # the offset is not read as a TDC error
    again = discover(found.model, pressure_faults, OPTIONS)  # the model that states them: nothing more to name
    assert again.to_json()["found"] == [], again.verdict()


def test_a_single_cylinders_misfires_are_the_short_motored_runs_between_burns():
    """One cylinder: the monitor calls an unburned cycle motored (no sibling burned); over the log, runs of up to
    three motored cycles between burned ones are misfires, a long stretch (ignition off) and the log's ends are not."""
    from frictionwatch.core.discrepancy.pressure_channel import single_cylinder_misfires

    motored = np.array([1, 0, 1, 0, 1, 1, 1, 0, 1, 1, 1, 1, 0, 1], dtype=bool)
    expected = np.array([0, 0, 1, 0, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0], dtype=bool)
    np.testing.assert_array_equal(single_cylinder_misfires(motored), expected)
    assert not single_cylinder_misfires(np.ones(5, bool)).any() and not single_cylinder_misfires(np.zeros(0, bool)).size


def test_every_cylinder_the_window_cannot_tell_from_the_lead_is_held_out_too():
    """genset-v20, a worn ring on cylinder 12 (bench.bench_discrepancy's speed case): ring_wear on cylinders 8, 2
    and 12 fitted the training window within 5 of each other's chi^2, 19 by 17 more; 8 alone was held out and named.
    Now 2 and 12 go to the held-out test beside it (19 does not, nor another effect, nor an engine-wide lead's)."""
    from types import SimpleNamespace as NS

    from frictionwatch.core.discrepancy.choice import close_cylinders

    def item(effect, cyl, cost):
        return NS(candidate=NS(effect=effect, cylinder=cyl, label=f"{effect}[cyl {cyl}]"), cost=cost)

    items = [item("ring_wear", 8, 1166.9), item("ring_wear", 2, 1169.0), item("tdc_offset", 17, 1170.0),
             item("ring_wear", 12, 1171.7), item("ring_wear", 19, 1183.6)]
    close = close_cylinders(items, [items[0]], lambda x: x.cost)
    assert [x.candidate.label for x in close] == ["ring_wear[cyl 2]", "ring_wear[cyl 12]"]
    assert close_cylinders(items, [item("side_thrust_skirt", None, 1160.0)], lambda x: x.cost) == []


def test_a_half_order_load_ripple_is_named_with_its_order_amplitude_and_phase():
    """A 5 % load ripple at engine order 0.5 (no cylinder's: the load's) is named as one, its amplitude within 20 %
    and 2 sigma of the simulator's (measured: 6.73 against 6.92 N m, sigma 0.34; phase 59.1 deg against 60). Seed 9 at 2500 rpm: neither the matrix's points nor its seeds (bench_discrepancy:
    1800 and 3000 rpm, seeds 1-2), nothing tuned on it."""
    spec = load_engine(ENGINE)
    ripple = make_effect("load_ripple", {"fraction": 0.05, "order": 0.5, "phase_deg": 60.0})
    sim = simulate(spec, 2500.0, 0.8, CYCLES, 9, effects=[ripple])
    cycles = assembled_cycles(spec, sim.info, sim.records)[0]
    doc = discover(EngineModel.from_spec(spec), cycles, OPTIONS).to_json()
    first = doc["found"][0]
    assert first["effect"] == "load_ripple" and first["parameters"]["order"] == 0.5, doc["found"]
    a, b = first["parameters"]["in_phase_nm"], first["parameters"]["quadrature_nm"]
    true_nm = sim.truth["operating"]["load_ripple_nm"]
    np.testing.assert_allclose(np.hypot(a, b), true_nm, rtol=0.2)
    sigma = np.hypot(a * first["sigma"]["in_phase_nm"], b * first["sigma"]["quadrature_nm"]) / np.hypot(a, b)
    assert abs(np.hypot(a, b) - true_nm) <= 2.0 * sigma
    # the phase as the plant has it, within what a few tenths of a degree of twist at the load move it
    np.testing.assert_allclose(np.degrees(np.arctan2(b, a)), 60.0, atol=5.0)
    assert doc["gap_after"] <= 0.2 * doc["gap_before"]
    assert "order=0.5" in doc["verdict"]
    # 6.9 N m is more than one cylinder's friction can swing (amp > 1 + mean): the cam-order friction fitted to it
    # is dropped, and the JSON says why
    assert "would drive the engine" in doc["not_physical"].get("extra_friction[order 0.5]", ""), doc["not_physical"]


def test_a_cam_order_friction_is_said_without_a_cylinder_the_speed_cannot_tell():
    """An extra friction at engine order 0.5 in cylinder 3 (with its mean): the speed reads it alike from every
    cylinder, so the workflow says what it is and that it cannot place it, and adds nothing (it had named a worn ring
    on that cylinder, and then a load ripple). Seed 10 at 2500 rpm: not the matrix's."""
    spec = load_engine(ENGINE)
    cam = make_effect("extra_friction", {"cylinder": 3, "mean_frac": 0.5, "amp_frac": 0.8, "order": 0.5})
    cycles = cycles_of(2500.0, 0.8, 10, [cam])
    model = EngineModel.from_spec(spec)
    found = discover(model, cycles, OPTIONS)
    doc = found.to_json()
    assert doc["outcome"] == "ambiguous" and doc["found"] == [] and found.model == model, doc["verdict"]
    assert doc["ambiguous"]["candidates"] == ["extra_friction[order 0.5] in any one of the 4 cylinders"]
    assert "the speed cannot tell which, so it was not added" in doc["verdict"]


def test_a_softer_shaft_line_is_found_from_the_refinement_that_starts_softer():
    """A shaft line 25 % softer than the spec's: the speed is far from linear in the stiffness, so the refinement
    also starts from the effect's declared seeds (a third softer and stiffer); the scale is named within 10 % of its
    excess and the gap falls by 80 %. Seed 12 at 2500 rpm, scale 0.75: neither the matrix's points nor its scales
    (0.8, 1.5). Measured: 0.753 +- 0.009, gap 5.9 -> 0.5; without the seeds 0.787 +- 0.017, gap 5.9 -> 2.0."""
    spec = load_engine(ENGINE)
    cycles = cycles_of(2500.0, 0.8, 12, [make_effect("chain_mismatch", {"stiffness_scale": 0.75})])
    doc = discover(EngineModel.from_spec(spec), cycles, OPTIONS).to_json()
    first = doc["found"][0]
    assert first["effect"] == "chain_mismatch", doc["verdict"]
    np.testing.assert_allclose(first["parameters"]["stiffness_scale"] - 1.0, -0.25, rtol=0.1)
    assert doc["gap_after"] <= 0.2 * doc["gap_before"]


def test_a_log_with_load_steps_is_judged_per_operating_point():
    """A log stepping between two loads (0.8 <-> 0.45 every 30 cycles): healthy, nothing is named; with a TDC offset
    it is named, and what a found model leaves is measured within each point (pooled over both, the between-point
    spread read as noise and the gap left after a found effect read 0)."""
    spec = load_engine(ENGINE)
    rpm, n = 2400.0, 150
    steps = [(120.0 / rpm * k, 0.45 if (k // 30) % 2 else 0.8) for k in range(30, n + 30, 30)]
    found, runs = {}, {}
    for label, effects in (("healthy", []), ("tdc", [make_effect("tdc_offset", {"cylinder": 2, "deg": 1.5})])):
        sim = simulate(spec, rpm, 0.8, n, 12, effects=effects, load_steps=steps)
        cycles = assembled_cycles(spec, sim.info, sim.records)[0]
        runs[label] = discover(EngineModel.from_spec(spec), cycles, OPTIONS)
        found[label] = runs[label].to_json()
    assert found["healthy"]["outcome"] == "nothing", found["healthy"]["verdict"]
    tdc = found["tdc"]
    assert [(f["effect"], f["cylinder"]) for f in tdc["found"]] == [("tdc_offset", 2)], tdc["verdict"]
    np.testing.assert_allclose(tdc["found"][0]["parameters"]["deg"], 1.5, atol=0.2)
    assert len(tdc["localisation"]["balance"].get("points", [])) == 2  # the two loads, each its own point
    assert tdc["gap_after"] <= 0.2 * tdc["gap_before"]
    # both cycles of each jump and the one after; a step within a cycle makes two jumps: at most 4 per step
    assert 0 < tdc["localisation"]["cycles_between_points"] <= 4 * len(steps)
    assert "ran at 2 operating points" in render(tdc, runs["tdc"])  # the operator's report says so


def test_a_constant_extra_friction_is_said_without_a_cylinder_and_never_named_a_worn_ring():
    """A constant 60 % extra friction in cylinder 2: a constant torque has no harmonic, so the speed cannot place it;
    the workflow says it explains the log in any one cylinder (or beside another shape as good) and adds nothing.
    At 1800 rpm seed 2 (the matrix's) it was named a worn ring in cylinder 2 (gain 2.16): the shape that explains the
    held-out cycles never reached them (design note 39). Seed 11 at 2200 rpm 0.7: not the matrix's."""
    spec = load_engine(ENGINE)
    cycles = cycles_of(2200.0, 0.7, 11, [make_effect("extra_friction", {"cylinder": 2, "mean_frac": 0.6})])
    model = EngineModel.from_spec(spec)
    found = discover(model, cycles, OPTIONS)
    doc = found.to_json()
    assert doc["outcome"] == "ambiguous" and doc["found"] == [] and found.model == model, doc["verdict"]
    assert "extra_friction in any one of the 4 cylinders" in doc["ambiguous"]["candidates"], doc["ambiguous"]
    assert "a motored run cylinder by cylinder" in doc["verdict"]


def test_a_fit_within_the_noise_of_none_on_a_healthy_log_is_not_named(monkeypatch):
    """k9k 1800 rpm 0.7 seed 4, 84 cycles, nothing hidden (a log no matrix uses): nothing is beyond the null and the
    speed gap is within a healthy log's, and the shaft line's chain_mismatch fits the model's own error with both
    scales within 2 sigma of 1 -- named before design note 50, refused now, said why; the model stays as it was.
    Since the flywheel's inertia is a candidate (design note 109) nothing is named and the chain is no longer the
    refused fit (nothing is refused): the refusal is shown with that candidate left out of the library."""
    model, cycles = EngineModel.from_spec(load_engine(ENGINE)), cycles_of(1800.0, 0.7, 4)  # one log, run twice
    doc = discover(model, cycles, OPTIONS).to_json()
    assert doc["found"] == [] and doc["outcome"] == "nothing"
    assert doc["gap_after"] == doc["gap_before"]
    from frictionwatch.core.discrepancy import workflow
    from frictionwatch.core.discrepancy.candidates import candidate_library

    monkeypatch.setattr(workflow, "candidate_library",
                        lambda m: [c for c in candidate_library(m) if c.effect != "flywheel_inertia"])
    doc = discover(model, cycles, OPTIONS).to_json()
    assert doc["found"] == [] and doc["outcome"] == "nothing"
    assert [r["candidate"] for r in doc["refused"]] == ["chain_mismatch"]
    assert "within the noise of none" in doc["refused"][0]["reason"]
    assert doc["gap_after"] == doc["gap_before"]


def test_a_shaft_line_fit_within_its_own_model_error_on_a_healthy_log_is_not_named():
    """k9k 1800 rpm 0.6 seed 7, 84 cycles, nothing hidden (none of the logs fit.CHAIN_FLOOR was tuned on, none of the
    matrix's): order 2 is beyond the null near the shaft line's resonance, and chain_mismatch fits it at 0.9927 +-
    0.0009, 1.012 +- 0.0052 -- named before design note 53. With the shaft line's own error in the chain's sigma both
    scales are within 2 sigma of 1: refused, said why, the model as it was. Since the flywheel's inertia is a
    candidate (design note 109) it fits that order best (the same lowest mode, omega^2 ~ k / J): 1.0188 +- 0.0020,
    named, until the line's error was carried to it through the mode (fit.parameter_floor): 1.019 +- 0.018, refused
    so. Which of the two fits the line's error is not the point; that neither is named is. (CHAIN_FLOOR emptied, the
    same log names the flywheel: the test can fail.)"""
    model = EngineModel.from_spec(load_engine(ENGINE))
    doc = discover(model, cycles_of(1800.0, 0.6, 7), OPTIONS).to_json()
    assert doc["found"] == [] and doc["outcome"] != "named"
    assert [r["candidate"] for r in doc["refused"]] in (["chain_mismatch"], ["flywheel_inertia"])
    assert "the model's own error in it" in doc["refused"][0]["reason"]
    assert doc["gap_after"] == doc["gap_before"]


def _healthy_or_with(engine, rpm, load, seed, n, effects=()):
    spec = load_engine(engine)
    sim = simulate(spec, rpm, load, n, seed, effects=list(effects))
    return EngineModel.from_spec(spec), assembled_cycles(spec, sim.info, sim.records)[0]


def test_a_fit_of_the_models_own_error_on_a_quiet_healthy_log_is_not_named(monkeypatch):
    """deutz 3000 rpm 0.9 seed 5, 120 cycles, nothing hidden (design note 58's last paragraph): nothing beyond the
    null, the speed gap 0.65 of a healthy log's. With the balance's model-error floor in each feature's variance
    (FLOOR_RMS_BALANCE 0.31, design note 79) the Stribeck ring is not named: refused by the floored held-out fall
    (34.3 < 40), or with a pressure gain on cylinder 1 a rival within the floor (choice.rival; before note 76's
    load means). Without the balance's
    floor (as before note 79) the ring passes the plain held-out test (delta chi^2 ~215) at 3.4 sigma from none, so
    note 50's rule does not refuse it; with the speed's floor allowed for (choice.within_model_error) its held-out
    chi^2 falls by ~16, under min_delta_chi2: refused, said why, nothing named (design note 61). With the floored
    test off too (``floored_when_quiet=False``) the same log names the ring: the tests can fail. No number here is
    tuned (min_delta_chi2 and the healthy-gap ratio 1 are the workflow's). Since design note 109 the flywheel's
    inertia fits this log's own error before the ring; the floored test is then shown with that candidate left out."""
    from frictionwatch.core.discrepancy import features, workflow
    from frictionwatch.core.discrepancy.candidates import candidate_library

    model, cycles = _healthy_or_with("deutz-1cyl", 3000.0, 0.9, 5, 120)
    doc = discover(model, cycles, OPTIONS).to_json()
    assert doc["found"] == [] and doc["outcome"] == "nothing"
    # how "nothing" is reached depends on the balance's per-cycle load (design note 76 moved it): either the ring
    # and a gain on cylinder 1 as rivals within the floor, or the ring refused by the floored held-out fall
    # (or, since the flywheel's inertia is a candidate, design note 109: the whole crank's inertia, this one-node
    # line's, fits the model's own error best -- 0.9975 +- 0.0012 on the quiet residual, 2.0 sigma from none, before
    # fit.ONE_NODE_FLOOR -- and is refused as the model's own error; the ring is then neither held out nor refused)
    refused = [r["candidate"] for r in doc["refused"] if "model-error floor allowed for" in r["reason"]]
    own = [r["candidate"] for r in doc["refused"] if "within the noise of none" in r["reason"]]
    assert ("stribeck_ring" in doc["within_null_fits"] and len(doc["within_null_fits"]) >= 2) or \
        refused == ["stribeck_ring"] or own == ["flywheel_inertia"]
    # the floored test itself, on the fit it was written for: the ring, the flywheel's candidate left out
    monkeypatch.setattr(workflow, "candidate_library",
                        lambda m: [c for c in candidate_library(m) if c.effect != "flywheel_inertia"])
    monkeypatch.setattr(workflow, "feature_floor",
                        lambda res, scale: features.feature_floor(res, scale, rms=features.FLOOR_RMS._replace(balance=0.0)))
    doc = discover(model, cycles, OPTIONS).to_json()
    assert doc["found"] == [] and doc["outcome"] == "nothing"
    assert [r["candidate"] for r in doc["refused"]] == ["stribeck_ring"]
    refused = doc["refused"][0]
    assert "model-error floor allowed for" in refused["reason"] and refused["quiet_before"]
    assert refused["delta_chi2_heldout"] >= OPTIONS.min_delta_chi2 > refused["delta_chi2_heldout_floored"]
    plain = discover(model, cycles, Options(max_steps=2, floored_when_quiet=False)).to_json()
    assert [f["effect"] for f in plain["found"]] == ["stribeck_ring"]
