"""What a live session counts when it falls behind a looped replay, and when it is stopped mid-cycle (issue 28 items 3
and 4, design note 119).

A cold `make run` (numba compiling for ~3 minutes) printed "skipped: data_gap 3" beside the cycles it dropped while
behind: the bounded queue dropped the oldest batches of the replay, loop seam marks among them, and the cycle
assembler read each hole as a data gap of the engine. The queue now leaves a marker where it dropped, the session
restarts the assembly there (reason ``dropped_while_behind``), and the lost stretch is counted once, as dropped. A stop
while the sources still deliver cuts the cycle in progress; that is not ``log_ends_mid_cycle`` (a finite log's end
is).

The source here is the demo's first passes as the looped replay gives them (seam marks included), read as fast as the
session takes them while saying it runs in real time: the queue drops its oldest rather than let it wait. The first
result's ``on_result`` stands in for the cold compile: it holds the ingest thread until the source has given all.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from frictionwatch.drivers.errors import EndOfStream
from frictionwatch.drivers.logs.mcap_replay import McapSource
from frictionwatch.drivers.logs.recorder import Recorder
from frictionwatch.drivers.source import Source, StreamRestart
from frictionwatch.service.cmd_analyze import summary
from frictionwatch.service.live import LiveSession
from frictionwatch.service.pipeline import analyze_log, assembled_cycles, resolve_model
from frictionwatch.service.record_merge import record_key
from frictionwatch.service.stream_holes import DROPPED_WHILE_BEHIND

from tests.service.serve_helpers import DEMO

PASSES = 3  # ~12.7 s of acquisition: a hole of ~10 s holds two seams
MAX_QUEUE_S = 2.0
BATCH = 12  # records a read: ~40 ms of the demo (4 records per 10 ms), as a paced replay reads them
HOLD_AT = 16 * BATCH  # the source gives ~0.5 s, then waits for the first result


class ListSource(Source):
    """``records`` in reads of ``BATCH``; then the end (``ends``) or nothing, for ever. ``speed`` set: a real-time
    source to the session (its oldest queued batches are dropped, it never waits). ``hold_at``: nothing more from
    that record on until ``go`` is set."""

    def __init__(self, records: list, info, engine_toml: str | None, ends: bool, speed: float | None,
                 hold_at: int | None = None) -> None:
        super().__init__()
        self.records, self.info, self.engine_toml, self.ends = records, info, engine_toml, ends
        if speed is not None:
            self.speed = speed
        self.hold_at, self.go = hold_at, threading.Event()
        self.given = threading.Event()  # every record handed out
        self._i = 0

    def _read_internal(self, timeout: float | None) -> list:
        if self.hold_at is not None and self._i >= self.hold_at and not self.go.is_set():
            time.sleep(timeout or 0.0)
            return []
        if self._i >= len(self.records):
            self.given.set()
            if self.ends:
                raise EndOfStream("end of the list")
            time.sleep(timeout or 0.0)
            return []
        out = self.records[self._i: self._i + BATCH]
        self._i += BATCH
        return out


@pytest.fixture(scope="module")
def demo_passes():
    """The records of PASSES passes of the looped demo (its seam marks between them), its info and engine."""
    src = McapSource(DEMO, loop=True)
    try:
        records: list = []
        while src.passes < PASSES:
            records += src.read()
    finally:
        src.close()
    while isinstance(records[-1], StreamRestart):  # the mark opening a pass not read
        records.pop()
    return records, src.info, src.engine_toml


def test_a_stretch_dropped_while_behind_is_counted_as_dropped_not_as_a_data_gap(demo_passes, tmp_path):
    records, info, toml = demo_passes
    # the first half second of the log (~6 cycles), nothing more until the first result, then the rest as fast as
    # the session takes it
    src = ListSource(records, info, toml, ends=True, speed=1.0, hold_at=HOLD_AT)
    model = resolve_model(toml, None, DEMO.name, info)
    held = []

    def on_result(result) -> None:  # the cold compile's stand-in: the first result holds the ingest thread
        if not held:
            held.append(result.index)
            src.go.set()
            assert src.given.wait(30.0)

    recorder = Recorder(tmp_path / "rec", toml, info)
    live = LiveSession(model, info, {"log": src}, max_queue_s=MAX_QUEUE_S, warmup_s=0.0, on_result=on_result,
                       recorder=recorder)
    try:
        assert live.wait_ended(60.0)
    finally:
        live.stop()
    lag, skipped, restarts = live.lag(), live.skipped, live.restarts
    seams = sum(isinstance(r, StreamRestart) for r in records)
    assert seams == PASSES - 1
    # most of the log went while the ingest thread was held: both seams inside the hole
    assert lag.dropped_s > 2 * 4.2, lag  # a pass and its gap are 4.24 s
    assert lag.dropped_records > 0.6 * len(records)
    assert dict(skipped) == {}, skipped  # no data_gap, nor any other loss: the hole is the drop's
    assert restarts[DROPPED_WHILE_BEHIND] == 1 and restarts["loop_restart"] == 0, restarts
    results = live.results
    assert len(results) > 20  # the ~2 s left after the hole: ~25 cycles
    index = np.array([r.index for r in results])
    assert np.all(np.diff(index) >= 1)
    # the first cycle after the hole has no cycle before it (as after a seam): flagged, still analysed
    after = [r for r in results if r.index > held[0]]
    assert after and "no_previous_cycle" in after[0].flags
    assert after[0].t_start * info.tick_hz - record_key(records[0]) > 0.9 * lag.dropped_s * info.tick_hz
    # its index jumps over the cycles the engine turned in the hole (design note 124): the index the same cycle has
    # when nothing is dropped, seams included (each seam's two part cycles counted as the hole's edges count them)
    whole, _ = assembled_cycles(model, info, records)
    same = min(whole, key=lambda c: abs(c.tooth_ticks[0] - after[0].t_start * info.tick_hz))
    assert abs(same.tooth_ticks[0] - after[0].t_start * info.tick_hz) < 0.01 * info.tick_hz
    assert abs(after[0].index - same.index) <= PASSES, (after[0].index, same.index)
    (hole,) = live.analysis().holes
    assert hole["first_cycle"] == last_before(results, after[0]).index + 1 and hole["last_cycle"] == after[0].index - 1
    assert hole["cycles"] > 0.9 * hole["dropped_cycles"] > 0.9 * 2 * 40  # two whole passes and more went
    assert hole["dropped_records"] == lag.dropped_records and hole["restarted"] == "all"

    # the session's black-box recording says the hole as the live run did: no data gap, one hole, the same cycles
    (rec,) = recorder.files
    again = analyze_log(rec)
    assert dict(again.skipped) == {}, again.skipped
    assert again.restarts == {DROPPED_WHILE_BEHIND: 1}
    assert again.holes == live.analysis().holes
    assert [r.index for r in again.results] == [r.index for r in results]
    (gap,) = summary(again)["data_gaps"]
    assert gap["cause"] == DROPPED_WHILE_BEHIND and gap["after_cycle"] == hole["first_cycle"] - 1


def last_before(results, result):
    return max((r for r in results if r.index < result.index), key=lambda r: r.index)


def _cut_mid_cycle(demo_passes) -> tuple[list, object, str | None]:
    """The first pass's records up to 3/4 into its sixth cycle (540 deg: more than the 360 deg a log's tail needs to
    be counted as a cycle lost)."""
    records, info, toml = demo_passes
    one = records[: next(i for i, r in enumerate(records) if isinstance(r, StreamRestart))]
    cycles, _ = assembled_cycles(resolve_model(toml, None, DEMO.name, info), info, one)
    c = cycles[5]
    cut = c.tooth_ticks[0] + 0.75 * (c.tooth_ticks[-1] - c.tooth_ticks[0])
    return [r for r in one if record_key(r) <= cut], info, toml


@pytest.mark.parametrize("ends, lost", [(True, {"log_ends_mid_cycle": 1}), (False, {})])
def test_a_stop_cuts_the_cycle_in_progress_a_log_that_ends_loses_it(demo_passes, ends, lost):
    records, info, toml = _cut_mid_cycle(demo_passes)
    src = ListSource(records, info, toml, ends=ends, speed=None)  # waits for room: nothing dropped
    live = LiveSession(resolve_model(toml, None, DEMO.name, info), info, {"log": src})
    try:
        assert live.wait_progress("log", record_key(records[-1]), 30.0)
        assert not ends or live.wait_ended(30.0)
    finally:
        live.stop()
    assert live.cycles_ok == 5 and live.lag().dropped_records == 0
    assert dict(live.skipped) == lost


def test_the_stop_line_says_dropped_once_and_seams_apart():
    from types import SimpleNamespace

    from frictionwatch.service.serve import stop_summary

    lag = {"dropped_records": 1869, "dropped_s": 8.699, "dropped_cycles": 108.7}
    svc = SimpleNamespace(engine_id="genset-v20", cycles_ok=504, skipped={"pressure_nan": 2}, backlog=lambda: lag,
                          restarts={"loop_restart": 15, DROPPED_WHILE_BEHIND: 1})
    assert stop_summary(svc) == (
        "frictionwatch serve: stopped genset-v20: 504 cycles analysed; dropped while the analysis was behind: ~109 "
        "cycles, 8.7 s of acquisition (1869 records); skipped: pressure_nan 2; 15 loop seams of the replay "
        "(restarts, nothing lost)")
    quiet = SimpleNamespace(engine_id="e", cycles_ok=7, skipped={}, restarts={}, backlog=lambda: {"dropped_records": 0})
    assert stop_summary(quiet) == "frictionwatch serve: stopped e: 7 cycles analysed"


def test_the_stop_line_names_the_cycles_its_holes_left_out():
    from types import SimpleNamespace

    from frictionwatch.service.serve import SPANS_SAID, stop_summary

    lag = {"dropped_records": 3432, "dropped_s": 14.7, "dropped_cycles": 137.4}
    hole = lambda a, b: {"first_cycle": a, "last_cycle": b}  # noqa: E731
    svc = SimpleNamespace(engine_id="e", cycles_ok=1688, skipped={}, backlog=lambda: lag, restarts={},
                          holes=[hole(26, 33), hole(36, 45), {"first_cycle": None, "last_cycle": None},
                                 hole(416, 415), hole(500, 500)])  # a hole that left no index out; one of one cycle
    assert stop_summary(svc) == ("frictionwatch serve: stopped e: 1688 cycles analysed; dropped while the analysis "
                                 "was behind: ~137 cycles, 14.7 s of acquisition (3432 records), not numbered: "
                                 "cycles 26-33, 36-45, 500")
    svc.holes = [hole(10 * i, 10 * i + 1) for i in range(SPANS_SAID + 3)]
    assert stop_summary(svc).endswith("cycles 0-1, 10-11, 20-21, 30-31, 40-41, 50-51, 60-61, 70-71 and 3 more")


def test_an_ingest_thread_past_the_drain_counts_what_it_could_not_record(demo_passes, tmp_path, monkeypatch):
    """A stop whose drain runs out while the ingest thread is still busy (here: held in the first result's callback)
    closes the recorder; what that thread delivers afterwards is counted as not recorded, never written into the
    closed recording (before: "write to a closed Recorder" killed the thread)."""
    records, info, toml = demo_passes
    crashed = []
    monkeypatch.setattr(threading, "excepthook", lambda args: crashed.append(args.exc_value))
    src = ListSource(records, info, toml, ends=True, speed=None)
    reached, release = threading.Event(), threading.Event()

    def on_result(result) -> None:
        if not reached.is_set():
            reached.set()
            release.wait(30.0)

    live = LiveSession(resolve_model(toml, None, DEMO.name, info), info, {"log": src}, warmup_s=0.0,
                       on_result=on_result, recorder=Recorder(tmp_path / "rec", toml, info))
    assert reached.wait(600.0)  # a cold numba cache compiles the monitor first
    live.stop(timeout=0.0)  # the drain runs out at once: the ingest thread is still held
    release.set()
    for thread in live.threads:
        thread.join(30.0)
    assert crashed == []
    assert live.errors["not_recorded_after_stop"] > 0, live.errors
