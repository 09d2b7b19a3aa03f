"""``McapSource``: replay an MCAP log as a live source -- real time, N x, or as fast as possible, with start / seek.

URL (drivers/source.py): ``mcap:PATH?speed=1|10|max&start=SECONDS&loop=1`` -- ``speed`` defaults to ``max``;
``start`` is seconds after the first record of the log; ``loop=1`` plays the log again from ``start`` when it ends,
for ever (a demonstration service): each pass is moved later in timer ticks by the span of the pass before plus
``LOOP_GAP_S`` of silence, so the stream's time never runs back, and starts with a ``StreamRestart`` mark
(drivers/source.py): the engine pipeline restarts its cycle assembler there and counts a ``loop_restart``, not a
data gap (the log's end and its start are not one engine's continuous run: nothing there is lost data). Pacing
follows the MCAP log time (derived from the timer ticks, docs/replay-format.md); a record is released once the wall
clock, scaled by ``speed``, has reached its log time.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from frictionwatch.core.types import (
    CamBatch,
    FreeEndToothBatch,
    LoadSample,
    PressureBlock,
    PressureFrame,
    StreamRecord,
    ToothBatch,
)
from frictionwatch.drivers.errors import EndOfStream
from frictionwatch.drivers.logs.mcap_log import LogReader
from frictionwatch.drivers.logs.mcap_schema import last_tick
from frictionwatch.drivers.source import Source, StreamRestart

_OPTIONS = ("speed", "start", "loop")
LOOP_GAP_S = 1.0  # acquisition time between the end of one pass and the start of the next


class McapSource(Source):
    """Replay source over a ``LogReader``; ``damage`` is the reader's counter (truncation, corrupt chunks...).

    Parameters
    ----------
    path : the MCAP log.
    speed : replay rate relative to real time (1 = real time); None = as fast as possible.
    start_s : start this many seconds after the first record of the log.
    max_records : most records returned by one ``read``.
    loop : start again from ``start_s`` at the end of the log instead of ending (never raises EndOfStream).
    clock, sleep : monotonic clock [s] and sleep function; tests pass fakes.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        speed: float | None = None,
        start_s: float = 0.0,
        max_records: int = 512,
        loop: bool = False,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        super().__init__()
        if speed is not None and not (speed > 0 and math.isfinite(speed)):
            raise ValueError(f"speed must be > 0 (1 = real time) or None for as fast as possible, got {speed!r}")
        if max_records < 1:
            raise ValueError(f"max_records must be >= 1, got {max_records}")
        self._reader = LogReader(path)  # CorruptLog if nothing is readable
        self.damage = self._reader.damage
        self.info = self._reader.info
        self.engine_toml = self._reader.engine_toml
        self.speed = speed
        self._max = max_records
        self._clock, self._sleep = clock, sleep
        self._iter: Iterator[tuple[int, StreamRecord]] = iter(())
        self._next: tuple[int, StreamRecord] | None = None
        self._anchor: tuple[float, int] | None = None  # (wall clock, log time) pair that pacing refers to
        self.loop, self.passes = loop, 0  # passes: how many times the log has been played to its end
        self._start_s = start_s
        self._shift = 0  # ticks added to every record of this pass (loop)
        self._pass_ticks: tuple[int, int] | None = None  # first and last tick of this pass, before the shift
        # ... of a whole pass from start_s, once one has been read: every such pass decodes the same bytes into the
        # same records, so later passes need not work it out again record by record (last_tick's exact fractions:
        # ~10 % of a looped replay's reading). A seek drops it; the pass it moves then spans the whole pass's range
        # and what it reads after the seek (stream time still never runs back; the next pass is whole again).
        self._whole_pass: tuple[int, int] | None = None
        self._pass_from_start = True  # this pass began at start_s and has not been moved by a seek
        self._restart: StreamRestart | None = None  # the mark the next read gives first (loop: a new pass began)
        if loop and self.info is None:
            self._reader.close()
            raise ValueError(f"{path}: loop=1 needs the log's acquisition metadata (its tick clock)")
        try:
            self._start(start_s)
        except BaseException:  # CorruptLog when a full pass finds nothing readable
            self._reader.close()
            raise

    @classmethod
    def from_url(cls, target: str, options: dict[str, str], clocks: object = None) -> McapSource:
        """``clocks`` is not used: a log carries its own unwrapped timer."""
        unknown = sorted(set(options) - set(_OPTIONS))
        if unknown:
            raise ValueError(f"mcap source: unknown option(s) {unknown}; known: {', '.join(_OPTIONS)}")
        raw_speed = options.get("speed", "max")
        try:
            speed = None if raw_speed == "max" else float(raw_speed)
            start = float(options.get("start", "0"))
            loop = {"0": False, "1": True}[options.get("loop", "0")]
        except ValueError as exc:
            raise ValueError(f"mcap source: speed must be a number or 'max', start in seconds, loop 0 or 1 ({exc})"
                             ) from exc
        except KeyError as exc:
            raise ValueError(f"mcap source: loop must be 0 or 1, got {exc}") from exc
        if not (start >= 0 and math.isfinite(start)):
            raise ValueError(f"mcap source: start must be >= 0 s, got {start}")
        return cls(target, speed=speed, start_s=start, loop=loop)

    @property
    def position_ns(self) -> int | None:
        """Log time of the next record to be read (None at the end)."""
        return self._next[0] if self._next is not None else None

    def seek(self, seconds: float) -> None:
        """Continue from ``seconds`` after the first record of the log (pacing restarts from there)."""
        if self._whole_pass is not None and self._pass_ticks is None and self._pass_from_start:
            self._pass_ticks = self._whole_pass  # not tracked so far in this pass: take the whole pass's range
        self._whole_pass, self._pass_from_start = None, False
        self._start(seconds)

    def _start(self, seconds: float) -> None:
        if not (seconds >= 0 and math.isfinite(seconds)):
            raise ValueError(f"seek position must be >= 0 s, got {seconds!r}")
        first = self._reader.start_ns
        start_ns = None if first is None or seconds == 0 else first + round(seconds * 1e9)
        self._iter = self._reader.iter_timed(start_ns=start_ns)
        self._next = next(self._iter, None)
        self._anchor = None

    def _advance(self) -> StreamRecord:
        assert self._next is not None
        record = self._next[1]
        self._next = next(self._iter, None)
        if not self.loop:
            return record
        if self._whole_pass is not None and self._pass_from_start:
            return shifted(record, self._shift)
        key = int(last_tick(record))  # a record's first element is ms before its last: the gap covers that
        seen = self._pass_ticks
        self._pass_ticks = (key, key) if seen is None else (min(seen[0], key), max(seen[1], key))
        return shifted(record, self._shift)

    def _next_pass(self) -> None:
        """Loop: the next pass starts LOOP_GAP_S after the last tick of this one."""
        assert self.info is not None
        if self._whole_pass is not None and self._pass_from_start:
            self._pass_ticks = self._whole_pass
        if self._pass_ticks is None:  # nothing readable after start: looping would spin
            raise EndOfStream(f"end of {self._reader.path}: nothing to loop over after {self._start_s} s")
        if self._pass_from_start:
            self._whole_pass = self._pass_ticks
        first, last = self._pass_ticks
        self._restart = StreamRestart(ticks=last + self._shift + 1)  # after this pass, before the next (its silence)
        self._shift += last - first + round(LOOP_GAP_S * self.info.tick_hz)
        self._pass_ticks = None
        self.passes += 1
        self._pass_from_start = True
        self._start(self._start_s)

    def reanchor(self) -> None:
        """Pace from the next record on as if the replay started now: a reader that was made to wait (a live session
        while its kernels compile) does not then race through what it owes the clock."""
        self._anchor = None

    def _read_internal(self, timeout: float | None) -> list[StreamRecord | StreamRestart]:
        if self._next is None:
            if not self.loop:
                raise EndOfStream(f"end of {self._reader.path}")
            self._next_pass()
        if self._restart is not None:  # alone in its read: the records of the new pass follow it
            mark, self._restart = self._restart, None
            return [mark]
        if self.speed is None:
            return [self._advance() for _ in range(self._max) if self._next is not None]
        now = self._clock()
        if self._anchor is None:
            self._anchor = (now, self._next[0])
        wall0, log0 = self._anchor
        wait = (self._next[0] - log0) / 1e9 / self.speed - (now - wall0)
        if wait > 0:
            if timeout is not None and wait > timeout:
                self._sleep(timeout)
                return []
            self._sleep(wait)
            now = self._clock()
        due = max(log0 + (now - wall0) * self.speed * 1e9, self._next[0] if wait > 0 else 0)
        out: list[StreamRecord | StreamRestart] = []
        while self._next is not None and self._next[0] <= due and len(out) < self._max:
            out.append(self._advance())
        return out

    def _close_internal(self) -> None:
        self._reader.close()


def shifted(record: StreamRecord, ticks: int) -> StreamRecord:
    """The record moved ``ticks`` later on the timer (the same record when ``ticks`` is 0)."""
    # built field by field, not with dataclasses.replace (which looks the fields up again for every record: ~3 us
    # of a looped replay's ~25 records a genset-v20 cycle, design notes 70)
    if ticks == 0:
        return record
    kind = type(record)
    if kind is ToothBatch or kind is CamBatch or kind is FreeEndToothBatch:
        return kind(record.ticks + ticks)
    if kind is PressureFrame:
        return PressureFrame(record.cylinders, record.t0_ticks + ticks, record.period_ticks, record.values)
    if kind is LoadSample:
        return LoadSample(record.ticks + ticks, record.torque, record.power)
    if kind is PressureBlock:
        return PressureBlock(record.cylinder, record.t0_ticks + ticks, record.period_ticks, record.values)
    if kind is StreamRestart:  # a recording's mark (docs/replay-format.md, restarts)
        start = record.dropped_from_ticks
        return dataclasses.replace(record, ticks=record.ticks + ticks,
                                   dropped_from_ticks=None if start is None else start + ticks)
    raise TypeError(f"not a stream record: {type(record).__name__}")
