"""A live session's reader side (service/live.py ``LiveSession``): one thread per source calls ``source.read`` and
puts what it gets on the session's queue (service/ingest_queue.py) with each record's key worked out once
(``KeyedBatch``); whether a source can be made to wait (``is_realtime``, ``is_replay_paced``) decides how the queue
treats it. ``ReaderThreads`` is a mixin of LiveSession: its attributes are the session's.
"""

from __future__ import annotations

import logging
import time

from frictionwatch.drivers.errors import EndOfStream
from frictionwatch.drivers.source import Source, StreamRestart
from frictionwatch.service.record_merge import record_key

log = logging.getLogger("frictionwatch.service.live")  # the session's own logger, as before the split

END = object()  # a source's end (and the session's stop) on the queue


class KeyedBatch:
    """A reader's batch on its way through the queue: the records and each one's ``record_key``, worked out once."""

    __slots__ = ("records", "keys")

    def __init__(self, records: list, keys: list[float]) -> None:
        self.records, self.keys = records, keys

    def __len__(self) -> int:  # the queue counts records (IngestQueue.discard)
        return len(self.records)



LIVE_DRIVERS = ("frictionwatch.drivers.serial", "frictionwatch.drivers.can")  # sources that cannot wait for us


def is_replay_paced(source: Source) -> bool:
    """A log replayed at the wall clock's pace (not a serial or CAN board): real time, but it *can* wait, and start
    its clock again (``reanchor``)."""
    inner = getattr(source, "inner", source)
    return is_realtime(source) and not type(inner).__module__.startswith(LIVE_DRIVERS) and hasattr(inner, "reanchor")


def is_realtime(source: Source) -> bool:
    """Whether a source produces at the wall clock's pace and cannot be made to wait: a serial or CAN board, or a
    replay with a speed. A log read as fast as possible (mcap ``speed=max``: None; mdf4 speed 0) and test doubles
    can wait. Read from the drivers' attributes, since Source has no such flag."""
    inner = getattr(source, "inner", source)  # engine_service.StampedSource wraps the driver
    if type(inner).__module__.startswith(LIVE_DRIVERS):
        return True
    speed = getattr(inner, "speed", None)
    return speed is not None and speed > 0


class ReaderThreads:
    """LiveSession's reader threads (see the module docstring)."""

    def _read_loop(self, name: str, src: Source) -> None:
        batch_s = self.replay_batch_s if name in self._paced_replays else 0.0
        while not self._stop.is_set():
            try:
                records = src.read(timeout=self.read_timeout_s)
            except EndOfStream:
                self._queue.put_marker(name, END)
                return
            except Exception as exc:  # noqa: BLE001 - counted; a reader thread must not die of one bad read
                reason = f"reader_error: {type(exc).__name__}"
                with self._cond:
                    first = self._reader_counts[name][reason] == 0
                    self._reader_counts[name][reason] += 1
                if first:
                    log.warning("%s: %s", name, exc)
                self._stop.wait(0.1)
                continue
            if records:
                now = self._heard[name] = time.monotonic()  # stamped here: a busy ingest thread must not see silence
                keys = [record_key(r) for r in records]  # once: they travel with the records (record_merge.py)
                newest = max(keys)
                if self.on_read is not None:
                    self.on_read(name, newest, now)
                self._queue.put(name, KeyedBatch(records, keys), newest,
                                self._realtime[name] and not self._replay_waits(name))
                # what comes due meanwhile stays in the replay: the next read takes it in one (not after a loop's
                # restart mark, which comes alone: the pass after it starts its clock at its first read)
                if batch_s > 0.0 and not isinstance(records[-1], StreamRestart):
                    self._stop.wait(batch_s)

    def _replay_waits(self, name: str) -> bool:
        """Whether this source's batch waits for room rather than pushing the oldest out: a paced replay while the
        monitor warms up (WARM_RESULTS results), within ``warmup_s`` of the start."""
        return (name in self._paced_replays and not self._warm.is_set()
                and time.monotonic() - self._start_s < self.warmup_s)
