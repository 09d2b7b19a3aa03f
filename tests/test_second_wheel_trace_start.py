"""bench.second_wheel_trace.records_from_cycle (``trace --start-cycle``, design note 41): the log's records from about
its N-th cycle at the nominal speed, nothing dropped after, and the cycle offset the truth is read with."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from frictionwatch.core.types import LoadSample, PressureBlock, ToothBatch

from bench.accuracy_v20_long import RPM
from bench.second_wheel_trace import records_from_cycle

TICK_HZ = 1.0e6
CYCLE_TICKS = 120.0 / RPM * TICK_HZ  # 80,000 ticks per cycle at 1,500 rpm


def _log(n_cycles: int) -> list:
    """Per cycle: a tooth batch from its start, a pressure block at 0.3 of it, a load sample at its middle."""
    out = []
    for c in range(n_cycles):
        t0 = int(1000 + c * CYCLE_TICKS)
        out.append(ToothBatch(np.arange(t0, t0 + int(CYCLE_TICKS), 1000, dtype=np.int64)))
        out.append(PressureBlock(cylinder=0, t0_ticks=t0 + int(0.3 * CYCLE_TICKS), period_ticks=10.0,
                                 values=np.zeros(4)))
        out.append(LoadSample(ticks=t0 + int(0.5 * CYCLE_TICKS), torque=1.0, power=float("nan")))
    return out


def test_starts_at_the_cycle_and_keeps_the_rest():
    log = _log(10)
    records, offset = records_from_cycle(iter(log), 4, SimpleNamespace(tick_hz=TICK_HZ))
    kept = list(records)
    assert offset == 4
    assert kept[0] is log[12]  # cycle 4's tooth batch: the first record 4 cycles after the log's first tick
    assert kept == log[12:]  # nothing dropped after it, in order


def test_past_the_end_gives_nothing():
    records, offset = records_from_cycle(iter(_log(3)), 5, SimpleNamespace(tick_hz=TICK_HZ))
    assert list(records) == [] and offset == 5
