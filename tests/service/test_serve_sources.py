"""What `serve` needs of the drivers: a replay log looped at real time whose timer never runs back, and timer
clocks per session (two engines in one process never share a board's timer unwrapping)."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.core.types import ToothBatch
from frictionwatch.drivers.can.pressure import CanSource
from frictionwatch.drivers.logs.mcap_replay import LOOP_GAP_S, McapSource
from frictionwatch.drivers.logs.mcap_schema import last_tick
from frictionwatch.drivers.serial.teeth import SerialSource
from frictionwatch.drivers.source import StreamRestart, open_source
from frictionwatch.drivers.timebase import Clocks, shared_unwrapper

from tests.service.serve_helpers import DEMO


def read_passes(src: McapSource, passes: int) -> tuple[list[list], list[StreamRestart]]:
    """The records of each pass, and the restart marks met (each the first thing a new pass gives)."""
    out: list[list] = [[]]
    marks: list[StreamRestart] = []
    while src.passes < passes:
        before = src.passes
        records = src.read(0.1)
        if src.passes != before:
            out.append([])
            assert records and isinstance(records[0], StreamRestart)
        marks += [r for r in records if isinstance(r, StreamRestart)]
        out[-1].extend(r for r in records if not isinstance(r, StreamRestart))
    return out, marks


def test_loop_replays_the_log_later_on_the_timer() -> None:
    with open_source(f"mcap:{DEMO}?loop=1") as src:
        assert isinstance(src, McapSource) and src.loop
        (first, second, _), marks = read_passes(src, 2)  # the read that starts a third pass ends the loop
        tick_hz = src.info.tick_hz
    keys = np.array([float(last_tick(r)) for r in first + second])
    assert np.all(np.diff(keys) >= 0)  # the stream's time never runs back across the seam
    assert [m.reason for m in marks] == ["loop_restart"] * 2
    assert float(last_tick(first[-1])) < marks[0].ticks < float(last_tick(second[0]))  # in place for a merge
    assert len(first) == len(second) > 100
    gap = float(last_tick(second[0])) - float(last_tick(first[-1]))
    assert gap >= LOOP_GAP_S * tick_hz  # a second of silence: the assembler does not bridge the seam
    teeth1 = [r for r in first if isinstance(r, ToothBatch)]
    teeth2 = [r for r in second if isinstance(r, ToothBatch)]
    shift = teeth2[0].ticks[0] - teeth1[0].ticks[0]
    for a, b in zip(teeth1, teeth2, strict=True):  # the same records, moved by one shift
        np.testing.assert_array_equal(b.ticks - a.ticks, shift)


def test_without_loop_the_log_ends() -> None:
    from frictionwatch.drivers.errors import EndOfStream

    with open_source(f"mcap:{DEMO}") as src:
        with pytest.raises(EndOfStream):
            while True:
                src.read(0.1)


def test_each_session_has_its_own_clocks() -> None:
    a, b = Clocks(), Clocks()
    assert a.get("daq") is a.get("daq") and a.get("daq") is not b.get("daq")
    a.get("daq").unwrap(2**32 - 10)
    a.get("daq").unwrap(5)  # wrapped once in session a
    assert b.get("daq").unwrap(5) == 5  # session b's board starts its own epoch
    assert shared_unwrapper("daq", a) is a.get("daq") and shared_unwrapper("daq") is not a.get("daq")


def test_sources_opened_by_url_join_their_session_clocks() -> None:
    clocks = Clocks()
    serial = SerialSource.from_url("loop://", {"tick_hz": "1e7"}, clocks=clocks)
    can = CanSource.from_url("virtual/fw-test-clocks", {}, clocks=clocks)
    try:
        assert serial.decoder.unwrapper is clocks.get("daq") is can.decoder.unwrapper
        other = SerialSource.from_url("loop://", {"clock": "daq"}, clocks=Clocks())
        assert other.decoder.unwrapper is not clocks.get("daq")
        other.close()
    finally:
        serial.close()
        can.close()
