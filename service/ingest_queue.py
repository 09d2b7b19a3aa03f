"""The queue between a live session's reader threads and its ingest thread, bounded by the acquisition time it holds.

    q = IngestQueue(max_span_ticks=10 * tick_hz, tick_hz=tick_hz)
    q.put("teeth", records, key, realtime=True)   # reader thread; key: the batch's newest tick (live.record_key)
    name, item = q.get(timeout=0.05)              # ingest thread; queue.Empty when nothing came
    q.lag()                                       # IngestLag: acquisition seconds queued, wall seconds behind

Policy (issue 28 item 3). The queue never holds more than ``max_span_ticks`` of acquisition time (newest queued
key minus oldest queued key), whatever the ingest thread's speed:

- a real-time source (a serial board, a CAN bus, a replay paced by the wall clock) cannot be asked to wait — its
  bytes would pile up in the OS or be lost unseen — so its batch is queued and the *oldest* queued batches are
  dropped until the span fits again: the newest data are kept, and what is dropped is counted (records and
  acquisition seconds) and logged (the first time, then at most once a minute). Where batches were dropped a
  ``Dropped`` marker stands in their place (one per run of a source's dropped batches), so that the ingest thread
  knows its source's stream has a hole there and restarts the cycle assembly at it: the cycle the hole cuts is one
  of the dropped ones, not a data gap of the engine (design note 119);
- a source that can wait (a log replayed as fast as it can be read) blocks in ``put`` until the span fits: a replay
  loses nothing and no longer loads the whole log into memory.

The hold (issue 28, design note 136): while an engine's warm-up compiles its kernels (service/warmup.py) a board's
input is read and nothing is analysed; ``hold(max_bytes)`` lifts the span bound meanwhile, so what the board delivers
is kept, in memory, bounded instead by the bytes the queued batches hold (``size``, service/stream_holes.py
``batch_bytes``): past ``max_bytes`` the oldest are dropped and counted as above (never unbounded growth).
``release()`` (the warm-up over) ends the hold once the ingest thread has caught up to within ``max_span_ticks``
again (the monitor runs ~30-60x real time), never before: ending it at once would drop at the next put what the hold
kept. ``lag()`` says the hold (``holding``) and the most it held (``held_s``, ``held_bytes``, ``held_records``).

Markers (a source's end, the session's stop) are never dropped and never wait. ``discard`` empties the queue on a
stop whose drain time is up and says how much it threw away.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

log = logging.getLogger(__name__)

DROP_LOG_EVERY_S = 60.0  # a session that keeps falling behind logs its drop count this often, not per batch


@dataclass(frozen=True)
class IngestLag:
    """How far the ingest thread is behind its readers. ``queued_s``: acquisition time waiting (newest queued key
    minus oldest); ``behind_s``: wall time the oldest waiting batch has waited; ``dropped_*``: thrown away so far."""

    queued_s: float
    behind_s: float
    queued_batches: int
    dropped_records: int
    dropped_s: float
    last_drop_age_s: float | None  # wall seconds since records were last dropped (None: never)
    # the hold (module docstring): on now; the most acquisition seconds, bytes and records it queued at once
    holding: bool = False
    held_s: float = 0.0
    held_bytes: int = 0
    held_records: int = 0


@dataclass
class Dropped:
    """A marker where a source's queued batches were dropped: ``first_key`` .. ``last_key`` the newest ticks of the
    first and last batch dropped there (every record of the source's next queued batch comes after ``last_key``),
    ``records`` how many; ``contents`` what they held, as the queue's ``measure`` counts it."""

    first_key: float
    last_key: float
    records: int
    contents: Counter = field(default_factory=Counter)  # what the dropped batches held (the queue's ``measure``)
    # the newest tick of the source's last batch handed out before the hole (None: none): where the hole begins
    after_key: float | None = field(default=None, compare=False)


@dataclass
class _Item:
    source: str
    payload: Any  # a list of records, or a marker object
    key: float | None  # newest tick of the batch; None for a marker
    read_s: float  # monotonic time the reader got it
    nbytes: int = 0  # what the batch holds (the queue's ``size``; 0 for a marker)


class IngestQueue:
    """See the module docstring. Thread-safe; one consumer. ``measure``: what a dropped batch holds (a Counter, summed
    into its hole's ``Dropped.contents``), called only for the batches dropped. ``size``: the bytes a batch holds
    (the hold's bound; None: its record count)."""

    def __init__(self, max_span_ticks: float, tick_hz: float, measure: Callable[[Any], Counter] | None = None,
                 size: Callable[[Any], int] | None = None) -> None:
        if not (max_span_ticks > 0 and tick_hz > 0):
            raise ValueError(f"need max_span_ticks > 0 and tick_hz > 0, got {max_span_ticks}, {tick_hz}")
        self.max_span, self.tick_hz = float(max_span_ticks), float(tick_hz)
        self._measure = measure
        self.dropped_contents: Counter = Counter()  # what every dropped batch held, summed (``measure``)
        self._items: deque[_Item] = deque()
        self._data = 0  # batches (not markers) queued
        self._newest_key = -float("inf")  # of the batches put (lag() need not scan the queue for it)
        self._cond = threading.Condition()
        self._closed = False
        self.dropped_records = 0
        self.dropped_ticks = 0.0
        self._last_drop_log = -float("inf")
        self._last_drop_s: float | None = None
        # sources whose hole marker has been handed out with none of their batches since: a batch of theirs dropped
        # now widens that hole, which needs no marker of its own (the ingest thread restarted there already)
        self._open: set[str] = set()
        self._handed: dict[str, float] = {}  # each source's newest key handed out (where its next hole begins)
        self._size = size if size is not None else len
        self._bytes = 0  # what the queued batches hold (``size``)
        self._records = 0  # records queued
        self._hold_bytes: int | None = None  # the hold's bound while it is on (None: off)
        self._releasing = False  # release() called: the hold ends once the span fits again
        self.held_s = 0.0  # the most the hold queued at once: acquisition seconds, bytes, records
        self.held_bytes = 0
        self.held_records = 0

    # --- the hold ------------------------------------------------------------------------------------------------
    def hold(self, max_bytes: int) -> None:
        """Keep a real-time source's batches beyond ``max_span_ticks`` until ``release``, up to ``max_bytes`` of
        them (past it the oldest go, counted): a warm-up's wait (module docstring)."""
        if not max_bytes > 0:
            raise ValueError(f"the hold's bound must be > 0 bytes, got {max_bytes}")
        with self._cond:
            self._hold_bytes, self._releasing = int(max_bytes), False

    def release(self) -> None:
        """The reason to hold is over: the hold ends as soon as the queued span fits ``max_span_ticks`` (now, or when
        the ingest thread has caught up that far)."""
        with self._cond:
            self._releasing = True
            self._end_hold()

    @property
    def holding(self) -> bool:
        return self._hold_bytes is not None

    def _end_hold(self) -> None:
        """Called with the lock held: the hold released and the span within bounds again -> the span bound alone."""
        if self._hold_bytes is not None and self._releasing and self._span() <= self.max_span:
            self._hold_bytes, self._releasing = None, False

    # --- readers -------------------------------------------------------------------------------------------------
    def put(self, source: str, records: list, key: float, realtime: bool) -> None:
        with self._cond:
            if not realtime:  # a replay waits for room; a closed queue (stop) takes it without waiting
                self._cond.wait_for(lambda: self._closed or self._span_with(key) <= self.max_span)
            nbytes = int(self._size(records))
            self._items.append(_Item(source, records, float(key), time.monotonic(), nbytes))
            self._data += 1
            self._bytes += nbytes
            self._records += len(records)
            self._newest_key = max(self._newest_key, float(key))
            if realtime:
                self._drop_oldest()
            if self._hold_bytes is not None:
                self.held_s = max(self.held_s, self._span() / self.tick_hz)
                self.held_bytes, self.held_records = max(self.held_bytes, self._bytes), max(self.held_records,
                                                                                            self._records)
            self._cond.notify_all()

    def put_marker(self, source: str | None, marker: object) -> None:
        with self._cond:
            self._items.append(_Item(source, marker, None, time.monotonic()))  # type: ignore[arg-type]
            self._cond.notify_all()

    def close(self) -> None:
        """Readers that wait for room stop waiting (the session is stopping)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    # --- the ingest thread ---------------------------------------------------------------------------------------
    def get(self, timeout: float) -> tuple[str | None, Any]:
        with self._cond:
            if not self._cond.wait_for(lambda: bool(self._items), timeout):
                raise queue.Empty
            item = self._items.popleft()
            if item.key is not None:
                self._data -= 1
                self._bytes -= item.nbytes
                self._records -= len(item.payload)
                self._open.discard(item.source)
                self._handed[item.source] = item.key
                if self._releasing:
                    self._end_hold()
            elif isinstance(item.payload, Dropped):
                self._open.add(item.source)
            self._cond.notify_all()  # a waiting replay reader may have room now
            return item.source, item.payload

    def discard(self) -> tuple[int, float]:
        """Drop every queued batch (markers stay): (records, acquisition seconds) thrown away."""
        with self._cond:
            keys = [it.key for it in self._items if it.key is not None]
            records = sum(len(it.payload) for it in self._items if it.key is not None)
            self._items = deque(it for it in self._items if it.key is None)
            self._data = self._bytes = self._records = 0
            span = (max(keys) - min(keys)) / self.tick_hz if keys else 0.0
            self._cond.notify_all()
            return records, span

    # --- what it shows -------------------------------------------------------------------------------------------
    def lag(self) -> IngestLag:
        with self._cond:
            first = next((it for it in self._items if it.key is not None), None)
            queued = 0.0 if first is None else max(0.0, self._newest_key - first.key) / self.tick_hz
            behind = 0.0 if first is None else time.monotonic() - first.read_s
            dropped_age = None if self._last_drop_s is None else time.monotonic() - self._last_drop_s
            return IngestLag(queued, behind, self._data, self.dropped_records, self.dropped_ticks / self.tick_hz,
                             dropped_age, self._hold_bytes is not None, self.held_s, self.held_bytes,
                             self.held_records)

    def __len__(self) -> int:
        return len(self._items)

    # --- policy --------------------------------------------------------------------------------------------------
    def _span(self) -> float:
        """The queued data's span in ticks (newest queued key minus oldest; 0 when none is queued)."""
        return max(0.0, self._span_with(self._newest_key))

    def _span_with(self, key: float) -> float:
        first = next((it for it in self._items if it.key is not None), None)
        return 0.0 if first is None else key - first.key  # type: ignore[operator]

    def _drop_oldest(self) -> None:
        """Called with the lock held, after an append: drop the oldest batches until the span fits (the newest
        batch itself is always kept) -- during a hold, until the queued bytes fit the hold's bound --, each leaving
        a ``Dropped`` marker in its place, or widening its source's marker still queued before it, or the hole whose
        marker was handed out last (one hole, one marker)."""
        items = self._items
        newest = items[-1].key
        dropped, first_dropped = 0, None
        while self._data > 1:
            i, first = next((i, it) for i, it in enumerate(items) if it.key is not None)
            if newest - first.key <= self.max_span or (self._hold_bytes is not None
                                                       and self._bytes <= self._hold_bytes):
                break
            n = len(first.payload)
            self._bytes -= first.nbytes
            self._records -= n
            held = self._measure(first.payload) if self._measure is not None else Counter()
            self.dropped_contents.update(held)
            # the source's item before it (the batches before the first data batch are all markers)
            before = next((items[j] for j in range(i - 1, -1, -1) if items[j].source == first.source), None)
            if before is not None and isinstance(before.payload, Dropped):
                hole = before.payload
                before.payload = Dropped(hole.first_key, max(hole.last_key, first.key), hole.records + n,
                                         hole.contents + held, hole.after_key)
                del items[i]
            elif before is None and first.source in self._open:
                del items[i]
            else:  # a marker's key is None: never dropped, not counted in the span
                items[i] = _Item(first.source, Dropped(first.key, first.key, n, held,
                                                       self._handed.get(first.source)), None, first.read_s)
            self._data -= 1
            dropped += n
            first_dropped = first.key if first_dropped is None else first_dropped
        if dropped:
            nxt = next(it.key for it in self._items if it.key is not None)
            self.dropped_records += dropped
            self.dropped_ticks += max(0.0, nxt - first_dropped)  # the acquisition time the dropped batches covered
            now = self._last_drop_s = time.monotonic()
            if now - self._last_drop_log >= DROP_LOG_EVERY_S:
                self._last_drop_log = now
                why = (f"by more than {self.max_span / self.tick_hz:.1f} s of acquisition" if self._hold_bytes is None
                       else f"and its hold's {self._hold_bytes / 2**20:.1f} MB are full")
                log.warning("ingest is behind %s: the oldest queued records are dropped, the newest kept (%d records, "
                            "%.1f s of acquisition dropped so far)", why, self.dropped_records,
                            self.dropped_ticks / self.tick_hz)
