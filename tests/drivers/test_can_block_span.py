"""A CAN reader that drains a long stretch of frames at once (it was starved for a moment) must not cost cycles.

The decoder joins a cylinder's continuing frames into one PressureBlock per batch. The record merge and the replay
log key a block by its last sample, so a long block held its first samples back until the teeth had gone on past
them, beyond the cycle assembler's 0.5 s pressure wait: with the whole 1.2 s session drained at once, 11 of 20 k9k
cycles were lost as 'pressure_missing' (seen live as a flaky tests/service/test_live_bad_input.py under load: 1-2
cycles). Blocks are now cut every MAX_BLOCK_S.
"""

from __future__ import annotations

import numpy as np
from frictionwatch.core.types import CamBatch, PressureBlock, ToothBatch
from frictionwatch.drivers.bridge import CAN, SERIAL
from frictionwatch.drivers.can.decoder import MAX_BLOCK_S, CanDecoder
from frictionwatch.drivers.serial.codec import CamFrame, Decoder, TeethFrame
from frictionwatch.drivers.timebase import TimerUnwrapper
from frictionwatch.service.live import record_key
from frictionwatch.service.pipeline import analyze_records

from tests.service.live_helpers import per_cycle, session


def _drained_at_once():
    """The session's records as a reader that got every CAN frame in one read would give them, in key order."""
    s = session()
    unwrapper = TimerUnwrapper()
    bus = CanDecoder(unwrapper=unwrapper, tick_hz=s.tick_hz)
    serial = Decoder(unwrapper=unwrapper)
    frames = [f for e in s.events if e.channel == SERIAL for f in serial.feed(e.payload)] + serial.flush()
    kinds = {TeethFrame: ToothBatch, CamFrame: CamBatch}
    records = [kinds[type(f)](f.ticks) for f in frames if type(f) in kinds]
    records += bus.feed([e.payload for e in s.events if e.channel == CAN]) + bus.flush()
    assert not bus.damage and not serial.damage
    return s, sorted(records, key=record_key)


def test_a_drained_batch_makes_short_blocks_with_every_sample():
    s, records = _drained_at_once()
    blocks = [r for r in records if isinstance(r, PressureBlock)]
    spans = np.array([r.values.size * r.period_ticks for r in blocks]) / s.tick_hz
    assert spans.max() <= MAX_BLOCK_S + 1e-12
    for cyl in {b.cylinder for b in blocks}:  # the cut loses and repeats nothing: one evenly sampled stream each
        mine = sorted((b for b in blocks if b.cylinder == cyl), key=lambda b: b.t0_ticks)
        t = np.concatenate([b.t0_ticks + b.period_ticks * np.arange(b.values.size) for b in mine])
        np.testing.assert_allclose(np.diff(t), mine[0].period_ticks, rtol=1e-9)
        want = np.concatenate([r.values for r in s.received if isinstance(r, PressureBlock) and r.cylinder == cyl]) \
            if any(isinstance(r, PressureBlock) for r in s.received) else None
        if want is not None:
            np.testing.assert_allclose(np.concatenate([b.values for b in mine]), want, rtol=0, atol=0)


def test_a_drained_batch_loses_no_cycle():
    s, records = _drained_at_once()
    want = analyze_records(s.spec, s.sim.info, s.received)
    got = analyze_records(s.spec, s.sim.info, records)
    assert not got.skipped and len(got.results) == len(want.results) == 20
    for g, w in zip(got.results, want.results, strict=True):
        for name, value in per_cycle(w).items():
            np.testing.assert_allclose(per_cycle(g)[name], value, rtol=1e-9, err_msg=name)


def test_a_log_with_long_pressure_records_says_why_its_cycles_are_lost(caplog):
    """An outside writer's log with one long block per cylinder: the skips are counted with their cause named."""
    s = session()
    records = [r for r in s.received if not isinstance(r, PressureBlock)]
    for cyl in sorted({r.cylinder for r in s.received if isinstance(r, PressureBlock)}):
        mine = [r for r in s.received if isinstance(r, PressureBlock) and r.cylinder == cyl]
        records.append(PressureBlock(cyl, mine[0].t0_ticks, mine[0].period_ticks,
                                     np.concatenate([b.values for b in mine])))
    got = analyze_records(s.spec, s.sim.info, sorted(records, key=record_key))
    assert got.skipped["pressure_missing"] > 0
    assert "more than the 0.50 s a cycle waits for its pressure" in caplog.text
