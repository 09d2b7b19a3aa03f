"""The TDC window's fit remembered by its arguments (core/monitor/calibration/tdc_memo.py): the memo answers with
tdc_from_pressure's own numbers, any argument changed misses it, it stays within its size, and the discrepancy
workflow's runs over one log give the same residuals with it as without. One small simulated log (deutz-1cyl 1800 rpm /
0.5, 16 cycles, seed 5: test_tdc_from_pressure's, TDC 0.6 deg late, a rigid crank)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from frictionwatch.core.discrepancy.residuals import pinned_config, run_model
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.view import reference
from frictionwatch.core.monitor.calibration.tdc import local_cycles, tdc_from_pressure
from frictionwatch.core.monitor.calibration.tdc_memo import TdcFitMemo, fit_key
from frictionwatch.core.monitor.calibration.tdc_smoothing import smoothing
from numpy.testing import assert_allclose

from tests.core.test_tdc_from_pressure import sim_cycles

SPEED = 1800.0 * np.pi / 30.0


@pytest.fixture(scope="module")
def log():
    return sim_cycles("deutz-1cyl", 1800.0, 0.5, 16, 5, 0.6)


@pytest.fixture(scope="module")
def window(log):
    spec, cycles = log
    p, ang = local_cycles(cycles, 0, float(spec.firing_angles[0]))
    return spec, p, ang, smoothing(float(np.diff(ang).mean()))


def assert_same_estimate(got, want):
    """Every figure of two TdcEstimates within rtol 1e-12 (the evidence's numbers too), the words equal."""
    assert (got.method, got.n_cycles) == (want.method, want.n_cycles)
    assert_allclose([got.offset_rad, got.sigma_rad, got.pegging_pa], [want.offset_rad, want.sigma_rad, want.pegging_pa],
                    rtol=1e-12, atol=0.0)
    assert set(got.evidence) == set(want.evidence)
    for key, value in want.evidence.items():
        if isinstance(value, str):
            assert got.evidence[key] == value, key
        else:
            assert_allclose(np.asarray(got.evidence[key], dtype=np.float64), np.asarray(value, dtype=np.float64),
                            rtol=1e-12, atol=0.0, err_msg=key)


def test_the_memo_answers_with_the_fits_own_numbers(window):
    spec, p, ang, op = window
    memo = TdcFitMemo()
    want = tdc_from_pressure(p, ang, spec, SPEED, operator=op)
    first = memo.fit(p, ang, spec, SPEED, operator=op)
    assert (memo.hits, memo.misses) == (0, 1)
    again = memo.fit(p.copy(), ang.copy(), dataclasses.replace(spec), SPEED, operator=smoothing(op.step))
    assert (memo.hits, memo.misses) == (1, 1)  # equal arguments, other objects: the memo's answer
    assert_same_estimate(first, want)
    assert_same_estimate(again, want)
    again.evidence["written_by_a_caller"] = 1.0  # a caller's write stays in its own copy
    assert "written_by_a_caller" not in memo.fit(p, ang, spec, SPEED, operator=op).evidence


def test_a_changed_argument_misses_the_memo(window):
    """The pressure by one sample, the grid, the speed, the spec's geometry or combustion, the operator: each a new
    fit, whose answer is the fit's of those arguments."""
    spec, p, ang, op = window
    memo = TdcFitMemo()
    memo.fit(p, ang, spec, SPEED, operator=op)
    nudged = p.copy()
    nudged[2, 40] *= 1.0 + 1e-9
    combustion = dataclasses.replace(spec.combustion, ivc_deg=spec.combustion.ivc_deg - 1.0)
    changed = [(nudged, ang, spec, SPEED, op), (p, ang + 1e-6, spec, SPEED, op), (p, ang, spec, SPEED * 1.01, op),
               (p, ang, dataclasses.replace(spec, bore=spec.bore * 1.001), SPEED, op),
               (p, ang, dataclasses.replace(spec, combustion=combustion), SPEED, op), (p, ang, spec, SPEED, None)]
    keys = {fit_key(*args) for args in changed} | {fit_key(p, ang, spec, SPEED, op)}
    assert len(keys) == len(changed) + 1
    for i, args in enumerate(changed):
        got = memo.fit(*args[:4], operator=args[4])
        assert (memo.hits, memo.misses) == (0, i + 2), i
        assert_same_estimate(got, tdc_from_pressure(*args[:4], operator=args[4]))


def test_the_memo_keeps_at_most_its_size_the_least_recently_used_dropped(window):
    spec, p, ang, op = window
    memo = TdcFitMemo(size=2)
    speeds = (SPEED, SPEED * 1.01, SPEED * 1.02)
    memo.fit(p, ang, spec, speeds[0], operator=op)
    memo.fit(p, ang, spec, speeds[1], operator=op)
    memo.fit(p, ang, spec, speeds[0], operator=op)  # used again: now the newest
    memo.fit(p, ang, spec, speeds[2], operator=op)  # the third: the least recently used (speeds[1]) dropped
    assert (memo.hits, memo.misses) == (1, 3)
    memo.fit(p, ang, spec, speeds[0], operator=op)
    assert (memo.hits, memo.misses) == (2, 3)
    memo.fit(p, ang, spec, speeds[1], operator=op)
    assert (memo.hits, memo.misses) == (2, 4)
    with pytest.raises(ValueError, match="memo of 0"):
        TdcFitMemo(size=0)


def test_the_workflows_runs_read_the_same_tdc_with_the_memo(log):
    """run_model twice over one log with one memo: the second run's fits all come from it, and both runs' TDC and
    pegging readings are those of a run without it (rtol 1e-12)."""
    spec, cycles = log
    model = EngineModel.from_spec(spec)
    ref, config = reference(cycles), pinned_config()
    want = run_model(model, ref, config, cycles)
    memo = TdcFitMemo()
    first = run_model(model, ref, config, cycles, memo)
    fitted = memo.misses
    second = run_model(model, ref, config, cycles, memo)
    assert fitted == spec.n_cyl and (memo.hits, memo.misses) == (spec.n_cyl, fitted)
    for got in (first, second):
        for field in ("tdc_deg", "tdc_sigma_deg", "pegging_pa", "pegging_sigma_pa", "balance", "harmonics"):
            assert_allclose(getattr(got, field), getattr(want, field), rtol=1e-12, atol=0.0, err_msg=field)
        assert np.all(np.isfinite(got.tdc_deg))
