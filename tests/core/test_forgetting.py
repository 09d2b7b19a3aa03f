"""The accumulated equations' forgetting (core.monitor.identify.identification.forgetting_factor): a window sized to the wear
time scale, never shorter than the cycle rule max(400, 100 z)."""

import math

import pytest
from frictionwatch.core.monitor.identify.identification import forgetting_factor
from frictionwatch.core.monitor.state import MonitorConfig
from numpy.testing import assert_allclose


def window(lam: float) -> float:
    return 1.0 / (1.0 - lam)


def test_default_is_four_hours_of_cycles_on_the_genset():
    period = 120.0 / 1500.0  # genset-v20 at 1500 rpm: 0.08 s a cycle
    assert_allclose(window(forgetting_factor(MonitorConfig(), 20, period)), 4 * 3600 / period, rtol=1e-9)


def test_never_shorter_than_the_cycle_rule():
    cfg = MonitorConfig(forgetting_time_s=10.0)  # 125 cycles of the genset: the rule's 2,000 win
    assert_allclose(window(forgetting_factor(cfg, 20, 0.08)), 2000.0, rtol=1e-9)
    assert_allclose(window(forgetting_factor(cfg, 1, 0.08)), 400.0, rtol=1e-9)


def test_cycle_rule_without_a_time_constant_or_a_period():
    assert_allclose(window(forgetting_factor(MonitorConfig(forgetting_time_s=None), 20, 0.08)), 2000.0, rtol=1e-9)
    assert_allclose(window(forgetting_factor(MonitorConfig(), 4, math.nan)), 400.0, rtol=1e-9)


def test_explicit_factor_wins():
    assert forgetting_factor(MonitorConfig(forgetting=0.99), 20, 0.08) == 0.99
    assert forgetting_factor(MonitorConfig(forgetting=1.0), 20, 0.08) == 1.0


@pytest.mark.parametrize("kwargs", [{"forgetting_time_s": 0.0}, {"forgetting_time_s": -5.0},
                                    {"forgetting_time_s": math.inf}, {"forgetting_time_s": "4h"},
                                    {"forgetting": 1.5}, {"forgetting": -0.1}])
def test_bad_settings_are_refused(kwargs):
    with pytest.raises(ValueError, match="forgetting"):
        MonitorConfig(**kwargs)
