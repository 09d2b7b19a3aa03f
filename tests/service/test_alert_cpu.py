"""The alert engine's cheaper arithmetic (design notes 72, 73) gives what the per-cycle numpy it replaced gave: each
helper against its reference, and a whole run of the engine (a leak, a worn ring from the measured friction, a load
step) against the same engine with the references put back."""

import json
import math

import numpy as np
import pytest
from frictionwatch.core.monitor.checks.ring_condition import friction_excess, friction_excess_reference
from frictionwatch.service import alert_ring_rule, alert_rules, alerts
from frictionwatch.service.alert_baseline import BaselineLearner
from frictionwatch.service.alert_interface import (
    LeakWeights,
    leak_statistics,
    leak_statistics_reference,
    sibling_median,
)
from numpy.testing import assert_allclose

from bench.bench_alert_engine import fold, synthetic_run


def _excess_loop(t: np.ndarray, s: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """FrictionRule's per-cylinder loop as it was before design note 72."""
    exc, sig = [], []
    for k in idx:
        others = idx[idx != k]
        ref = float(np.mean(t[others]))
        exc.append(t[k] / ref - 1.0)
        sig.append(math.sqrt(s[k] ** 2 + float(np.mean(s[others] ** 2)) / others.size) / ref)
    return np.array(exc), np.array(sig)


def _excess_over_siblings_72(t: np.ndarray, s: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """FrictionRule's reduction as design note 72 left it (service/alert_rules.py at f3d3e01): the numbers the rule
    keeps now that it calls core's friction_excess unscreened."""
    n = idx.size
    cols = np.arange(n - 1)
    others = idx[cols + (cols >= np.arange(n)[:, None])]
    ref = np.add.reduce(t[others], axis=1) / (n - 1)
    sig2 = np.add.reduce(s[others] ** 2, axis=1) / (n - 1)
    tk, sk = t[idx], s[idx]
    return tk / ref - 1.0, np.sqrt(sk ** 2 + sig2 / (n - 1)) / ref


def _friction_excess_loop(t: np.ndarray, s: np.ndarray, measured: np.ndarray, *, screened: bool = True
                          ) -> tuple[np.ndarray, np.ndarray]:
    """core friction_excess's interface over the rule's old per-cylinder loop (the rule calls it unscreened)."""
    assert not screened
    idx = np.flatnonzero(measured)
    exc, sig = np.full(t.shape[0], np.nan), np.full(t.shape[0], np.nan)
    exc[idx], sig[idx] = _excess_loop(t, s, idx)
    return exc, sig


def _change_against_siblings_reference(change: np.ndarray) -> np.ndarray:
    if change.shape[-1] < 3:
        return change
    return change - np.median(change, axis=-1, keepdims=True)


@pytest.mark.parametrize("z", [3, 4, 5, 20])
def test_sibling_median_is_numpys(z):
    rng = np.random.default_rng(z)
    a = rng.standard_normal((2, 4, z))
    assert_allclose(sibling_median(a), np.median(a, axis=-1, keepdims=True), rtol=1e-15, atol=0.0)
    a[0, 1, 1], a[1, 2, 0], a[1, 3, -1] = np.nan, np.inf, -np.inf  # a row with a NaN is NaN, as np.median's
    assert_allclose(sibling_median(a), np.median(a, axis=-1, keepdims=True), rtol=1e-15, atol=0.0)
    assert np.isnan(sibling_median(a)[0, 1, 0])


def test_leak_statistics_with_the_bands_weights_are_the_references():
    rng = np.random.default_rng(72)
    learner = BaselineLearner(20)
    for i in range(60):
        learner.add(rng.standard_normal((4, 20)) * [[1e-3], [1.2e-3], [2e-3], [1e-3]], i, 9e5)
    band = learner.band(0.1)
    lw = LeakWeights.of(band)
    for var, var_ratio in ((1.0, None), (0.013, 0.02)):
        ewma = rng.standard_normal((4, 20)) * 1e-3
        new, ref = leak_statistics(ewma, band, var, var_ratio, weights=lw), leak_statistics_reference(
            ewma, band, var, var_ratio)
        for a, b in ((new.z_leak, ref.z_leak), (new.effect, ref.effect), (new.z_ratio, ref.z_ratio)):
            assert_allclose(a, b, rtol=1e-12, atol=0.0)
        assert_allclose(leak_statistics(ewma, band, var, var_ratio).z_leak, ref.z_leak, rtol=1e-12, atol=0.0)


@pytest.mark.parametrize("n", [3, 4, 7, 20])
def test_core_friction_excess_unscreened_is_the_friction_rules_own(n):
    # healthy sets against the per-cylinder loop; with NaN / inf torques and sigmas, references about zero, against
    # the rule's reduction of design note 72 (the loop would raise on a zero reference); a 1e-9 change fails
    rng = np.random.default_rng(n)
    for trial in range(60):
        healthy = trial < 20
        t = 5.0 + rng.standard_normal(24) if healthy else rng.standard_normal(24)
        s = 0.05 + 0.01 * rng.random(24)
        if not healthy and trial % 2:
            t[rng.random(24) < 0.05], t[rng.random(24) < 0.03], s[rng.random(24) < 0.05] = np.nan, np.inf, np.inf
        idx = np.sort(rng.choice(24, n, replace=False))
        measured = np.zeros(24, bool)
        measured[idx] = True
        new = [a[idx] for a in friction_excess(t, s, measured, screened=False)]
        with np.errstate(all="ignore"):
            old = _excess_loop(t, s, idx) if healthy else _excess_over_siblings_72(t, s, idx)
        for a, b in zip(new, old, strict=True):
            assert_allclose(a, b, rtol=1e-12, atol=0.0, equal_nan=True)
        if healthy:
            with pytest.raises(AssertionError):
                assert_allclose(new[0] * (1.0 + 1e-9), old[0], rtol=1e-12, atol=0.0)


def test_a_run_gives_the_same_alerts_and_statistics_as_the_references(monkeypatch):
    # genset-v20, 1,200 synthetic cycles: every cylinder's friction measured from cycle 100 with cylinder 4's rising
    # 10 % from cycle 400 (a friction ring_wear, escalated to an alarm), a leak ramping into cylinder 2 from cycle 600
    # (a blow_by), a load step at cycle 900 (a new band learnt). Every event with its message and evidence, and
    # every cycle's z_leak, effect, z_ratio, EWMA, variances, long-run factors and ring-condition figure
    run = synthetic_run("genset-v20", 1200, 72, friction=True)
    _, events, stats = fold(alerts.AlertEngine, run, True)
    kinds = {(e[0], e[3], e[4]) for e in events}
    assert {("raised", "ring_wear", "warning"), ("updated", "ring_wear", "alarm"), ("raised", "blow_by", "warning")
            } <= kinds
    # the pressure statistics by their numpy functions (not core/monitor/checks/pressure_statistics.py's kernel, design note 94),
    # those functions by the references they replaced
    monkeypatch.setattr(alerts.AlertEngine, "statistics", alerts.AlertEngine.statistics_reference)
    monkeypatch.setattr(alerts, "change_against_siblings", _change_against_siblings_reference)
    monkeypatch.setattr(alerts, "leak_statistics", lambda *a, weights=None: leak_statistics_reference(*a))
    monkeypatch.setattr(alert_rules, "friction_excess", _friction_excess_loop)
    monkeypatch.setattr(alert_ring_rule, "friction_excess", friction_excess_reference)
    _, events_ref, stats_ref = fold(alerts.AlertEngine, run, True)
    assert [e[:8] for e in events] == [e[:8] for e in events_ref]
    for e, r in zip(events, events_ref, strict=True):
        assert e[8] == r[8]  # the message: its figures to 3-4 digits
        ev, evr = json.loads(e[9]), json.loads(r[9])
        assert ev.keys() == evr.keys()
        for key in ev:
            if isinstance(ev[key], float):
                assert_allclose(ev[key], evr[key], rtol=1e-12, atol=0.0)
            else:
                assert ev[key] == evr[key]
    assert len(stats) == len(stats_ref) and sum(x is not None for x in stats) > 1000
    for x, r in zip(stats, stats_ref, strict=True):
        assert (x is None) == (r is None)
        if x is not None:
            assert_allclose(x, r, rtol=1e-12, atol=0.0, equal_nan=True)
