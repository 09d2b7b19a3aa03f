"""The monitor's per-cycle checks have one interface (core/monitor/checks/check.py): the monitor runs the checks it is
given in order, each with its own state from the MonitorState field of its name, each seeing the identification the
one before left, their flags and result fields in the cycle's result; each check's docstring example runs."""

import doctest
from dataclasses import fields

from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.checks import check, condition, sensor_health
from frictionwatch.core.monitor.checks.check import CheckStep
from frictionwatch.core.monitor.checks.condition import ConditionCheck
from frictionwatch.core.monitor.checks.sensor_health import SensorHealthCheck, SensorHealthConfig
from frictionwatch.core.monitor.monitor import CHECKS, initial_state, process_cycle
from frictionwatch.core.monitor.state import MonitorConfig, MonitorState
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles
from numpy.testing import assert_allclose

K9K = load_engine("k9k-4cyl")


class SpyCondition:
    """The condition check, watched: what it was given (the state, the sensor check's identification) and a flag
    of its own."""

    name = "condition"

    def __init__(self):
        self.inner, self.seen = ConditionCheck(), []

    def update(self, state, inp):
        self.seen.append((state, inp.ident.smoothed_estimate.friction_torque_mean_sigma.copy()))
        step = self.inner.update(state, inp)
        return CheckStep(step.state, (*step.flags, "spy_seen"), step.ident, {**step.report})


def _cycles(n):
    sim = simulate(K9K, 1700, 1.0, n, seed=5)
    return assembled_cycles(K9K, sim.info, sim.records)[0]


def test_the_monitor_runs_its_checks_in_order_each_with_its_state_and_the_identification_before_it():
    assert [c.name for c in CHECKS] == ["sensor", "condition"]
    assert {c.name for c in CHECKS} <= {f.name for f in fields(MonitorState)}
    cfg = MonitorConfig(sensor_health=SensorHealthConfig())
    spy = SpyCondition()
    state = initial_state(K9K, cfg)
    for cyc in _cycles(6):
        before = state
        state, result = process_cycle(K9K, state, cyc, cfg, checks=(SensorHealthCheck(), spy))
        assert spy.seen[-1][0] is before.condition  # its own state from the cycle before (None on the first)
        assert "spy_seen" in result.flags and result.ring is not None and result.sensor_health is not None
        # it saw the estimate the sensor check inflated: the one the result reports
        assert_allclose(spy.seen[-1][1], result.smoothed.friction_torque_mean_sigma, rtol=1e-12)
        assert state.condition is not before.condition and state.sensor.count == (before.sensor.count + 1
                                                                                  if before.sensor else 1)
    assert spy.seen[0][0] is None


def test_without_a_check_its_fields_stay_empty_and_the_other_runs_the_same():
    cycles = _cycles(4)
    st_all, st_one = initial_state(K9K), initial_state(K9K)
    for cyc in cycles:
        st_all, r_all = process_cycle(K9K, st_all, cyc)
        st_one, r_one = process_cycle(K9K, st_one, cyc, checks=(ConditionCheck(),))
        # sensor health is off by default: the sensor check adds nothing, the condition check's figures agree
        assert r_all.flags == r_one.flags and r_one.sensor_health is None
        assert_allclose(r_all.ring.n_compression_dev, r_one.ring.n_compression_dev, rtol=1e-12)
        assert_allclose(r_all.smoothed.friction_torque_mean, r_one.smoothed.friction_torque_mean, rtol=1e-12)
    assert st_one.sensor is None and st_all.sensor is not None and st_all.sensor.count == 0


def test_each_check_s_example_runs():
    for module in (check, sensor_health, condition):
        result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
        assert result.failed == 0
    assert doctest.testmod(sensor_health).attempted >= 2 and doctest.testmod(condition).attempted >= 1
