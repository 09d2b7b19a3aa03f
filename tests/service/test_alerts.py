"""The alert engine's decisions (service/alerts.py) on constructed per-cycle results: a leak signature raised on its
cylinder and cleared, no flapping near the threshold, a gain-only change as a sensor check (never a ring alert),
misfire and model-misfit persistence, acknowledge, rebaseline, the baseline's round trip and the contract shape."""

import json
from types import SimpleNamespace

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.checks.ring_pressure import RingIndicators
from frictionwatch.service.alert_baseline import INDICATORS, Baseline
from frictionwatch.service.alerts import RING_KINDS, AlertConfig, AlertEngine
from numpy.testing import assert_allclose

K9K = load_engine("k9k-4cyl")
SD = np.array([0.0012, 0.0013, 0.0022, 0.0012])  # per-cycle scatter of the four indicators on a healthy K9K log
CONFIG = AlertConfig(baseline_cycles=100, skip_cycles=0)


def _estimate(z):
    nan = np.full(z, np.nan)
    return SimpleNamespace(resolved=np.zeros(z, bool), data_gain=np.zeros(z), friction_torque_mean=nan,
                           friction_torque_mean_sigma=nan, prior_friction_torque_mean=np.full(z, 5.0),
                           total_friction_torque=20.0, weight=10.0, source="data", chi2_reduced=1.0)


def _result(i, rng, shift=None, flags=(), z=4, imep_pa=12e5):
    """Cycle i at mean IMEP ``imep_pa`` with indicators = noise (SD) + shift (4, z): rows compression ratio, n_c dev,
    n_e dev, deficit."""
    x = rng.standard_normal((4, z)) * SD[:, None] + (0.0 if shift is None else shift)
    ring = RingIndicators(compression_pa=np.full(z, 30e5), compression_ratio=x[0], n_compression=1.37 + x[1],
                          n_expansion=1.33 + x[2], n_compression_dev=x[1], n_expansion_dev=x[2],
                          expansion_deficit=x[3])
    est = _estimate(z)
    return SimpleNamespace(index=i, t_start=0.07 * i, flags=tuple(flags), ring=ring, cycle=est, smoothed=est,
                           imep=np.full(z, imep_pa))


def _leak(cyl, dn, z=4):
    s = np.zeros((4, z))
    s[:, cyl - 1] = [-1.5 * dn, -dn, dn, -0.5 * dn]
    return s


def _run(engine, rng, n, start, shift=None, flags=()):
    events = []
    for i in range(start, start + n):
        events += [(i, e) for e in engine.update(_result(i, rng, shift, flags))]
    return events


def test_a_leak_is_raised_on_its_cylinder_and_cleared_after_it_goes():
    rng = np.random.default_rng(1)
    eng = AlertEngine(K9K, CONFIG)
    assert _run(eng, rng, 400, 0) == []  # learning, then healthy: nothing
    assert eng.baseline is not None and eng.baseline.cycles == 100
    ev = _run(eng, rng, 200, 400, _leak(3, 0.0025))
    raised = [(i, e.alert) for i, e in ev if e.kind == "raised"]
    assert len(raised) == 1 and raised[0][1].kind == "blow_by" and raised[0][1].cylinder == 3
    # ~2 sigma per cycle: Z > 6 within a fraction of the 50-cycle window, + 10; the z's standard error holds the
    # 100-cycle band mean's too (design note 71): 45 cycles here, 40 without it
    assert raised[0][0] - 400 <= 50
    a = raised[0][1].to_dict()
    assert set(a) >= {"alert_id", "cylinder", "kind", "severity", "state", "raised_cycle", "raised_at_s",
                      "cleared_cycle", "acknowledged_by", "message", "evidence"}
    assert a["state"] == "active" and a["evidence"]["source"] == "pressure"
    assert a["evidence"]["first_evidence_cycle"] >= 400
    assert 0.0 < a["evidence"]["n_expansion_change"] < 0.0025  # the EWMA on its way when the evidence crossed
    now = eng.active()[0].evidence  # 200 cycles on: the EWMA holds the change (its noise 0.1 x SD)
    assert_allclose([now["n_compression_change"], now["n_expansion_change"]], [-0.0025, 0.0025], atol=0.0008)
    json.dumps(a)  # JSON-able as it stands
    ev = _run(eng, rng, 400, 600)  # the leak gone (a repair): cleared once, nothing else
    assert [(e.kind, e.alert.kind) for _, e in ev] == [("cleared", "blow_by")]
    assert eng.active() == [] and eng.history()[0].state == "cleared"


