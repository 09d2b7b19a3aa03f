"""The discrepancy workflow's parts on made-up inputs (no monitor run): the gap and its noise floor, the order table,
pressure corrections, the candidate library's choices (the view and the library itself:
test_discrepancy_view.py; what is named and what is refused: test_discrepancy_choice.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from frictionwatch.core.discrepancy.candidates import candidate_library
from frictionwatch.core.discrepancy.features import (
    balance_residual,
    coherent_terms,
    gap,
    localise,
    noise_scale,
    order_table,
)
from frictionwatch.core.discrepancy.fit import parameter_sigma
from frictionwatch.core.discrepancy.residuals import ANGLE_POINTS, Residuals, operating_groups
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel


def made_up(n: int, m: int, coherent: np.ndarray, balance_mean: float, seed: int = 0) -> Residuals:
    rng = np.random.default_rng(seed)
    harm = coherent[None, :] + (rng.standard_normal((n, m)) + 1j * rng.standard_normal((n, m))) / np.sqrt(2)
    return Residuals(index=np.arange(n), omega=np.full(n, 200.0), load=np.full(n, 50.0), harmonics=harm,
                     balance=balance_mean + rng.standard_normal(n), speed=np.zeros((n, ANGLE_POINTS)),
                     angles=np.linspace(0, 4 * np.pi, ANGLE_POINTS, endpoint=False))


def test_gap_is_the_coherent_part_in_noise_units():
    m, n = 8, 4000
    noise = made_up(n, m, np.zeros(m), 0.0)
    scale = noise_scale(noise)
    expected = np.r_[np.full(2 * m, np.sqrt(0.5)), 1.0]  # Re and Im of unit complex noise, the balance's unit noise
    np.testing.assert_allclose(scale, expected, rtol=0.08)
    assert gap(noise, scale) < 0.2  # noise alone: the floor is removed (sqrt of ~ sqrt(2F/N) fluctuations)
    coherent = np.zeros(m, complex)
    coherent[3] = 2.0 + 1.0j  # order 2: (4 + 1) / 0.5 in noise variances of its Re and Im, the balance 3^2 / 1
    with_signal = made_up(n, m, coherent, 3.0, seed=1)
    np.testing.assert_allclose(gap(with_signal, expected), np.sqrt(10.0 + 9.0), rtol=0.05)


def test_order_table_flags_the_coherent_order_only():
    m = 10
    coherent = np.zeros(m, complex)
    coherent[0] = 0.5j  # order 0.5, a half order
    table = order_table(made_up(400, m, coherent, 0.0, seed=2))
    assert [o["order"] for o in table if o["significant"]] == [0.5]
    assert table[0]["half_order"] and not table[1]["half_order"]
    np.testing.assert_allclose(table[0]["amplitude_rpm"], 0.5 * 30 / np.pi, rtol=0.15)


def test_localise_reports_the_balance_and_no_trend_at_one_point():
    spec = load_engine("k9k-4cyl")
    res = made_up(200, 6, np.zeros(6), 4.0, seed=3)
    loc = localise(res, spec, noise_scale(res))
    np.testing.assert_allclose(loc["balance"]["mean_nm"], 4.0, atol=0.3)
    assert loc["balance"]["significant"]
    assert loc["trends"] == {"speed": None, "load": None}
    assert [c["cylinder"] for c in loc["cylinders"]] == [1, 2, 3, 4]


def test_the_pressures_tdc_reading_proposes_tdc_candidates():
    """pressure_seeds: every cylinder read 1.5 deg late -> the whole wheel at their median; one cylinder off -> that
    cylinder alone; readings within their noise propose nothing."""
    import dataclasses

    from frictionwatch.core.discrepancy.pressure_channel import pressure_seeds

    base = made_up(10, 4, np.zeros(4, complex), 0.0)
    sigma = np.full(4, 0.19)
    wheel = dataclasses.replace(base, tdc_deg=np.array([1.45, 1.50, 1.51, 1.47]), tdc_sigma_deg=sigma)
    assert pressure_seeds(wheel) == pytest.approx({"tdc_offset[cyl 0]": 1.485})
    one = dataclasses.replace(base, tdc_deg=np.array([-0.05, 1.50, 0.01, -0.04]), tdc_sigma_deg=sigma)
    assert pressure_seeds(one) == pytest.approx({"tdc_offset[cyl 2]": 1.50})
    quiet = dataclasses.replace(base, tdc_deg=np.array([-0.06, -0.02, 0.0, 0.3]), tdc_sigma_deg=sigma)
    assert pressure_seeds(quiet) == {}
    assert pressure_seeds(base) == {}  # no reading at all


def test_a_found_parameters_sigma_carries_the_model_error_floor_that_more_cycles_do_not_average():
    """A linear model of two parameters fitted by least squares on N cycles of F whitened features, each cycle with
    unit noise and every cycle with the same coherent error drawn at the floor's size: the spread of the fitted
    parameters over many draws is what parameter_sigma states (Monte Carlo, 4000 draws: rtol 0.08), at 20 and at 200
    cycles (the floor's part does not shrink); with a zero floor it is the classical (J'J)^-1 sigma."""
    rng = np.random.default_rng(7)
    f, p = 12, 2
    per_cycle = rng.standard_normal((f, p))
    floor = np.linspace(0.2, 1.5, f)
    for n in (20, 200):
        jac = np.tile(per_cycle, (n, 1)) * (1.0 + 0.1 * rng.standard_normal((n * f, 1)))
        a = np.linalg.pinv(jac.T @ jac) @ jac.T
        coherent = rng.standard_normal((4000, f)) * floor
        noise = rng.standard_normal((4000, n * f))
        fitted = (np.tile(coherent, (1, n)) + noise) @ a.T
        stated = parameter_sigma(jac, n, cost=float(n * f - p), floor=floor)
        np.testing.assert_allclose(fitted.std(axis=0), stated, rtol=0.08)
        np.testing.assert_allclose(parameter_sigma(jac, n, float(n * f - p), np.zeros(f)),
                                   np.sqrt(np.diag(np.linalg.inv(jac.T @ jac))), rtol=1e-4)
    assert stated.min() > 2.0 * np.sqrt(np.diag(np.linalg.inv(jac.T @ jac))).max()  # the floor dominates at 200


def test_a_parameter_fitted_over_several_points_carries_each_points_own_model_error():
    """Two operating points, 60 cycles each, a linear one-parameter model whose sensitivity turns between them (at the
    second point -0.8 of the first's, plus its own part); each point's coherent error drawn at its own floor, apart
    from the other's. The spread of the fitted parameter over 4000 draws is what parameter_sigma states with the
    points (rtol 0.08); one error shared by every cycle (no points, the floors' rms) states less than half of it --
    the sensitivities cancel in the sum (design note 65)."""
    rng = np.random.default_rng(11)
    f, n = 8, 60
    j1 = rng.standard_normal(f)
    j2 = -0.8 * j1 + 0.3 * rng.standard_normal(f)
    jac = np.concatenate([np.tile(j1, n), np.tile(j2, n)])[:, None]
    floors = (np.full(f, 0.9), np.full(f, 0.5))
    rows = (np.arange(2 * n) < n, np.arange(2 * n) >= n)
    a = (np.linalg.pinv(jac.T @ jac) @ jac.T)[0]
    e1, e2 = rng.standard_normal((4000, f)) * floors[0], rng.standard_normal((4000, f)) * floors[1]
    fitted = (np.concatenate([np.tile(e1, (1, n)), np.tile(e2, (1, n))], axis=1)
              + rng.standard_normal((4000, 2 * n * f))) @ a
    stated = parameter_sigma(jac, 2 * n, float(2 * n * f - 1), np.zeros(f), points=list(zip(rows, floors)))
    np.testing.assert_allclose(stated, fitted.std(), rtol=0.08)
    shared = parameter_sigma(jac, 2 * n, float(2 * n * f - 1), np.sqrt((floors[0] ** 2 + floors[1] ** 2) / 2.0))
    assert shared[0] < 0.5 * fitted.std()


def test_what_a_fit_leaves_coherent_counts_as_model_error_in_its_parameters_sigma():
    """The coherent residual after a fit (the same in every cycle, here 0.7 in every feature on top of unit noise)
    enters a found parameter's sigma as a floor of its own size would (rtol 0.05: the noise correction of the
    residual's coherent power is itself noisy)."""
    rng = np.random.default_rng(3)
    n, f, p = 400, 10, 1
    jac = np.tile(rng.standard_normal((f, p)), (n, 1))
    residual = (0.7 + rng.standard_normal((n, f))).ravel()
    np.testing.assert_allclose(parameter_sigma(jac, n, float(n * f), np.zeros(f), residual),
                               parameter_sigma(jac, n, float(n * f), np.full(f, 0.7)), rtol=0.05)


def test_nothing_found_at_one_operating_point_says_what_that_cannot_show():
    """A log at one operating point (one group of residuals.operating_groups, localise's ``operating_points``) cannot
    show a friction law that differs from the model's only elsewhere: 'nothing' and an ambiguity say so (the
    sentence words.ONE_POINT, which the bench judges a one-point friction-law row by), whatever the trends' slopes (a
    steady log's scatter always gives one: design note 58); a log at two points does not get the sentence."""
    from frictionwatch.core.discrepancy.discovery import Discovery
    from frictionwatch.core.discrepancy.words import ONE_POINT

    model = EngineModel.from_spec(load_engine("k9k-4cyl"))
    final = {"significant_orders": [], "balance": {"significant": False, "mean_nm": 0.0}, "orders": []}
    trends = {"speed": {"unit": "rpm"}, "load": {"unit": "N m"}}

    def found(points: int, ambiguous: dict | None = None) -> Discovery:
        return Discovery(model, model, [], 0.7, 0.7, {"trends": trends, "operating_points": points}, final,
                         ambiguous=ambiguous)

    steady = found(1)
    assert steady.outcome == "nothing" and steady.one_operating_point
    assert ONE_POINT in steady.verdict() and steady.to_json()["one_operating_point"] is True
    assert "a run across speeds and loads would separate the friction laws" in ONE_POINT
    torn = found(1, {"candidates": ["stribeck_ring", "pressure_gain[cyl 1]"], "separated_by": []})
    assert torn.outcome == "ambiguous" and ONE_POINT in torn.verdict()
    two = found(2)
    assert not two.one_operating_point and "one steady speed" not in two.verdict()
    # two points of one speed (load steps on the grid): the speed laws cannot show, said (words.ONE_SPEED)
    from frictionwatch.core.discrepancy.words import ONE_SPEED

    def at(rpms: list[float]) -> Discovery:
        points = [{"rpm": r, "load_nm": 100.0, "mean_nm": 0.0, "share": 0.5} for r in rpms]
        return Discovery(model, model, [], 0.7, 0.7, {"operating_points": 2, "balance": {"points": points}}, final)

    assert at([1500.0, 1502.0]).one_speed and ONE_SPEED in at([1500.0, 1502.0]).verdict()
    assert not at([1500.0, 1800.0]).one_speed and ONE_SPEED not in at([1500.0, 1800.0]).verdict()


def test_a_tdc_pair_tried_and_not_taken_is_said_in_the_verdict():
    """Where the pair of a TDC the pressure read and a friction beside it was tried and not added (pair.py), the
    verdict says what was tried and why not (it was in the JSON only: an operator reading the sentence saw a friction
    named alone with no word of the TDC the pressure read in its cylinder)."""
    from frictionwatch.core.discrepancy.discovery import Discovery

    model = EngineModel.from_spec(load_engine("k9k-4cyl"))
    final = {"significant_orders": [], "balance": {"significant": False, "mean_nm": 0.0}, "orders": []}
    why = ("tdc_offset[cyl 2] as the pressure reads it (+1.21 +- 0.70 deg) with a friction beside it: each alone "
           "leaves nothing beyond the model's own error")
    tried = Discovery(model, model, [], 0.7, 0.7, {"operating_points": 2}, final, pair_not_taken=why)
    assert f"tried and not added: {why}" in tried.verdict()
    assert "tried and not added" not in Discovery(model, model, [], 0.7, 0.7, {"operating_points": 2}, final).verdict()


def test_operating_points_are_grouped_at_jumps_of_load_or_speed_not_along_a_ramp():
    rng = np.random.default_rng(3)
    load = np.r_[np.full(50, 137.0), np.full(50, 80.0), np.full(40, 137.0)] + 0.5 * rng.standard_normal(140)
    omega = np.full(140, 230.0) + 0.3 * rng.standard_normal(140)
    groups = operating_groups(omega, load, 160.0)
    steps = np.r_[49:52, 99:102]  # the cycles either side of a step, and the one after those: between points
    assert np.all(groups[steps] == -1) and np.sum(groups == -1) == steps.size
    assert np.unique(groups[groups >= 0]).size == 2
    assert np.all(groups[:49] == groups[102:][0]) and np.all(groups[52:99] != groups[0])
    ramp = np.linspace(80.0, 137.0, 140)  # a slow ramp has no jump: one point, as a steady log
    assert np.unique(operating_groups(omega, ramp, 130.0)).size == 1
    omega2 = np.r_[np.full(70, 230.0), np.full(70, 240.0)]  # 4 % apart in speed at one load
    assert np.unique(operating_groups(omega2, np.full(140, 100.0), 120.0)).size == 2  # no -1: a speed change is none
    unknown = operating_groups(omega, np.r_[np.nan, load[1:]], 160.0)  # a cycle without a load reading: alone
    assert unknown[0] == -1 and unknown[1] == -1  # a jump from 0 to the load: the cycle and the next set aside
    idle = 0.8 * rng.standard_normal(140)  # zero load, its reading's noise: one point (the step is the friction's)
    assert np.unique(operating_groups(omega, idle, 20.0)).size == 1
    noisy = np.r_[np.full(70, 120.0), np.full(70, 132.0)] + 4.0 * rng.standard_normal(140)  # 10 % step, 3 % noise
    assert np.unique(operating_groups(omega, noisy, 150.0)).size == 1


def test_a_residual_that_turns_sign_between_loads_is_coherent_per_point_not_noise():
    """A friction law the model has wrong can read +a at one load and -a at another: pooled, its mean is 0 and the
    spread reads as noise (the gap of a log with load steps read 0); per operating point it is a^2 each."""
    m, n = 6, 2000
    coherent = np.zeros(m, complex)
    coherent[1] = 1.5
    plus, minus = made_up(n, m, coherent, 2.0, seed=4), made_up(n, m, -coherent, -2.0, seed=5)
    both = Residuals(index=np.arange(2 * n), omega=np.full(2 * n, 200.0), load=np.r_[np.full(n, 80.0), np.full(n, 40.0)],
                     harmonics=np.r_[plus.harmonics, minus.harmonics], balance=np.r_[plus.balance, minus.balance],
                     speed=np.zeros((2 * n, ANGLE_POINTS)), angles=plus.angles)
    pooled = dataclasses.replace(both, group=None)
    grouped = dataclasses.replace(both, group=operating_groups(both.omega, both.load, 80.0))
    unit = np.r_[np.full(2 * m, np.sqrt(0.5)), 1.0]
    np.testing.assert_allclose(noise_scale(grouped), unit, rtol=0.1)  # the scatter within each point
    assert noise_scale(pooled)[2 * m] > 1.8  # pooled, the +-2 N m between the points reads as noise
    assert gap(pooled, unit) < 0.3
    np.testing.assert_allclose(gap(grouped, unit), np.sqrt(1.5**2 / 0.5 + 2.0**2), rtol=0.05)
    bal = balance_residual(grouped)
    assert abs(bal["mean_nm"]) < 0.1 and bal["significant"]  # the mean cancels, each point's does not
    np.testing.assert_allclose([p["mean_nm"] for p in bal["points"]], [-2.0, 2.0], atol=0.1)  # ordered by load
    row = order_table(grouped)[1]
    assert row["significant"] and not order_table(pooled)[1]["significant"]
    np.testing.assert_allclose(row["amplitude_rpm"], 1.5 * 30 / np.pi, rtol=0.05)


def test_a_torque_balance_residual_alone_is_said_in_friction_and_in_the_readings_it_could_be():
    """A constant extra torque has no harmonic: with nothing in the speed, the verdict says how much friction it is
    (N m, % of the model's, FMEP) and which readings off by how much would read the same (genset-v20 with a 60 %
    extra friction in one cylinder read 'torque balance +55.1 N m' and nothing more)."""
    from frictionwatch.core.discrepancy.discovery import Discovery

    model = EngineModel.from_spec(load_engine("genset-v20"))
    final = {"significant_orders": [], "half_order_share": 0.0, "orders": [], "angle": {"peak_deg": 0.0},
             "cylinders": [{"cylinder": 1, "relative": 1.0}], "channels": {}, "load_nm": 9000.0,
             "balance": {"significant": True, "mean_nm": 55.0},
             "friction": {"mean_nm": 1655.0, "fmep_bar": 1.97, "sigma_nm": 2.0, "fmep_sigma_bar": 0.002}}
    found = Discovery(model, model, [], 0.8, 0.8, {"trends": {"speed": None, "load": None}}, final)
    assert found.outcome == "unexplained"
    text = found.verdict()
    assert "55 N m above the model's (+3.4 %, FMEP +0.065 bar)" in text, text
    assert "cannot place in a cylinder" in text and "load reading 0.61 % low" in text
    assert "indicated work 0.52 % high" in text and "motored run" in text


def test_two_explanations_are_compared_with_the_model_error_floor_in_each_features_variance():
    """A difference between two candidates that lies inside the model's own error (a floor that does not average
    away with more cycles) is no evidence for either: the floored chi^2 weighs a feature by 1 / (1 + N floor^2)
    (deutz-1cyl: a half-order load ripple was named a cam-order friction, 550 better in the plain chi^2 through
    orders where the engine's model error sits; now the two are said ambiguous)."""
    from frictionwatch.core.discrepancy.choice import chi2 as _chi2
    from frictionwatch.core.discrepancy.choice import chi2_floored

    m, n = 6, 400
    coherent = np.zeros(m, complex)
    coherent[2] = 0.5
    res = made_up(n, m, coherent, 0.0, seed=6)
    scale = noise_scale(res)
    floor = np.zeros(2 * m + 1)
    np.testing.assert_allclose(chi2_floored(res, scale, floor), _chi2(res, scale), rtol=1e-12)
    floor[[2, m + 2]] = 0.5  # the order's Re and Im carry a model error of half the per-cycle noise
    terms = n * coherent_terms(res, scale)
    np.testing.assert_allclose(chi2_floored(res, scale, floor),
                               terms.sum() - terms[[2, m + 2]].sum() * (1 - 1 / (1 + n * 0.25)), rtol=1e-12)
    assert chi2_floored(res, scale, floor) < 0.1 * _chi2(res, scale)


def test_the_held_out_test_takes_the_best_of_each_shape_not_of_each_effect():
    """An effect's constant and its cam-order stand-in are two shapes: the cam shape, better on the window, does not
    take the constant's place in the held-out test (design note 39); a per-cylinder effect's cylinders are one."""
    from frictionwatch.core.discrepancy.choice import best_of_shapes, to_confirm
    from frictionwatch.core.discrepancy.fit import Trial

    lib = {c.label: c for c in candidate_library(EngineModel.from_spec(load_engine("k9k-4cyl")))}

    def trial(label, cost):
        return Trial(lib[label], np.zeros(1), np.zeros(1), cost, 2500.0, 1)

    trials = [trial("extra_friction[order 0.5]", 1450.0), trial("ring_wear[cyl 2]", 1560.0),
              trial("ring_wear[cyl 3]", 2300.0), trial("extra_friction[order 1.5]", 1890.0),
              trial("extra_friction", 1897.0), trial("tdc_offset[cyl 0]", 1933.0)]
    trials.sort(key=lambda t: t.cost)
    assert [t.candidate.label for t in best_of_shapes(trials, 4)] == [
        "extra_friction[order 0.5]", "ring_wear[cyl 2]", "extra_friction[order 1.5]", "extra_friction"]
    labels = [t.candidate.label for t in to_confirm(trials, 2)]
    assert labels == ["extra_friction[order 0.5]", "ring_wear[cyl 2]"]  # the stand-in has no sibling cylinder
    assert "extra_friction" in [t.candidate.label for t in to_confirm(trials, 4)]
    assert "ring_wear[cyl 3]" not in labels  # 740 worse on the window: told from cylinder 2


def test_a_shape_the_window_cannot_tell_from_the_last_one_held_out_is_held_out_too():
    """A shape within AMBIGUOUS_DCHI2 of the last one taken is held out too; one further off is not. Made-up trials
    at window costs seen on maruti 4000 <-> 1500 rpm seed 7 (main's skirt 2232.5, the branch's flywheel 2225.7;
    design note 109: what kept that log's skirt out was the screen before the refinement, choice.up_to_the_edge)."""
    from frictionwatch.core.discrepancy.choice import to_confirm
    from frictionwatch.core.discrepancy.fit import Trial

    lib = {c.label: c for c in candidate_library(EngineModel.from_spec(load_engine("maruti-3cyl")))}

    def trial(label, cost):
        return Trial(lib[label], np.zeros(1), np.zeros(1), cost, 2500.0, 1)

    trials = [trial("extra_friction[order 1.5]", 2029.8), trial("load_ripple[order 1.5]", 2196.1),
              trial("flywheel_inertia", 2225.7), trial("side_thrust_skirt", 2232.5), trial("chain_mismatch", 2257.3)]
    assert [t.candidate.label for t in to_confirm(trials, 3)] == [
        "extra_friction[order 1.5]", "load_ripple[order 1.5]", "flywheel_inertia", "side_thrust_skirt"]
    assert [t.candidate.label for t in to_confirm(trials, 2)] == [
        "extra_friction[order 1.5]", "load_ripple[order 1.5]"]  # the flywheel 29.6 behind: told apart


def test_a_refinement_whose_step_is_clipped_back_to_no_effect_moves_along_its_slope():
    """A share whose Gauss-Newton step is negative is clipped to 0, its no-effect value: that failed step gives no
    chord (it divided by 0 and fitted fraction=NaN, a ValueError); the secant steps start from the slope instead."""
    from frictionwatch.core.discrepancy.fit import Linearised, _along_main

    model = EngineModel.from_spec(load_engine("k9k-4cyl"))
    cand = next(c for c in candidate_library(model) if c.label == "stribeck_ring")

    class Linear:  # a residual linear in the fraction: r = r0 + j x, least squares at x = 0.3
        calls = 0

        def vector(self, m):
            x = next((e["fraction"] for e in m.effects if e.name == "stribeck_ring"), 0.0)
            return np.arange(1), np.array([[3.0 - 10.0 * x, 1.0]])

    r0 = np.array([3.0, 1.0])
    lin = Linearised(cand, np.arange(1), r0, np.array([[-10.0], [0.0]]), np.array([0.0]), 1.0, 10.0)
    x, cost, _ = _along_main(lin, model, Linear(), (np.zeros(1), 10.0, r0), (np.zeros(1), r0))
    np.testing.assert_allclose(x, [0.3], atol=1e-9)
    np.testing.assert_allclose(cost, 1.0, atol=1e-9)


def test_two_fits_within_the_null_are_said_and_are_no_ambiguity():
    """Where nothing in the held-out residual is beyond the null (features.beyond_null: no order above its floor, no
    balance beyond its own), two candidates that fit it equally are the model's own error: the outcome is nothing,
    the verdict says so and names neither (deutz 3000 rpm seed 2, healthy, had read "A discrepancy is found")."""
    from frictionwatch.core.discrepancy.discovery import Discovery
    from frictionwatch.core.discrepancy.features import beyond_null

    quiet = {"significant_orders": [], "balance": {"significant": False}}
    assert not beyond_null(quiet)
    assert beyond_null({**quiet, "significant_orders": [0.5]})
    assert beyond_null({**quiet, "balance": {"significant": True}})
    model = EngineModel.from_spec(load_engine("deutz-1cyl"))
    found = Discovery(model, model, [], 2.7, 2.7, {}, {},
                      within_null_fits=["extra_friction[order 0.5]", "load_ripple[order 0.5]"])
    doc = found.to_json()
    assert doc["outcome"] == "nothing" and doc["ambiguous"] is None and doc["found"] == []
    assert doc["verdict"].startswith("No significant missing effect")
    assert "extra_friction[order 0.5] and load_ripple[order 0.5] fit as well as each other, which names neither" \
        in doc["verdict"]


def test_the_pressure_names_a_tdc_offset_far_beyond_its_sigma_and_proposes_a_nearer_one():
    """pressure_findings: a cylinder read 1.5 deg late at sigma 0.2 (7.5 sigma) is named tdc_offset at its reading
    with the reading's sigma; 0.6 deg (3 sigma) is under TDC_SIGMAS: only a starting point for the speed
    (pressure_seeds); every cylinder 1.5 deg late is the whole wheel (cylinder 0) at their median; on a one-cylinder
    engine its offset is cylinder 1's; readings of a healthy log name nothing."""
    import dataclasses

    from frictionwatch.core.discrepancy.pressure_channel import TDC_SIGMAS, pressure_findings, pressure_seeds

    def tdc(res):
        return {f.label: (f.value, f.sigma) for f in pressure_findings(res) if f.effect == "tdc_offset"}

    base = made_up(10, 4, np.zeros(4, complex), 0.0)
    sigma = np.full(4, 0.2)
    one = dataclasses.replace(base, tdc_deg=np.array([-0.05, 1.50, 0.06, -0.04]), tdc_sigma_deg=sigma)
    np.testing.assert_allclose(tdc(one)["tdc_offset[cyl 2]"], (1.50, 0.2), rtol=1e-12)
    assert list(tdc(one)) == ["tdc_offset[cyl 2]"]
    near = dataclasses.replace(one, tdc_deg=np.array([-0.05, 0.60, 0.06, -0.04]))
    assert 0.6 < TDC_SIGMAS * 0.2 and tdc(near) == {}
    assert pressure_seeds(near) == pytest.approx({"tdc_offset[cyl 2]": 0.60})
    wheel = dataclasses.replace(one, tdc_deg=np.array([1.45, 1.50, 1.56, 1.47]))
    assert list(tdc(wheel)) == ["tdc_offset[cyl 0]"]
    np.testing.assert_allclose(tdc(wheel)["tdc_offset[cyl 0]"], (1.485, 0.2), rtol=1e-12)
    single = dataclasses.replace(made_up(10, 4, np.zeros(4, complex), 0.0), tdc_deg=np.array([1.44]),
                                 tdc_sigma_deg=np.array([0.21]))
    np.testing.assert_allclose(tdc(single)["tdc_offset[cyl 1]"], (1.44, 0.21), rtol=1e-12)
    healthy = dataclasses.replace(one, tdc_deg=np.array([-0.05, 0.06, 0.06, -0.004]))  # k9k 3000 rpm, seed 2
    assert tdc(healthy) == {}


def test_a_speed_gap_far_beyond_a_healthy_logs_inside_every_floor_is_a_discrepancy_said_with_its_signature():
    """features.healthy_gap: the speed gap against the rms model error at the log's amplitudes (FLOOR_RMS of each
    order's floor). A coherent residual at the firing order at 0.8 of its floor is not beyond the null (no order
    above its floor) but many times a healthy log's gap: said, with the order, its size against the normal scale
    and what would tell the model's own error from a missing effect (deutz 3000 rpm seed 2, a load ripple at order
    0.5, had read "No missing effect"); at 0.05 of its floor it is a healthy log's."""
    from frictionwatch.core.discrepancy.discovery import Discovery
    from frictionwatch.core.discrepancy.features import (
        FLOOR_RMS,
        GAP_NULL,
        NULL_FLOOR,
        NULL_OWN,
        beyond_healthy_gap,
        beyond_null,
        healthy_gap,
    )

    spec = load_engine("k9k-4cyl")
    m, n = 8, 400
    measured = np.full((n, m), 0.05)
    measured[:, 3] = 10.0  # order 2, k9k's firing order, dominates
    floor = NULL_OWN * measured[0] + NULL_FLOOR * 10.0  # rad/s
    kind = np.where(np.arange(m) == 3, FLOOR_RMS.own, FLOOR_RMS.share)  # order 2's floor is its own amplitude's
    normal = np.sqrt(np.sum((kind * floor) ** 2))  # the rms healthy error, summed as the gap sums (rad/s)
    for share, beyond in ((0.8, True), (0.05, False)):
        coherent = np.zeros(m, complex)
        coherent[3] = share * floor[3]
        res = dataclasses.replace(made_up(n, m, coherent, 0.0), measured=measured)
        res = dataclasses.replace(res, harmonics=res.harmonics * 0.01 + (coherent - 0.01 * coherent)[None, :])
        scale = np.full(2 * m + 1, 0.01 / np.sqrt(2))
        hg = healthy_gap(res, scale)
        np.testing.assert_allclose(hg["ratio"], share * floor[3] / normal, rtol=0.05)
        loc = localise(res, spec, scale)
        assert not beyond_null(loc) and loc["healthy_gap"]["beyond"] == beyond == (hg["ratio"] > GAP_NULL)
        assert beyond_healthy_gap(loc) == beyond
    assert loc["healthy_gap"]["orders"] == [2.0]
    model = EngineModel.from_spec(spec)
    final = localise(dataclasses.replace(res, harmonics=res.harmonics * 0 + coherent * 16.0), spec, scale)
    assert beyond_healthy_gap(final) and final["healthy_gap"]["firing"] == [2.0]
    doc = Discovery(model, model, [], 20.0, 20.0, final, final).to_json()
    assert doc["outcome"] == "unexplained" and doc["remainder"]["engine_orders"] == [2.0]
    for words in ("engine order 2 (a firing order)", "inside the model-error floor", "a motored stretch"):
        assert words in doc["verdict"]
    amb = Discovery(model, model, [], 20.0, 20.0, final, final,
                    ambiguous={"candidates": ["load_ripple[order 2]"], "separated_by": [],
                               "inside_floor": final["healthy_gap"]}).to_json()
    assert amb["outcome"] == "ambiguous"
    assert "load_ripple[order 2] or the model's own error there explain it equally well" in amb["verdict"]
