"""The load reading is calibrated like the pressure (core.model.calibration: load_torque_sigma, load_power_sigma,
generator_efficiency): friction = indicated - load - ..., so a load read 3 % low is ~+20 % of a k9k's friction and
~+28 % of genset-v20's. A genset seldom reads shaft torque: its electrical power undercounts the shaft's by the
generator's losses (2-4 %), which no check of the speed or the pressure sees (both fits stand on the same load).

Simulated k9k-4cyl at 2000 rpm, 0.8 load, seed 11 (no tuning log of the sigmas above: those are stated from data
sheets, not fitted), the monitor run with a commissioned calibration (TDC and gain known well) and the load given as
electrical power only, 3 % under the shaft power (a generator of efficiency 0.97 the model does not state)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import as_model
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.core.types import LoadSample

from tests.sim_logs import pipeline_results

EFFICIENCY = 0.97
COMMISSIONED = Calibration(status="commissioned", tdc_wheel_sigma_deg=0.05, tdc_cylinder_sigma_deg=0.05,
                           gain_sigma=0.005, gain_common_sigma=0.01, inertia_sigma=0.02, stiffness_sigma=0.003,
                           damping_sigma=0.02, source="tests: a commissioned installation assumed")


@pytest.fixture(scope="module")
def log():
    spec = load_engine("k9k-4cyl")
    sim = simulate(spec, 2000.0, 0.8, 120, seed=11)
    truth = float(np.sum(np.mean([[c["friction_torque_mean_nm"] for c in e["cylinders"]]
                                  for e in sim.truth["cycles"][-60:]], axis=0)))
    # the generator's electrical power: the shaft's times its efficiency; no torque reading
    powered = [LoadSample(r.ticks, float("nan"), r.power * EFFICIENCY) if isinstance(r, LoadSample) else r
               for r in sim.records]
    return spec, sim, dataclasses.replace(sim, records=powered), truth


def _last(spec, sim, cal: Calibration):
    results, skipped = pipeline_results(dataclasses.replace(as_model(spec), calibration=cal), sim)
    assert not skipped
    return results[-1].smoothed


def test_an_unstated_generator_loss_is_inside_the_sigma(log):
    """Unstated efficiency: friction reads high by the generator's losses; the load's 3 % sigma covers it within 2
    sigma. Without it (the sigma the monitor had before: none) the same figure is outside 2 sigma (2.3 on this log,
    where the commissioned common gain's 1 % is most of the sigma; 22 sigma of the data's own on genset-v20)."""
    spec, _, powered, truth = log
    est = _last(spec, powered, COMMISSIONED)
    err = est.total_friction_torque - truth
    assert err / truth > 0.12  # the losses booked as friction: ~+20 %
    assert abs(err) <= 2.0 * est.total_friction_torque_sigma, (err, est.total_friction_torque_sigma)
    # each cylinder's figure carries its part of the load's error
    assert np.all(est.calibration_sigma > 0.2 * est.total_calibration_sigma / spec.n_cyl)
    blind = _last(spec, powered, dataclasses.replace(COMMISSIONED, load_power_sigma=0.0))
    assert abs(blind.total_friction_torque - truth) > 2.0 * blind.total_friction_torque_sigma
    assert math.isclose(blind.total_friction_torque, est.total_friction_torque, rel_tol=1e-9)  # the sigma, not the figure


def test_a_stated_generator_efficiency_gives_the_shaft_s_load(log):
    """The efficiency stated (the generator's data sheet): the friction is the torque-read run's, with the small
    sigma the stated efficiency leaves."""
    spec, sim, powered, truth = log
    stated = dataclasses.replace(COMMISSIONED, generator_efficiency=EFFICIENCY, load_power_sigma=0.005)
    est = _last(spec, powered, stated)
    by_torque = _last(spec, sim, COMMISSIONED)
    assert abs(est.total_friction_torque - truth) <= 0.03 * truth
    assert abs(est.total_friction_torque - truth) <= 2.0 * est.total_friction_torque_sigma
    assert math.isclose(est.total_friction_torque, by_torque.total_friction_torque, rel_tol=0.01)


def test_the_calibration_refuses_what_is_not_a_load_calibration():
    with pytest.raises(ValueError, match="generator_efficiency"):
        Calibration(generator_efficiency=0.3)
    with pytest.raises(ValueError, match="load"):
        Calibration(load_power_sigma=0.6)
    with pytest.raises(ValueError, match="load_torque_sigma"):
        Calibration(load_torque_sigma=-0.01)
    cal = Calibration()
    assert math.isclose(cal.load_variance(200.0, False), (0.005 * 200.0) ** 2, rel_tol=1e-12)
    assert math.isclose(cal.load_variance(200.0, True), (0.03 * 200.0) ** 2, rel_tol=1e-12)
    assert cal.load_variance(float("nan"), True) == 0.0
