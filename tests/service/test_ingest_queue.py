"""The bounded reader -> ingest queue (service/ingest_queue.py): a real-time source keeps the newest and counts what it
drops, leaving one marker where its batches were (design note 119); a replay waits for room and loses nothing;
markers are never dropped."""

from __future__ import annotations

import queue
import threading

import pytest
from frictionwatch.service.ingest_queue import Dropped, IngestQueue

HZ = 1000.0  # ticks per second of these tests


def drain(q: IngestQueue) -> list:
    out = []
    while True:
        try:
            out.append(q.get(timeout=0.0))
        except queue.Empty:
            return out


def batches(items: list) -> list:
    """The data batches among drained items (not the markers)."""
    return [payload for _, payload in items if isinstance(payload, list)]


def test_realtime_keeps_the_newest_and_counts_the_dropped() -> None:
    q = IngestQueue(max_span_ticks=2.0 * HZ, tick_hz=HZ)
    for i in range(10):  # one batch of 3 records a second of acquisition, for 10 s: never more than 2 s queued
        q.put("teeth", [i] * 3, key=i * HZ, realtime=True)
        assert q.lag().queued_s <= 2.0
    items = drain(q)
    kept = [payload[0] for payload in batches(items)]
    assert kept == [7, 8, 9]  # the newest 2 s (keys 7, 8, 9 s span exactly 2 s)
    # where the seven went, one marker: the newest ticks of the first and last batch dropped, and their records
    assert items[0] == ("teeth", Dropped(0.0, 6 * HZ, 7 * 3)) and len(items) == 4
    lag = q.lag()
    assert lag.dropped_records == 7 * 3
    assert lag.dropped_s == pytest.approx(7.0)  # batches at 0..6 s dropped: 7 s of acquisition (0 -> 7)
    assert lag.last_drop_age_s is not None and lag.queued_batches == 0


def test_markers_are_never_dropped() -> None:
    q = IngestQueue(max_span_ticks=1.0 * HZ, tick_hz=HZ)
    end = object()
    q.put("a", [0], key=0.0, realtime=True)
    q.put_marker("b", end)
    for i in range(1, 6):
        q.put("a", [i], key=i * HZ, realtime=True)
    items = drain(q)
    assert ("b", end) in items and batches(items) == [[4], [5]]
    # the source's one hole, 0 .. 3 s, one marker, though another source's marker stands within it
    assert [(n, p) for n, p in items if isinstance(p, Dropped)] == [("a", Dropped(0.0, 3 * HZ, 4))]


def test_each_source_has_its_own_hole_marker() -> None:
    q = IngestQueue(max_span_ticks=1.0 * HZ, tick_hz=HZ)
    for i in range(4):  # two sources a batch each per second; the queue holds 1 s
        q.put("teeth", [i, i], key=i * HZ, realtime=True)
        q.put("bus", [i], key=i * HZ + 1, realtime=True)
    q.put("teeth", [9], key=4 * HZ, realtime=True)
    items = drain(q)
    holes = {n: p for n, p in items if isinstance(p, Dropped)}
    assert holes == {"teeth": Dropped(0.0, 2 * HZ, 6), "bus": Dropped(1.0, 2 * HZ + 1, 3)}
    # each marker before its source's kept batches, and the dropped counts the queue reports are the markers' sum
    for name, hole in holes.items():
        at = items.index((name, hole))
        assert all(n != name for n, _ in items[:at])
    assert q.lag().dropped_records == 6 + 3


def test_a_replay_waits_for_room_and_loses_nothing() -> None:
    q = IngestQueue(max_span_ticks=2.0 * HZ, tick_hz=HZ)
    done = threading.Event()

    def reader() -> None:
        for i in range(20):
            q.put("log", [i], key=i * HZ, realtime=False)
        done.set()

    threading.Thread(target=reader, daemon=True).start()
    assert not done.wait(0.3)  # blocked: 3 batches (0, 1, 2 s) fill the 2 s span
    assert q.lag().queued_s <= 2.0
    got = []
    while len(got) < 20:
        got.append(q.get(timeout=5.0)[1][0])
        assert q.lag().queued_s <= 2.0
    assert got == list(range(20)) and done.wait(5.0) and q.lag().dropped_records == 0