def test_no_flapping_while_the_evidence_hovers_between_the_levels():
    rng = np.random.default_rng(2)
    eng = AlertEngine(K9K, CONFIG)
    _run(eng, rng, 150, 0)
    # a leak whose statistic wanders between clear (3) and raise (6) and beyond: raised once, never cleared
    events = []
    for i in range(150, 1150):
        dn = 0.0025 if i < 400 else 0.0013 + 0.0004 * np.sin(i / 15.0)
        events += [e for e in eng.update(_result(i, rng, _leak(2, dn)))]
    kinds = [(e.kind, e.alert.kind, e.alert.cylinder) for e in events if e.kind != "updated"]
    assert kinds == [("raised", "blow_by", 2)]


def test_a_gain_error_is_a_sensor_check_never_a_ring_alert():
    rng = np.random.default_rng(3)
    eng = AlertEngine(K9K, CONFIG)
    _run(eng, rng, 150, 0)
    gain = np.zeros((4, 4))
    gain[0, 1] = np.log(1.03)  # only the compression ratio moves: the exponents are gain-invariant
    ev = _run(eng, rng, 300, 150, gain)
    raised = [e.alert for _, e in ev if e.kind == "raised"]
    assert [(a.kind, a.cylinder, a.severity) for a in raised] == [("sensor_fault", 2, "info")]
    assert_allclose(eng.active()[0].evidence["gain_estimate"], 1.03, atol=0.003)  # after the EWMA settled
    assert not any(a.kind in RING_KINDS for a in eng.history())


def test_misfires_and_model_misfit_need_persistence():
    rng = np.random.default_rng(4)
    eng = AlertEngine(K9K, CONFIG)
    assert _run(eng, rng, 1, 0, flags=("misfire_cyl4",)) == []  # one misfire: a flag, not an alert
    assert _run(eng, rng, 3, 1, flags=("model_misfit",)) == []  # fewer than flag_raise_cycles
    ev = _run(eng, rng, 10, 4, flags=("misfire_cyl4", "model_misfit"))
    got = sorted((e.alert.kind, e.alert.cylinder) for _, e in ev if e.kind == "raised")
    assert got == [("misfire", 4), ("model_misfit", None)]


def test_acknowledge_rebaseline_and_monotonic_ids():
    rng = np.random.default_rng(5)
    eng = AlertEngine(K9K, CONFIG)
    _run(eng, rng, 150, 0)
    _run(eng, rng, 100, 150, _leak(1, 0.004) + _leak(4, 0.004))
    act = eng.active()
    assert [a.cylinder for a in act] == [1, 4] and act[0].alert_id < act[1].alert_id
    ack = eng.acknowledge(act[0].alert_id, "operator")
    assert ack.state == "acknowledged" and ack.acknowledged_by == "operator"
    assert eng.active()[0].state == "acknowledged"
    with pytest.raises(KeyError):
        eng.acknowledge(999, "operator")
    cleared = eng.rebaseline()  # after an overhaul: the leaking state is the new normal
    assert sorted(e.alert.cylinder for e in cleared) == [1, 4] and all(e.kind == "cleared" for e in cleared)
    assert eng.baseline is None
    assert _run(eng, rng, 300, 250, _leak(1, 0.004) + _leak(4, 0.004)) == []  # relearnt on the new state
    _run(eng, rng, 100, 550, _leak(1, 0.004) + _leak(4, 0.004) + _leak(2, 0.004))
    new = eng.active()
    assert [a.cylinder for a in new] == [2] and new[0].alert_id > act[1].alert_id


def test_a_baseline_round_trip_gives_the_same_decisions():
    rng = np.random.default_rng(6)
    eng = AlertEngine(K9K, CONFIG)
    _run(eng, rng, 120, 0)
    text = json.dumps(eng.baseline.to_dict())
    back = Baseline.from_dict(json.loads(text))
    assert_allclose(back.mean, eng.baseline.mean, rtol=0, atol=0)
    assert_allclose(back.cov, eng.baseline.cov, rtol=0, atol=0)
    assert back.cycles == eng.baseline.cycles == 100
    given, original = AlertEngine(K9K, CONFIG, baseline=back), AlertEngine(K9K, CONFIG, baseline=eng.baseline)
    seq = [_result(i, rng, _leak(2, 0.003) if i >= 150 else None) for i in range(120, 300)]
    a = [(e.kind, e.alert.kind, e.alert.cylinder, e.alert.raised_cycle) for r in seq for e in original.update(r)]
    b = [(e.kind, e.alert.kind, e.alert.cylinder, e.alert.raised_cycle) for r in seq for e in given.update(r)]
    assert a == b and a
    with pytest.raises(ValueError, match="not a baseline"):
        Baseline.from_dict({"version": 1})
    with pytest.raises(ValueError, match="cylinders"):
        AlertEngine(load_engine("maruti-3cyl"), CONFIG, baseline=back)


