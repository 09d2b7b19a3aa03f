"""A live session: several sources (tooth board on serial, pressure and load on CAN, ...) -> one engine pipeline.

    with LiveSession(spec, info, {"teeth": serial_source, "bus": can_source}, recorder=rec) as session:
        session.wait_results(10, timeout=5.0)       # results arrive on the ingest thread
    session.results, session.skipped, session.damage  # recent cycles; lost cycles by reason; input damage per source

Memory stays bounded for months of running: the session holds the newest ``max_results`` results (the newest 64
whole, older ones without traces, ``service.pipeline.ResultHistory``; 20,000 genset-v20 cycles, 27 minutes at
1500 rpm, hold ~0.2 GB); ``on_result`` sees every one (a store keeps the history), ``cycles_ok`` counts them all.

Threads. One reader thread per source calls ``source.read(timeout)`` and queues what it gets; one ingest thread
merges the streams into time order, writes them to the black-box recorder (if any) and feeds ``EnginePipeline``.
``stop()`` ends the readers, lets the ingest thread drain the queue, release every held record and flush the
pipeline, then closes the sources and the recorder (the session owns what it is given). ``read`` never raising is
the sources' contract; an exception that escapes anyway is counted (``reader_error: <type>``) and the reader goes on.
A failing recorder, ``on_result`` callback or pipeline step is counted in ``errors`` and logged once; the session
goes on.

Merge (``RecordMerge``). Each record is keyed by the tick of its last element (the replay log's time,
docs/replay-format.md §2). Within one source records come nearly in order (a serial CAM frame can overtake the TEETH
frame still being filled, by at most 2 ms; see drivers/bridge.py), so a source vouches for "nothing older will come"
only up to ``slack`` ticks behind the newest key it gave. A held record is released once every source vouches for
its key, except sources that have ended or gone quiet: a source that gave no record for ``quiet_s`` of wall time (an
engine at rest sends no teeth, a port is lost) stops holding the others back until it speaks again. Whatever the
vouches, a record is released once it is ``window`` ticks older than the newest key seen (memory stays bounded when
one source lags). A record older than one already released is still fed (the cycle assembler tolerates streams that
run a little apart) and counted as ``late_record`` for its source. ``merge.stats`` counts records released without
every vouch (by quiet sources, the window, or the final flush).

Choosing the window: it bounds how long a source that lags (not a silent one) holds the others, in acquisition time.
Within it the order is kept whatever the lag, at the cost of memory (1 s of genset-v20 pressure is 3.2 MB) and of
latency only while a source lags. Beyond it, teeth released more than the assembler's pressure wait (0.5 s) ahead of
their pressure lose their cycle ('pressure_missing'). The default is 1 s.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Self

from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.types import (
    AcquisitionInfo,
    CamBatch,
    LoadSample,
    PressureBlock,
    PressureFrame,
    StreamRecord,
    ToothBatch,
)
from frictionwatch.drivers.errors import EndOfStream
from frictionwatch.drivers.logs.recorder import Recorder
from frictionwatch.drivers.source import Source, StreamRestart
from frictionwatch.service.pipeline import EnginePipeline, LogAnalysis, ResultHistory

log = logging.getLogger(__name__)

# ties: the simulator's order; a restart mark before the records it precedes
_RANK = {StreamRestart: -1, ToothBatch: 0, CamBatch: 1, PressureBlock: 2, PressureFrame: 2, LoadSample: 3}
_END = object()


def record_key(record: StreamRecord | StreamRestart) -> float:
    """Tick of the record's last element (when it was complete): drivers.logs.mcap_schema.last_tick as a float; a
    restart mark's own tick."""
    if isinstance(record, ToothBatch | CamBatch):
        return float(record.ticks[-1])
    if isinstance(record, PressureBlock):
        return float(record.t0_ticks) + (len(record.values) - 1) * float(record.period_ticks)
    if isinstance(record, PressureFrame):
        return float(record.t0_ticks) + (record.values.shape[-1] - 1) * float(record.period_ticks)
    if isinstance(record, LoadSample | StreamRestart):
        return float(record.ticks)
    raise TypeError(f"not a stream record: {type(record).__name__}")


