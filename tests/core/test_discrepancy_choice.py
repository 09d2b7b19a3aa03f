"""The discrepancy workflow's choice of what to name, on made-up trials (no monitor run): a fit within the noise or
the model's own error of none is not named (choice.unresolved, within_model_error, quiet_residual), a friction refitted
beside a TDC against the friction alone (pair), and what the verdict says of a step that raises the plain gap (words).
Split from test_discrepancy_parts.py, which keeps the features (gap, order table, floors, operating points)."""

from __future__ import annotations

import numpy as np
from frictionwatch.core.discrepancy.candidates import candidate_library
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel


def test_a_sensor_correction_within_what_the_pressure_methods_resolve_is_not_named():
    """unresolved: a pressure gain fitted 0.999 +- 0.0008 (deutz 3000 rpm seed 3, healthy) is within 2 x hypot(sigma,
    SensorHealthConfig.floor_gain 0.003) of none: refused, said why; 1.06 +- 0.001 is a sensor fault; a friction law
    has no such floor; a TDC of 0.05 +- 0.01 deg is within the 0.03 deg floor's 2 sigma, 1.5 deg is not. Any effect
    with every parameter within 2 sigma of none is refused too, on a quiet residual (``quiet=True``) said as the
    model's own error, on a louder one as a size not resolved from none (design note 101)."""
    from frictionwatch.core.discrepancy.candidates import candidate_library
    from frictionwatch.core.discrepancy.choice import unresolved
    from frictionwatch.core.discrepancy.fit import Trial

    lib = {c.label: c for c in candidate_library(EngineModel.from_spec(load_engine("k9k-4cyl")))}

    def trial(label, x, s):
        return Trial(lib[label], np.array([x]), np.array([s]), 0.0, 1.0, 0)

    why = unresolved(trial("pressure_gain[cyl 1]", 0.999, 0.0008))
    assert why.startswith("gain 0.999 +- 0.0008 is within 2 sigma of none")
    assert unresolved(trial("pressure_gain[cyl 1]", 1.06, 0.001)) == ""
    # no sensor floor, a residual beyond a healthy log's: within 2 sigma of none is still no name (design note 101)
    assert "not resolved from none" in unresolved(trial("stribeck_ring", 0.01, 0.5))
    assert unresolved(trial("stribeck_ring", 0.9, 0.3)) == ""
    assert unresolved(trial("tdc_offset[cyl 2]", 0.05, 0.01)) != ""
    assert unresolved(trial("tdc_offset[cyl 2]", 1.5, 0.02)) == ""
    # on a quiet residual (nothing beyond the null, the speed gap within a healthy log's) any effect whose every
    # parameter lies within 2 sigma of none is the model's own error (k9k 1800 rpm 0.6 seed 3, healthy: the chain
    # 1.0011 +- 0.0017, 1.023 +- 0.013 had been named; design note 50); one parameter resolved from none is an effect
    assert "within the noise of none" in unresolved(trial("stribeck_ring", 0.01, 0.5), quiet=True)
    chain = lib["chain_mismatch"]
    assert chain.x0 == (1.0, 1.0)
    quiet_chain = Trial(chain, np.array([1.0011, 1.023]), np.array([0.0017, 0.013]), 0.0, 1.0, 0)
    assert unresolved(quiet_chain, quiet=True).startswith("stiffness_scale 1.001 +- 0.0017, damping_scale 1.023")
    assert unresolved(quiet_chain) != ""  # the chain's sigma holds the shaft line's own error: quiet or not (below)
    assert unresolved(Trial(chain, np.array([1.0011, 1.2]), np.array([0.0017, 0.013]), 0.0, 1.0, 0), quiet=True) == ""
    assert unresolved(trial("stribeck_ring", 0.8, 0.1), quiet=True) == ""


def test_a_quiet_residual_is_nothing_beyond_the_null_and_a_speed_gap_within_a_healthy_logs():
    """choice.quiet_residual: no order and no balance beyond the null, the healthy-gap ratio <= 1."""
    from frictionwatch.core.discrepancy.choice import quiet_residual

    calm = {"significant_orders": [], "balance": {"significant": False}, "healthy_gap": {"ratio": 0.15}}
    assert quiet_residual(calm)
    assert not quiet_residual({**calm, "healthy_gap": {"ratio": 1.35}})
    assert not quiet_residual({**calm, "significant_orders": [2.0]})
    assert not quiet_residual({**calm, "balance": {"significant": True}})
    assert not quiet_residual({k: v for k, v in calm.items() if k != "healthy_gap"})


def test_a_residual_inside_the_null_is_nothing_beyond_a_floor_and_a_speed_gap_within_gap_null():
    """choice.within_null (design note 155): no order and no balance beyond the null and the speed gap not beyond
    GAP_NULL x a healthy log's (``healthy_gap["beyond"]``); wider than quiet_residual (ratio <= 1): maruti 1500/0.5
    <-> 4000/0.8 seed 17, healthy, ratio 1.91 -- not quiet, inside the null."""
    from frictionwatch.core.discrepancy.choice import quiet_residual, within_null

    calm = {"significant_orders": [], "balance": {"significant": False},
            "healthy_gap": {"ratio": 1.91, "beyond": False}}
    assert within_null(calm) and not quiet_residual(calm)
    assert within_null({**calm, "healthy_gap": {"ratio": 0.15, "beyond": False}})
    assert not within_null({**calm, "healthy_gap": {"ratio": 4.2, "beyond": True}})
    assert not within_null({**calm, "significant_orders": [0.5]})
    assert not within_null({**calm, "balance": {"significant": True}})
    assert not within_null({k: v for k, v in calm.items() if k != "healthy_gap"})


