"""Sigma that holds on data the model did not make (issue 16 item 5): a small subset of bench/mismatch_coverage.py.

The monitor is never told about the mismatch. On each log the smoothed total friction must hold the truth within
2 sigma, and the model-error floor (core.monitor.identify.estimate.ModelErrorFloor) must not inflate the sigma of a healthy
log by more than a quarter. The full table (every mismatch, four operating points) is the bench's.

These validate the floor's tuned numbers (core/monitor/tuned.json, tuned by bench/calibrate_model_error_floor.py on
other k9k points and seeds; maruti-3cyl not at all): VALIDATES lists the cases, which
tests/core/test_tuned_provenance.py checks are none of the tuning ones.
"""

import functools

import numpy as np
import pytest
from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.terms import cylinder_samples, rezeka_henein
from frictionwatch.core.model.thermo import cylinder_model
from frictionwatch.core.monitor.identify.estimate import ModelErrorFloor
from frictionwatch.core.monitor.monitor import MonitorConfig
from frictionwatch.core.plant.operating_point import cylinder_means, sized_transfers
from frictionwatch.core.tuned import MONITOR_RECORD, Case, parse_case, read_tuned
from numpy.testing import assert_allclose

from bench.mismatch_coverage import CASES, COMMISSIONED, monitor_case, simulate_case

RAW = MonitorConfig(model_error_floor=ModelErrorFloor(balance_check=False))
CYCLES = 100
MONITOR = read_tuned(MONITOR_RECORD)
K_SOFT = Case("k9k-4cyl", 1700.0, 0.69, 1, CASES["chain_k-20_c+20"])
VALIDATES = [K_SOFT, Case("maruti-3cyl", 3000.0, 0.8, 1, CASES["side_thrust_skirt"]), Case("k9k-4cyl", 1700.0, 0.69, 1)]


def test_a_friction_law_mismatch_keeps_the_mean_and_changes_the_shape():
    """sized_transfers: the moved share keeps the cylinder's mean friction at the operating point; the new term's
    torque over the cycle is another shape, not a rescaled copy of the one it replaces."""
    spec = load_engine("k9k-4cyl")
    lib = rezeka_henein(spec.friction.coefficients)
    for t in parse_effect("stribeck_ring").plant_terms(spec):
        lib = lib + t
    z, omega, load = spec.n_cyl, 1700 * np.pi / 30, 0.7
    tmodel = cylinder_model(spec)
    coef = np.zeros((z, len(lib)))
    coef[:, :6] = spec.friction.coefficients
    fuel = np.full(z, spec.combustion.fuel_mass_kg * load)
    sized = sized_transfers(spec, tmodel, omega, fuel, load, coef, (("ring_mixed", "plant_stribeck_ring", 1.0),), lib)
    assert_allclose(sized[:, 1], 0.0)  # ring_mixed moved out whole
    before = cylinder_means(spec, tmodel, omega, fuel[0], load, coef[0], library=lib)
    after = cylinder_means(spec, tmodel, omega, fuel[0], load, sized[0], library=lib)
    assert_allclose(after.friction_nm, before.friction_nm, rtol=1e-9)
    theta = np.linspace(0, 4 * np.pi, 721)[:-1]
    samples = cylinder_samples(theta, omega, 5e5 * np.exp(-(((theta + 2 * np.pi) % (4 * np.pi)) - 2 * np.pi) ** 2),
                               spec.friction_params())
    basis = lib.evaluate(samples, spec.friction_params())
    assert np.corrcoef(coef[0, 1] * basis[1], sized[0, 6] * basis[6])[0, 1] < 0.9


@functools.cache
def simulated(case: Case):
    return simulate_case(case.engine, case.rpm, case.load, case.effects, CYCLES, seed=case.seed)


@pytest.mark.parametrize("case", VALIDATES[:2], ids=str)
def test_truth_within_two_sigma_on_a_mismatch(case):
    spec, sim = simulated(case)
    row = monitor_case(spec, sim)
    err = row["estimate_nm"] - row["truth_nm"]
    assert abs(err) <= 2.0 * row["sigma_nm"], row


def test_the_floor_leaves_a_healthy_sigma_nearly_alone():
    spec, sim = simulated(VALIDATES[2])
    row, raw = monitor_case(spec, sim), monitor_case(spec, sim, RAW)
    assert abs(row["estimate_nm"] - row["truth_nm"]) <= 2.0 * row["sigma_nm"]
    assert row["sigma_nm"] <= 1.25 * raw["sigma_nm"], (row["sigma_nm"], raw["sigma_nm"])


def test_a_commissioned_installation_leans_on_the_floor_for_a_chain_mismatch():
    """Commissioned (drive-train sigma 0.3 % / 2 %), nothing but the floor's drive-train term covers a chain 20 %
    softer than the model: without it the truth lies beyond 2 sigma, with the tuned k within (held out: k was tuned
    on other k9k points and seeds, bench/calibrate_model_error_floor.py)."""
    spec, sim = simulated(K_SOFT)
    row = monitor_case(spec, sim, calibration=COMMISSIONED)
    bare = monitor_case(spec, sim, MonitorConfig(model_error_floor=ModelErrorFloor(coupling_per_misfit=0.0)),
                        calibration=COMMISSIONED)
    err = row["estimate_nm"] - row["truth_nm"]
    assert_allclose(bare["estimate_nm"], row["estimate_nm"], rtol=1e-12)  # the floor moves the sigma only
    assert abs(err) > 2.0 * bare["sigma_nm"], bare
    assert abs(err) <= 2.0 * row["sigma_nm"], row


def test_self_consistency_the_recorded_k_holds_its_hardest_tuning_log():
    """A self-consistency check, not a validation (it re-runs a tuning log on purpose): the record's k puts the log
    that set it (bench/calibrate_model_error_floor.py, named in the figure) at 2 sigma, within the rounding."""
    tuning = parse_case(MONITOR["MODEL_ERROR_COUPLING_PER_MISFIT"].figure.split("(")[1].split(", ")[0])
    assert tuning.seed not in {c.seed for c in VALIDATES}
    spec, sim = simulated(tuning)
    row = monitor_case(spec, sim, calibration=COMMISSIONED)
    ratio = abs(row["estimate_nm"] - row["truth_nm"]) / row["sigma_nm"]
    assert_allclose(ratio, 2.0, atol=0.02)
