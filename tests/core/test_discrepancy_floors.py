"""The speed channel's model-error floors on made-up residuals (no monitor run): the floor itself (NULL_OWN of the
order's amplitude + NULL_FLOOR of the largest) and the model error each order gets by its floor's kind (FloorRms,
design note 128). Moved from test_discrepancy_parts.py, unchanged."""

from __future__ import annotations

import dataclasses

import numpy as np
from frictionwatch.core.discrepancy.features import (
    NULL_FLOOR,
    NULL_OWN,
    RPM_PER_RAD_S,
    SMALL_ORDER,
    FloorRms,
    feature_floor,
    noise_scale,
    order_table,
    speed_floor_rpm,
    speed_model_error_rpm,
)

from tests.core.test_discrepancy_parts import made_up


def test_a_coherent_residual_within_the_model_error_floor_is_not_significant():
    """The floor (features.speed_floor_rpm): NULL_OWN x the order's measured amplitude + NULL_FLOOR x the largest.
    A residual of many sigmas but inside it is the monitor's model, not a missing effect; above it, significant."""
    m, n = 8, 400
    measured = np.full((n, m), 0.05)
    measured[:, 3] = 10.0  # the firing order dominates: 10 rad/s, the others 0.05
    floor = NULL_OWN * measured[0] + NULL_FLOOR * 10.0  # rad/s
    coherent = np.zeros(m, complex)
    coherent[3] = 0.8 * floor[3]  # tens of sigmas (noise 1/sqrt(n) per part), but inside the floor
    coherent[5] = 1.5 * floor[5]
    res = dataclasses.replace(made_up(n, m, coherent, 0.0), measured=measured)
    res = dataclasses.replace(res, harmonics=res.harmonics * 0.01 + (coherent - 0.01 * coherent)[None, :])
    table = order_table(res)
    np.testing.assert_allclose([o["floor_rpm"] for o in table], floor * RPM_PER_RAD_S, rtol=1e-12)
    assert [o["order"] for o in table if o["significant"]] == [3.0]
    without = dataclasses.replace(res, measured=None)  # no measured scale: the sigma test alone
    assert {o["order"] for o in order_table(without) if o["significant"]} == {2.0, 3.0}
    # the floors a tuning run states in their place (bench.discrepancy_null's FLOOR_RMS_SPEED, design note 122)
    np.testing.assert_allclose(speed_floor_rpm(res, null=(0.02, 0.003)),
                               (0.02 * measured[0] + 0.003 * 10.0) * RPM_PER_RAD_S, rtol=1e-12)
    np.testing.assert_allclose(feature_floor(res, noise_scale(res), rms=FloorRms(0.5, 0.5, 0.0), null=(0.02, 0.003))[:m],
                               0.5 * (0.02 * measured[0] + 0.003 * 10.0) / np.sqrt(2.0) / noise_scale(res)[:m],
                               rtol=1e-12)


def test_each_speed_orders_model_error_follows_its_own_kind_of_floor():
    """features.speed_model_error_rpm (design note 128): an order whose own measured amplitude is below SMALL_ORDER of
    the largest (its floor mostly NULL_FLOOR's share of the largest) gets FloorRms.share x its floor, the others
    FloorRms.own x theirs, whatever the other kind's rms; feature_floor carries it into Re and Im. Over two operating
    points each point's kinds: an order small at one point and large at the other gets each point's own rms, combined
    as the floors are (the cycles' shares)."""
    m, n = 8, 40
    measured = np.full((n, m), 0.05)
    measured[:, 3] = 10.0  # order 2, the firing order: the largest
    measured[:, 1] = 2.0  # order 1: a fifth of the largest, its own kind
    measured[:, 5] = 0.99 * SMALL_ORDER * 10.0  # order 3: just under a tenth, the share kind
    res = dataclasses.replace(made_up(n, m, np.zeros(m, complex), 0.0), measured=measured)
    share, own = 0.2, 1.5
    kind = np.full(m, share)
    kind[[1, 3]] = own
    floor = speed_floor_rpm(res)
    np.testing.assert_allclose(speed_model_error_rpm(res, FloorRms(share, own, 0.3)), kind * floor, rtol=1e-12)
    scale = noise_scale(res)
    per_feature = feature_floor(res, scale, FloorRms(share, own, 0.3))
    np.testing.assert_allclose(per_feature[:m] * scale[:m], kind * floor / RPM_PER_RAD_S / np.sqrt(2.0), rtol=1e-12)
    np.testing.assert_allclose(per_feature[m:2 * m] * scale[m:2 * m], per_feature[:m] * scale[:m], rtol=1e-12)
    # two points (30 and 10 cycles): order 3 rises to twice a tenth of the largest at the second
    second = measured.copy()
    second[:, 5] = 2.0
    group = np.repeat([0, 1], [30, 10])
    two = dataclasses.replace(res, measured=np.where(group[:, None] == 0, measured, second), group=group)
    floors = [speed_floor_rpm(dataclasses.replace(res, measured=x)) for x in (measured, second)]
    kinds = [kind, np.where(np.arange(m) == 5, own, kind)]
    expect = np.sqrt(0.75 * (kinds[0] * floors[0]) ** 2 + 0.25 * (kinds[1] * floors[1]) ** 2)
    np.testing.assert_allclose(speed_model_error_rpm(two, FloorRms(share, own, 0.3)), expect, rtol=1e-12)