def test_a_step_on_a_quiet_residual_must_pass_the_held_out_test_with_the_model_error_floor_allowed_for():
    """choice.within_model_error: refused (a reason said) only on a quiet residual whose floored chi^2 falls by less
    than the workflow's min_delta_chi2; a loud residual or a floored fall at or above it: not refused (design note
    61; deutz 3000 rpm 0.9 seed 5's Stribeck ring fell by 16.5 floored, 215 plain)."""
    from frictionwatch.core.discrepancy.choice import within_model_error

    why = within_model_error(True, 16.5, 40.0)
    assert "16.5" in why and "model-error floor" in why and "inside the null" in why
    assert within_model_error(False, 16.5, 40.0) == ""
    assert within_model_error(True, 40.0, 40.0) == ""
    assert within_model_error(True, 116.4, 40.0) == ""


def test_a_shaft_line_fit_within_its_own_model_error_of_none_is_not_named_quiet_or_not(monkeypatch):
    """unresolved: the chain candidate's sigma holds the shaft line's own model error (fit.CHAIN_FLOOR, tuned on
    healthy logs: bench/calibrate_chain_floor.py), and a fit with both scales within 2 sigma of 1 is refused where the
    residual is not quiet too (k9k 1800 rpm 0.6 seed 7, healthy, order 2 beyond the null: 0.9927, 1.0119 named before
    design note 53); 20 % softer is an effect; with no floor (CHAIN_FLOOR 0) the rule does not reach the chain."""
    from frictionwatch.core.discrepancy import line_floor
    from frictionwatch.core.discrepancy.candidates import candidate_library
    from frictionwatch.core.discrepancy.choice import unresolved
    from frictionwatch.core.discrepancy.fit import Trial, parameter_floor

    chain = next(c for c in candidate_library(EngineModel.from_spec(load_engine("k9k-4cyl")))
                 if c.effect == "chain_mismatch")
    floor = parameter_floor(chain)
    assert np.all(floor > 0.0)
    x = np.array([0.9927, 1.0119])
    sigma = np.hypot([0.0009, 0.0052], floor)  # as fit.parameter_sigma adds it
    assert "the model's own error in it" in unresolved(Trial(chain, x, sigma, 0.0, 1.0, 0))
    assert unresolved(Trial(chain, np.array([0.8, 1.0119]), sigma, 0.0, 1.0, 0)) == ""
    monkeypatch.setattr(line_floor, "CHAIN_FLOOR", {})  # where parameter_floor reads it (fit re-exports it)
    assert unresolved(Trial(chain, x, np.array([0.0009, 0.0052]), 0.0, 1.0, 0)) == ""


def test_a_named_step_that_raises_the_plain_held_out_gap_says_so():
    """Issue 27's "never worse" read on the plain gap too (design note 65): a step accepted because its chi^2 with the
    model-error floor falls (the laws step; k9k 3000/0.9 <-> 1800/0.6 seed 2's Stribeck ring, plain gap 4.63 -> 6.19)
    says the rise in the verdict with the floored fall beside it; a step whose plain gap falls says nothing of it."""
    from types import SimpleNamespace

    from frictionwatch.core.discrepancy.words import verdict
    from frictionwatch.core.model.effects import make_effect

    ring = make_effect("stribeck_ring", {"fraction": 0.906}, {"fraction": 0.104})
    step = SimpleNamespace(effects=(ring,), effect=ring, gap_before=4.63, gap_after=6.19, floored_fall=12.5)
    d = SimpleNamespace(steps=[step], remainder=None, ambiguous=None, within_null_fits=[], one_operating_point=False,
                        one_speed=False, refused=[], step_limit_reached=False, pair_not_taken="")
    text = verdict(d)
    assert "the plain held-out gap rises 4.6 -> 6.2" in text and "falls by 12.5" in text
    d.steps = [SimpleNamespace(effects=(ring,), effect=ring, gap_before=6.19, gap_after=4.63, floored_fall=None)]
    assert "rises" not in verdict(d)


def test_a_friction_beside_a_tdc_reads_otherwise_than_alone_in_another_cylinder_or_beyond_two_of_its_sigma():
    """pair.reads_otherwise: the friction refitted beside a TDC the pressure reads under its naming threshold
    contradicts the friction alone when it sits in another cylinder or a parameter lies beyond 2 of the single's
    sigma from the single's; only then can the pair and the single be an ambiguity (design note 91). A sensor
    correction is not a friction (pair.sensor_correction). The figures: k9k 1800/0.6 s2, TDC 0.3 deg and a ring on
    2, ring_wear[2] 2.77 +- 0.053 alone and 2.48 +- 0.14 beside the TDC."""
    from frictionwatch.core.discrepancy.fit import Trial
    from frictionwatch.core.discrepancy.pair import reads_otherwise, said_alone, sensor_correction

    lib = {c.label: c for c in candidate_library(EngineModel.from_spec(load_engine("k9k-4cyl")))}

    def fitted(label, x, sigma):
        return Trial(lib[label], np.array([x]), np.array([sigma]), 0.0, 1.0, 0)

    alone = fitted("ring_wear[cyl 2]", 2.77, 0.053)
    assert reads_otherwise(alone, fitted("ring_wear[cyl 3]", 2.77, 0.053))  # another cylinder
    assert reads_otherwise(alone, fitted("ring_wear[cyl 2]", 2.48, 0.14))  # 0.29 apart, 2 sigma alone 0.106
    assert not reads_otherwise(alone, fitted("ring_wear[cyl 2]", 2.7, 0.14))  # 0.07: inside what the single claims
    assert said_alone(alone) == "ring_wear[cyl 2] alone (gain 2.77 +- 0.053)"
    assert sensor_correction(fitted("pressure_gain[cyl 3]", 1.06, 0.002)) and not sensor_correction(alone)