def test_close_releases_a_waiting_replay_and_discard_says_what_it_dropped() -> None:
    q = IngestQueue(max_span_ticks=1.0 * HZ, tick_hz=HZ)
    q.put("log", [0, 0], key=0.0, realtime=False)
    q.put("log", [1, 1], key=1.0 * HZ, realtime=False)
    t = threading.Thread(target=q.put, args=("log", [2], 2.0 * HZ, False), daemon=True)
    t.start()
    t.join(0.2)
    assert t.is_alive()
    q.close()
    t.join(5.0)
    assert not t.is_alive()
    assert q.discard() == (5, pytest.approx(2.0)) and len(q) == 0


def test_a_hole_whose_marker_was_taken_widens_without_another_until_a_batch_is_taken() -> None:
    q = IngestQueue(max_span_ticks=1.0 * HZ, tick_hz=HZ)
    for i in range(3):
        q.put("log", [i], key=i * HZ, realtime=True)
    assert q.get(timeout=0.0) == ("log", Dropped(0.0, 0.0, 1))  # the ingest thread restarts here
    for i in range(3, 5):  # still behind: batches 1 and 2 go too, the same hole
        q.put("log", [i], key=i * HZ, realtime=True)
    items = drain(q)
    assert items == [("log", [3]), ("log", [4])] and q.lag().dropped_records == 3
    # a batch of it taken (above): the next drop is a new hole, with its own marker
    for i in range(5, 8):
        q.put("log", [i], key=i * HZ, realtime=True)
    assert drain(q) == [("log", Dropped(5 * HZ, 5 * HZ, 1)), ("log", [6]), ("log", [7])]


def test_a_hold_keeps_what_the_span_would_drop_until_the_ingest_has_caught_up() -> None:
    """While held (a warm-up's wait, design note 136) a real-time source's batches beyond the span are kept; the
    release ends the hold only once the queue is back within its span, then the span bound drops again."""
    q = IngestQueue(max_span_ticks=2.0 * HZ, tick_hz=HZ)
    q.hold(max_bytes=10**6)
    for i in range(10):  # 10 s of one 3-record batch a second: the span's 2 s would have kept the newest 3 batches
        q.put("teeth", [i] * 3, key=i * HZ, realtime=True)
    lag = q.lag()
    assert lag.dropped_records == 0 and lag.holding and lag.queued_batches == 10
    assert lag.held_s == pytest.approx(9.0) and lag.held_records == 30 and lag.held_bytes == 30  # ``size``: len
    q.release()
    assert q.holding  # 9 s queued: released, but held until the ingest has caught up to within 2 s
    q.put("teeth", [10] * 3, key=10 * HZ, realtime=True)
    assert q.lag().dropped_records == 0
    got = [payload[0] for _, payload in [q.get(timeout=0.0) for _ in range(8)]]
    assert got == list(range(8)) and not q.holding  # 8 .. 10 s left: within the span, the hold is over
    q.put("teeth", [11] * 3, key=11 * HZ, realtime=True)  # the span bound again: 8 s goes
    assert q.lag().dropped_records == 3 and not q.lag().holding


def test_a_hold_past_its_bytes_drops_the_oldest_and_counts_them() -> None:
    """The hold's bound is the bytes queued (``size``): past it the oldest go, with a hole's marker, as the span's."""
    q = IngestQueue(max_span_ticks=1.0 * HZ, tick_hz=HZ, size=lambda records: 100 * len(records))
    q.hold(max_bytes=1000)
    for i in range(6):  # 300 bytes a batch: at most 3 batches (900) fit
        q.put("teeth", [i] * 3, key=i * HZ, realtime=True)
    items = drain(q)
    assert batches(items) == [[3] * 3, [4] * 3, [5] * 3]
    assert items[0] == ("teeth", Dropped(0.0, 2 * HZ, 9))
    lag = q.lag()
    assert lag.dropped_records == 9 and lag.held_bytes == 1000 - 100 and lag.held_s == pytest.approx(2.0)
    with pytest.raises(ValueError, match="bytes"):
        q.hold(0)
