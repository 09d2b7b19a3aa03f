"""ResultHistory: a run's results stay in order and bounded in memory (the newest whole, older ones slim, a live
session's oldest dropped and counted)."""

import dataclasses

import numpy as np
import pytest
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.service.pipeline import ResultHistory


def _result(i: int) -> CycleResult:
    """A stand-in result with traces (the values are what the history must not change)."""
    z, n = 2, 8
    fields = {f.name: None for f in dataclasses.fields(CycleResult)}
    fields.update(index=i, t_start=0.1 * i, flags=(), imep=np.full(z, float(i)), grid=np.arange(n, dtype=float),
                  friction_torque=np.ones(n), friction_torque_cyl_time=np.ones((z, 4)), time_angles=np.arange(4.0),
                  speed_measured=np.ones(n), speed_model=np.ones(n))
    return CycleResult(**fields)


def test_newest_results_keep_their_traces_older_ones_are_slim():
    h = ResultHistory(keep_traces=3)
    made = [_result(i) for i in range(10)]
    for r in made:
        h.append(r)
    got = h.to_list()
    assert [r.index for r in got] == list(range(10)) and h.count == 10 and h.dropped == 0
    assert all(r is m for r, m in zip(got[-3:], made[-3:]))  # whole
    for r, m in zip(got[:-3], made[:-3]):
        assert r.grid is None and r.speed_measured is None and r.friction_torque_cyl_time is None
        assert r.imep is m.imep and r.t_start == m.t_start


def test_a_bounded_history_drops_the_oldest_and_counts_them():
    h = ResultHistory(keep_traces=2, max_len=4)
    for i in range(9):
        h.append(_result(i))
    assert [r.index for r in h] == [5, 6, 7, 8] and h.dropped == 5 and h.count == 9 and len(h) == 4


def test_bad_bounds_are_refused():
    with pytest.raises(ValueError):
        ResultHistory(keep_traces=0)
    with pytest.raises(ValueError):
        ResultHistory(keep_traces=10, max_len=5)