def _load_offset(z=4):
    """What a step from 12 to 8 bar IMEP does to a healthy genset's cylinders (measured on genset-v20 0.75 -> 0.45,
    bench/alert_detection.py): persistent sibling-relative exponent shifts of ~0.002 in the leak direction on some
    cylinders, the opposite on others."""
    s = np.zeros((4, z))
    s[1], s[2] = [0.002, -0.002, 0.0005, -0.0005], [-0.002, 0.002, -0.0005, 0.0005]
    return s


def test_a_load_step_alone_raises_nothing_and_a_leak_at_constant_load_still_does():
    rng = np.random.default_rng(7)
    eng = AlertEngine(K9K, CONFIG)
    assert _run(eng, rng, 300, 0) == []  # commissioned at 12 bar
    events = []
    for i in range(300, 1500):  # steps 12 -> 8 -> 12 -> 8 bar every 300 cycles
        low = (i // 300) % 2 == 1
        events += eng.update(_result(i, rng, _load_offset() if low else None, imep_pa=8e5 if low else 12e5))
    assert events == []
    assert [round(b.imep_pa / 1e5, 1) for b in eng.baseline.bands] == [12.0, 8.0]  # the 8 bar band learnt
    # the 8 bar band learnt after the load change settled (settle_cycles 50)
    assert eng.baseline.bands[1].first_cycle == 350 and eng.baseline.bands[1].cycles == 100
    # a leak in cylinder 2 at constant load, in the band learnt after the step: raised on cylinder 2
    ev = _run_at(eng, rng, 200, 1500, _load_offset() + _leak(2, 0.0025), 8e5)
    raised = [e.alert for e in ev if e.kind == "raised"]
    assert [(a.kind, a.cylinder) for a in raised] == [("blow_by", 2)]
    assert raised[0].evidence["commissioned_at_this_load"] is True
    assert_allclose(raised[0].evidence["load_band_imep_bar"], [7.2, 8.8], atol=0.05)
    # at a load never seen the alert holds and says why; back at 8 bar the leak keeps it open
    ev = _run_at(eng, rng, 80, 1700, _leak(2, 0.0025), 5e5)
    assert ev == [] and eng.active()[0].evidence["commissioned_at_this_load"] is False
    assert eng.active()[0].evidence["suspended"] == "not commissioned at this load: learning"
    assert _run_at(eng, rng, 100, 1780, _load_offset() + _leak(2, 0.0025), 8e5) == []
    assert eng.active()[0].evidence["commissioned_at_this_load"] is True


def test_one_baseline_for_every_load_would_raise_on_the_load_step():
    """The case above with a band wide enough to hold both loads (the former single baseline): false alarms."""
    rng = np.random.default_rng(7)
    eng = AlertEngine(K9K, AlertConfig(baseline_cycles=100, skip_cycles=0, band_width=1.0))
    _run(eng, rng, 300, 0)
    ev = _run_at(eng, rng, 300, 300, _load_offset(), 8e5)
    # a ring alert on cylinder 2 (the leak rule's, or the ring condition's where it got there first: with the band
    # mean's error in the leak z, design note 71, it does here), none elsewhere
    raised = sorted((e.alert.kind, e.alert.cylinder) for e in ev if e.kind == "raised")
    assert ("blow_by", 2) in raised and {c for _, c in raised} == {2}
    assert {k for k, _ in raised} <= {"blow_by", "ring_wear"}


def test_bands_round_trip_and_a_version_1_baseline_is_read_as_valid_at_every_load():
    rng = np.random.default_rng(8)
    eng = AlertEngine(K9K, CONFIG)
    _run(eng, rng, 120, 0)
    _run_at(eng, rng, 170, 120, None, 8e5)
    assert len(eng.baseline.bands) == 2
    back = Baseline.from_dict(json.loads(json.dumps(eng.baseline.to_dict())))
    for a, b in zip(back.bands, eng.baseline.bands, strict=True):
        assert_allclose(np.concatenate([a.mean.ravel(), a.cov.ravel(), [a.imep_pa, a.imep_lo_pa, a.imep_hi_pa]]),
                        np.concatenate([b.mean.ravel(), b.cov.ravel(), [b.imep_pa, b.imep_lo_pa, b.imep_hi_pa]]),
                        rtol=0, atol=0)
        assert (a.cycles, a.first_cycle, a.last_cycle) == (b.cycles, b.first_cycle, b.last_cycle)
    band = eng.baseline.bands[0]
    v1 = {"version": 1, "n_cylinders": 4, "cycles": band.cycles, "first_cycle": band.first_cycle,
          "last_cycle": band.last_cycle, "indicators": list(INDICATORS), "mean": band.mean.tolist(),
          "cov": band.cov.tolist(), "friction_excess": [None] * 4, "friction_excess_sigma": [None] * 4,
          "friction_cycle": [-1] * 4}
    old = Baseline.from_dict(v1)
    assert old.band_for(1e5) is old.band_for(50e5) is old.bands[0]
    assert_allclose(old.mean, band.mean, rtol=0, atol=0)
    bad = eng.baseline.to_dict()
    bad["bands"][1]["imep_lo_pa"] = 2e6  # above its upper edge
    with pytest.raises(ValueError, match="not a baseline"):
        Baseline.from_dict(bad)


def _run_at(engine, rng, n, start, shift, imep_pa):
    return [e for i in range(start, start + n) for e in engine.update(_result(i, rng, shift, imep_pa=imep_pa))]


def test_one_wild_cycle_at_a_load_step_raises_nothing():
    """On genset-v20 the cycle a load step falls in read one cylinder's n_compression 0.27 off (its trace spliced
    across the step); the monitor flags it operating_point_changed, and that cycle is not used."""
    rng = np.random.default_rng(9)
    eng = AlertEngine(K9K, CONFIG)
    _run(eng, rng, 300, 0)
    wild = np.zeros((4, 4))
    wild[1, 1] = -0.27
    assert eng.update(_result(300, rng, wild, flags=("operating_point_changed",))) == []
    assert _run(eng, rng, 100, 301) == []
    assert eng.update(_result(401, rng, wild)) == []  # the same cycle unflagged: the EWMA takes it (no alert yet)
    assert [e.alert.cylinder for _, e in _run(eng, rng, 20, 402) if e.kind == "raised"] == [2]


def test_leaving_out_what_changes_nothing_gives_the_same_events():
    """The rules leave out a Decision that is not on and a Hold where the engine keeps no latch or open alert for it
    (``Context.watched``): the same events, cycle by cycle and field by field, as an engine that is handed every one
    -- over learning, a load step (the pressure statistics held), a leak raised and cleared, a flagged sensor and
    misfires."""
    def script(i):
        if i < 300:
            return None, (), 12e5
        if i < 340:
            return None, (), 9e5  # a load step: the statistics settle, then learn a new band
        if i < 700:  # a leak; a sensor flag; a load step while its alert is open (held: the alert says why)
            return _leak(2, 0.003), ("sensor_tdc_offset_cyl4",) if 500 <= i < 560 else (), \
                9e5 if 620 <= i < 650 else 12e5
        return None, ("misfire_cyl1",) if i % 3 == 0 else (), 12e5

    class _EveryCylinder:
        def __contains__(self, cylinder) -> bool:
            return True

    def run(every: bool):
        rng = np.random.default_rng(7)
        eng = AlertEngine(K9K, CONFIG)
        if every:  # every rule told that every cylinder is watched: all its decisions made and applied
            eng._watching = lambda name: _EveryCylinder()
        out = []
        for i in range(1000):
            shift, flags, imep = script(i)
            for e in eng.update(_result(i, rng, shift, flags, imep_pa=imep)):
                out.append((i, e.kind, json.dumps(e.alert.to_dict(), sort_keys=True)))
            if i == 640:  # held: the open leak alert's evidence says why
                out.append((i, "open", json.dumps([a.to_dict() for a in eng.active()], sort_keys=True)))
        return out

    sparse, every = run(False), run(True)
    assert len(sparse) >= 4, sparse  # the scenario raises and clears something
    held = [json.loads(d) for i, k, d in sparse if k == "open"][0]
    assert [a["evidence"]["suspended"] for a in held if a["kind"] == "blow_by"] == ["settling after a load change"]
    assert sparse == every