def test_a_kinds_rms_is_the_logs_mean_unless_one_log_dominates_it_then_the_median_logs():
    """bench.discrepancy_null.kind_rms (design note 137, the rule stated before its validation run): one kind's rms
    model error is the square root of the tuning logs' mean of each log's power over its floor's, unless one log
    carries more than DOMINANT (half) of the kind's summed positive power; then of their median, so one log far above
    the others (k9k 1800 rpm order 2 on TUNE: 0.34 against <= 0.04) cannot set it alone. Figures spread over several
    logs (the small orders on TUNE) keep the mean. Logs without features of the kind (NaN) are not counted, fewer
    than MIN_LOGS such logs give no figure, a typical figure below zero (the noise's correction) reads no model
    error, and figures below zero do not count in the sum a log's share is taken of."""
    from bench.discrepancy_null import DOMINANT, MIN_LOGS, kind_rms, kind_rule, largest_share

    rng = np.random.default_rng(3)
    typical = rng.uniform(0.0005, 0.004, 10)
    dominated = np.append(typical, 0.34)  # one log carries ~0.9 of the sum
    np.testing.assert_allclose(kind_rms(dominated), np.sqrt(np.median(dominated)), rtol=1e-12)
    assert kind_rms(dominated) < np.sqrt(typical.max()) < np.sqrt(dominated.mean())  # the mean's would read ~0.18
    spread = np.append(typical, [0.067, 0.035, 0.029, 0.017])  # the largest log ~0.4 of the sum
    assert kind_rule(spread) == "mean" and kind_rule(dominated) == "median"
    np.testing.assert_allclose(kind_rms(spread), np.sqrt(np.mean(spread)), rtol=1e-12)
    # the threshold: just over half of the positive sum takes the median, just under keeps the mean
    rest = np.array([0.01, 0.02, 0.03, 0.04, -0.05])
    for over, rule in ((1.001, "median"), (0.999, "mean")):
        powers = np.append(rest, over * 0.10)  # 0.10: the positive rest's sum, so the log is ~half of the sum
        np.testing.assert_allclose(largest_share(powers), over * 0.10 / (over * 0.10 + 0.10), rtol=1e-12)
        assert kind_rule(powers) == rule == ("median" if largest_share(powers) > DOMINANT else "mean")
    np.testing.assert_allclose(kind_rms(np.append(dominated, [np.nan, np.nan])), kind_rms(dominated), rtol=1e-12)
    assert np.isnan(kind_rms(np.append(dominated[:MIN_LOGS - 1], [np.nan] * 5)))
    assert np.isfinite(kind_rms(dominated[:MIN_LOGS]))
    assert kind_rms(np.array([-0.7, -0.01, -0.002, 0.001, 0.3])) == 0.0  # dominated: the median, below zero
    assert kind_rms(np.array([-0.7, 0.001, 0.001, 0.001, 0.001])) == 0.0  # spread: the mean, below zero