class RecordMerge:
    """Time-ordered merge of named record streams with a bounded reorder window (no threads, no clock).

    Parameters
    ----------
    sources : names of the streams.
    window_ticks : a held record is released at the latest when it is this much older than the newest key seen.
    slack_ticks : how far behind its own newest key a source may still deliver (its internal disorder).
    """

    def __init__(self, sources: Iterable[str], window_ticks: float, slack_ticks: float = 0.0) -> None:
        names = list(sources)
        if not names or len(set(names)) != len(names):
            raise ValueError(f"need one or more distinct source names, got {names}")
        if not (window_ticks > 0 and slack_ticks >= 0):
            raise ValueError("need window_ticks > 0 and slack_ticks >= 0")
        self.window, self.slack = float(window_ticks), float(slack_ticks)
        self.progress: dict[str, float] = {n: -math.inf for n in names}  # newest key per source
        self.ended: set[str] = set()
        self.quiet: set[str] = set()
        self.counts: dict[str, Counter[str]] = {n: Counter() for n in names}
        self.stats: Counter[str] = Counter()  # released_by_quiet / _window / _flush: records not vouched for
        self.released_key = -math.inf
        self._heap: list[tuple[float, int, int, StreamRecord]] = []
        self._order = itertools.count()

    @property
    def held(self) -> int:
        return len(self._heap)

    def push(self, source: str, records: Iterable[StreamRecord]) -> list[StreamRecord]:
        """File the records of one source; returns those now released, in key order."""
        if source not in self.progress:
            raise ValueError(f"unknown source {source!r}; known: {sorted(self.progress)}")
        self.quiet.discard(source)
        late: list[StreamRecord] = []
        for r in records:
            key = record_key(r)
            self.progress[source] = max(self.progress[source], key)
            if key < self.released_key:
                if not self.counts[source]["late_record"]:
                    log.warning("%s: a record %.0f ticks older than what was released (%s)", source,
                                self.released_key - key, dict(self.stats))
                self.counts[source]["late_record"] += 1
                late.append(r)
            else:
                heapq.heappush(self._heap, (key, _RANK[type(r)], next(self._order), r))
        late.sort(key=record_key)  # a CAN batch comes ordered by first sample, the streams meet by last
        return late + self._release()

    def end(self, source: str) -> list[StreamRecord]:
        """The source has ended: it no longer holds the others back."""
        self.ended.add(source)
        return self._release()

    def set_quiet(self, sources: Iterable[str]) -> list[StreamRecord]:
        """These sources are silent (wall clock): they stop holding the others back until they deliver again."""
        self.quiet = set(sources) & set(self.progress)
        return self._release()

    def flush(self) -> list[StreamRecord]:
        """Release everything held, in key order."""
        return self._release(flushing=True)

    def _release(self, flushing: bool = False) -> list[StreamRecord]:
        all_live = [p - self.slack for n, p in self.progress.items() if n not in self.ended]
        voiced = [p - self.slack for n, p in self.progress.items() if n not in self.ended and n not in self.quiet]
        strict, vouched = min(all_live, default=math.inf), min(voiced, default=math.inf)
        window = max(self.progress.values()) - self.window
        limit = math.inf if flushing else max(vouched, window)
        out = []
        while self._heap and self._heap[0][0] <= limit:
            key, _, _, r = heapq.heappop(self._heap)
            if key > strict:
                why = "flush" if flushing else ("window" if key > vouched else "quiet")
                self.stats[f"released_by_{why}"] += 1
            self.released_key = max(self.released_key, key)
            out.append(r)
        return out


class LiveSession:
    """Sources -> merge -> (recorder) -> EnginePipeline, on threads; see the module docstring.

    Parameters
    ----------
    spec, info : the engine and its stated acquisition (tick clock, wheel, cam, instrumented cylinders).
    sources : {name: Source} or a sequence of sources (named by class and position). The session closes them.
    recorder : black-box recorder of the merged raw records (closed by the session), or None.
    window_s, slack_s : merge window and per-source slack [s of acquisition time] (see ``RecordMerge``).
    quiet_s : wall time without records after which a source stops holding the others back.
    read_timeout_s : how long one ``read`` of a source waits (bounds how fast ``stop`` returns).
    on_result : called on the ingest thread with each CycleResult (exceptions are logged and counted).
    on_record : called on the ingest thread with each merged raw record, before the pipeline sees it (cheap: keep a
    reference; exceptions are logged and counted).
    max_results : how many recent results the session holds (``results``); older ones are dropped, still counted.
    config : the monitor's settings (``MonitorConfig``; None: the defaults), e.g. the speed-based sensor-health
    stage switched on (``serve --sensor-health``).
    """

    def __init__(self, spec: EngineSpec, info: AcquisitionInfo, sources: Mapping[str, Source] | Sequence[Source], *,
                 recorder: Recorder | None = None, window_s: float = 1.0, slack_s: float = 0.005,
                 quiet_s: float = 0.5, read_timeout_s: float = 0.05,
                 on_result: Callable[[CycleResult], None] | None = None, max_results: int = 20_000,
                 start: bool = True, on_record: Callable[[StreamRecord], None] | None = None,
                 config: MonitorConfig | None = None) -> None:
        if isinstance(sources, Mapping):
            self.sources = dict(sources)
        else:
            self.sources = {f"{type(s).__name__.lower()}{i}": s for i, s in enumerate(sources)}
        if not self.sources:
            raise ValueError("a live session needs at least one source")
        self.spec, self.info = spec, info
        self.pipeline = EnginePipeline(spec, info, config)
        self.merge = RecordMerge(self.sources, window_s * info.tick_hz, slack_s * info.tick_hz)
        self.recorder = recorder
        self.quiet_s, self.read_timeout_s = quiet_s, read_timeout_s
        self.on_result, self.on_record = on_result, on_record
        self._history = ResultHistory(max_len=max_results)
        self.records_fed = 0
        self.errors: Counter[str] = Counter()  # the session's own trouble: recorder, on_result, pipeline bugs
        self._reader_counts: dict[str, Counter[str]] = {n: Counter() for n in self.sources}
        self._heard = dict.fromkeys(self.sources, time.monotonic())  # wall time a reader last got records
        self._queue: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._cond = threading.Condition()  # guards results, pipeline counters and the merge's counters
        self._readers = [threading.Thread(target=self._read_loop, args=(n, s), name=f"live-read-{n}", daemon=True)
                         for n, s in self.sources.items()]
        self._ingest = threading.Thread(target=self._ingest_loop, name="live-ingest", daemon=True)
        self._started = self._stopped = False
        if start:
            self.start()

    # --- life cycle ----------------------------------------------------------------------------------------------
    def start(self) -> LiveSession:
        if self._started:
            raise ValueError("a live session starts once")
        self._started = True
        self._heard = dict.fromkeys(self.sources, time.monotonic())
        self._ingest.start()
        for t in self._readers:
            t.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """End the readers, drain and flush, close sources and recorder. Idempotent."""
        if self._stopped:
            return
        self._stopped = True
        self._stop.set()
        if self._started:
            for t in self._readers:
                t.join(timeout)
            self._queue.put((None, _END))
            self._ingest.join(timeout)
        for name, src in self.sources.items():
            try:
                src.close()
            except Exception as exc:  # noqa: BLE001 - a close that fails must not keep the others open
                log.warning("closing %s: %s", name, exc)
        if self.recorder is not None:
            self.recorder.close()
        alive = [t.name for t in (*self._readers, self._ingest) if t.is_alive()]
        if alive:
            log.error("live session: threads still running after stop: %s", alive)

    @property
    def threads(self) -> list[threading.Thread]:
        return [*self._readers, self._ingest]

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- what it has found ---------------------------------------------------------------------------------------
    def wait_results(self, n: int, timeout: float) -> bool:
        """Wait until at least ``n`` cycles have been analysed (True) or ``timeout`` seconds passed (False)."""
        with self._cond:
            return self._cond.wait_for(lambda: self._history.count >= n, timeout)

    def wait_progress(self, source: str, tick: float, timeout: float) -> bool:
        """Wait until ``source`` has delivered a record with a key at or after ``tick``."""
        with self._cond:
            return self._cond.wait_for(lambda: self.merge.progress[source] >= tick, timeout)

    def wait_ended(self, timeout: float) -> bool:
        """Wait until every source has ended (finite sources: log replay) and its records have been fed."""
        with self._cond:
            return self._cond.wait_for(lambda: len(self.merge.ended) == len(self.sources), timeout)

    @property
    def results(self) -> list[CycleResult]:
        """The recent results, oldest first (a copy; at most ``max_results``)."""
        with self._cond:
            return self._history.to_list()

    @property
    def cycles_ok(self) -> int:
        """Cycles analysed since the start, including those no longer held in ``results``."""
        with self._cond:
            return self._history.count

    @property
    def skipped(self) -> Counter[str]:
        """Cycles lost, by reason (cycle assembly and monitor)."""
        with self._cond:
            return Counter(self.pipeline.skipped)

    @property
    def restarts(self) -> Counter[str]:
        """Stream restarts the pipeline met, by reason (a looped replay's ``loop_restart``): not lost cycles."""
        with self._cond:
            return Counter(self.pipeline.restarts)

    @property
    def damage(self) -> dict[str, Counter[str]]:
        """Input damage per source: the source's own counts (decoder, transport) plus reader and merge counts."""
        with self._cond:
            out = {}
            for name, src in self.sources.items():
                own = Counter(dict(src.damage))  # a plain-dict copy is atomic under the GIL
                out[name] = own + self._reader_counts[name] + self.merge.counts[name]
            return out

    def analysis(self) -> LogAnalysis:
        """The session so far in the shape ``frictionwatch analyze`` reports (damage keys are 'source: reason')."""
        damage = Counter({f"{n}: {k}": v for n, c in self.damage.items() for k, v in c.items()})
        with self._cond:
            return LogAnalysis(self.spec, self._history.to_list(), Counter(self.pipeline.skipped), damage,
                               dropped=self._history.dropped, tdc_watch=self.pipeline.tdc_watch,
                               cylinder_twist=self.pipeline.cylinder_twist())

    # --- threads -------------------------------------------------------------------------------------------------
    def _read_loop(self, name: str, src: Source) -> None:
        while not self._stop.is_set():
            try:
                records = src.read(timeout=self.read_timeout_s)
            except EndOfStream:
                self._queue.put((name, _END))
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
                self._heard[name] = time.monotonic()  # stamped here: a busy ingest thread must not see silence
                self._queue.put((name, records))

    def _ingest_loop(self) -> None:
        while True:
            try:
                name, item = self._queue.get(timeout=min(0.05, self.quiet_s / 2))
            except queue.Empty:
                name, item = "", None
            if name is None:  # stop(): the readers have ended; what is still queued came before this
                break
            now = time.monotonic()
            quiet = {n for n, t in self._heard.items() if now - t >= self.quiet_s}
            with self._cond:  # the merge's progress and counts are read by other threads
                released = []
                if quiet != self.merge.quiet:
                    released = self.merge.set_quiet(quiet)
                if name:
                    released += self.merge.end(name) if item is _END else self.merge.push(name, item)
                self._cond.notify_all()
            self._deliver(released)
        with self._cond:
            released = self.merge.flush()
        self._deliver(released)
        with self._cond:
            self._publish(self.pipeline.flush())
            self._cond.notify_all()

    def _deliver(self, records: list[StreamRecord]) -> None:
        if not records:
            return
        for r in records:
            if isinstance(r, StreamRestart):  # not data: neither recorded nor handed on, the pipeline restarts
                with self._cond:
                    self._publish(self.pipeline.feed(r))
                continue
            if self.recorder is not None:
                try:
                    self.recorder.write(r)
                except OSError as exc:  # disk full, folder gone: the black box fails, the monitor goes on
                    self._error("recorder", exc)
            if self.on_record is not None:
                try:
                    self.on_record(r)
                except Exception as exc:  # noqa: BLE001 - a consumer's bug must not stop the monitor
                    self._error("on_record", exc)
            with self._cond:
                self.records_fed += 1
                try:
                    results = self.pipeline.feed(r)
                except Exception as exc:  # noqa: BLE001 - a bug met by odd input: counted, logged, stream goes on
                    self._error("pipeline", exc)
                    continue
                self._publish(results)
        with self._cond:
            self._cond.notify_all()

    def _publish(self, results: list[CycleResult]) -> None:
        """Called with ``_cond`` held."""
        for res in results:
            self._history.append(res)
            if self.on_result is not None:
                try:
                    self.on_result(res)
                except Exception as exc:  # noqa: BLE001 - a consumer's bug must not stop the monitor
                    self._error("on_result", exc)
        if results:
            self._cond.notify_all()

    def _error(self, where: str, exc: BaseException) -> None:
        reason = f"{where}: {type(exc).__name__}"
        if self.errors[reason] == 0:
            log.error("live session: %s failed: %s", where, exc, exc_info=exc)
        self.errors[reason] += 1
