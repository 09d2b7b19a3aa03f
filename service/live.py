"""A live session: several sources (tooth board on serial, pressure and load on CAN, ...) -> one engine pipeline.

    with LiveSession(spec, info, {"teeth": serial_source, "bus": can_source}, recorder=rec) as session:
        session.wait_results(10, timeout=5.0)       # results arrive on the ingest thread
    session.results, session.skipped, session.damage  # recent cycles; lost cycles by reason; input damage per source

Memory stays bounded for months of running: the session holds the newest ``max_results`` results (the newest 64
whole, older ones without traces, ``service.pipeline.ResultHistory``; 20,000 genset-v20 cycles, 27 minutes at
1500 rpm, hold ~0.2 GB); ``on_result`` sees every one (a store keeps the history), ``cycles_ok`` counts them all.

Threads. One reader thread per source calls ``source.read(timeout)`` and queues what it gets; one ingest thread
merges the streams into time order, writes them to the black-box recorder (if any) and feeds ``EnginePipeline``;
each result goes to ``on_result`` under the session's lock, then to ``after_results`` with it released (a consumer
that waits there never holds the monitor).
``stop()`` ends the readers, lets the ingest thread drain the queue for at most ``drain_s`` (what is left then is
dropped, counted in ``left_at_stop`` and logged), release every held record and flush the pipeline, then closes the
sources and the recorder (the session owns what it is given).

Backpressure. The reader -> ingest queue is bounded by the acquisition time it holds (``max_queue_s``, default
10 s; service/ingest_queue.py states the policy): a real-time source (serial, CAN, a replay paced by the wall clock)
never waits — the oldest queued batches are dropped, the newest kept, counted in ``lag().dropped_*``, and the
pipeline restarts its cycle assembly where they were (``DROPPED_WHILE_BEHIND``: the cycle cut there is a dropped one,
not a data gap) — while a log replayed as fast as it can be read waits for room (and, in serve, the ingest thread for
its listeners: service/engine_service.py). Memory of the queue is bounded by the sources' data rate times
``max_queue_s`` (genset-v20: ~3.2 MB/s of pressure, ~32 MB), except during a ``hold`` (a warm-up's: the span bound
lifted, a bound in bytes instead, until the ingest has caught up; service/ingest_queue.py). ``lag()`` says how far
the ingest is behind. ``read`` never raising is the sources' contract; an exception that escapes anyway is counted
(``reader_error: <type>``) and the reader goes on.
A failing recorder, ``on_result`` callback or pipeline step is counted in ``errors`` and logged once; the session
goes on.

Merge: service/record_merge.py (``RecordMerge``: the streams into time order with a bounded reorder window).
Files: the life cycle, the settings and what the session has found here; the reader threads in
service/live_readers.py, the ingest thread in service/live_ingest.py (mixins of ``LiveSession``).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from typing import Self

from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.types import AcquisitionInfo, StreamRecord
from frictionwatch.drivers.logs.recorder import Recorder
from frictionwatch.drivers.source import Source
from frictionwatch.service.ingest_queue import IngestLag, IngestQueue
from frictionwatch.service.live_ingest import WARM_RESULTS, IngestThread
from frictionwatch.service.live_readers import (
    END,
    LIVE_DRIVERS,
    KeyedBatch,
    ReaderThreads,
    is_realtime,
    is_replay_paced,
)
from frictionwatch.service.pipeline import EnginePipeline, LogAnalysis, ResultHistory
from frictionwatch.service.record_merge import RecordMerge, record_key
from frictionwatch.service.stream_holes import batch_bytes, batch_contents, edges_to_cycles

log = logging.getLogger(__name__)

# the readers' and the ingest thread's names, where callers have always taken them from
__all__ = ["LIVE_DRIVERS", "WARM_RESULTS", "KeyedBatch", "LiveSession", "RecordMerge", "is_realtime", "is_replay_paced",
           "record_key"]


class LiveSession(ReaderThreads, IngestThread):
    """Sources -> merge -> (recorder) -> EnginePipeline, on threads; see the module docstring.

    Parameters
    ----------
    spec, info : the engine and its stated acquisition (tick clock, wheel, cam, instrumented cylinders).
    sources : {name: Source} or a sequence of sources (named by class and position). The session closes them.
    recorder : black-box recorder of the merged raw records (closed by the session), or None.
    window_s, slack_s : merge window and per-source slack [s of acquisition time] (see ``RecordMerge``).
    quiet_s : wall time without records after which a source stops holding the others back.
    read_timeout_s : how long one ``read`` of a source waits (bounds how fast ``stop`` returns).
    on_result : called on the ingest thread with each CycleResult (exceptions are logged and counted), under the
    session's lock (the one ``with_pipeline`` and the counters take): read the pipeline's state
    there, and keep it short.
    after_results : called on the ingest thread once the lock is released after results were given to
    ``on_result``, before the next record is fed: hand them on there. It may wait (a listener's backpressure on a
    log read as fast as possible: ``realtime`` False), until ``drain_until`` at the latest; holding the lock, a
    wait would hold every reader of the monitor's state with it.
    on_records : called on the ingest thread with each released batch of merged raw records (a list, in order; no
    restart marks) and their keys (``record_key`` of each, the list beside it), before the pipeline sees them
    (cheap: keep references; exceptions are logged and counted). Once a batch, not once a record: ~25 records a
    genset-v20 cycle (design notes 47).
    on_read : called on a source's reader thread with (source name, the batch's newest key, monotonic time it was
    read) for each batch read (serve: its latency stamps, service/engine_service.py).
    before_ingest : called once on the ingest thread before its first record (exceptions logged and counted): what
    the consumers need ready, done in the start's "compiling the kernels" phase rather than mid-run (serve: the
    alert engine's statistics kernel, design note 100).
    max_results : how many recent results the session holds (``results``); older ones are dropped, still counted.
    max_queue_s : the most acquisition time the reader -> ingest queue holds (see Backpressure above).
    drain_s : how long ``stop`` lets the ingest thread work through the queue before dropping the rest.
    warmup_s : while the monitor warms up (a fresh install compiles its numba kernels on the first cycle, 35 s on a
    2-core machine, and more at the first TDC-watch window: until WARM_RESULTS results), a replay paced by the wall
    clock waits for room instead of having its oldest data dropped, for at most this long; then its clock starts
    again (``reanchor``), so it does not race to catch up. A serial or CAN board never waits. 0: no such wait.
    config : the monitor's settings (``MonitorConfig``; None: the defaults), e.g. the speed-based sensor-health
    stage switched on (``serve --sensor-health``).
    replay_batch_s : a replay paced by the wall clock is read at most this often (wall s): it releases a record
    when its time comes, so read as soon as it can each read gave one record (genset-v20: ~240 reads, queue
    hand-overs and ingest wake-ups a second per engine, design notes 31); the records due in the meantime come in
    one read instead, each at most this much later. A serial or CAN board is read as it delivers. 0: no batching.
    40 ms (half a genset-v20 cycle at 1500 rpm): each read and its hand-over cost a looped demo's reader ~0.2 ms of
    CPU a cycle more at 20 ms (design notes 34), and a record of a replay waits at most 40 ms more for its read.
    """

    def __init__(self, spec: EngineSpec, info: AcquisitionInfo, sources: Mapping[str, Source] | Sequence[Source], *,
                 recorder: Recorder | None = None, window_s: float = 1.0, slack_s: float = 0.005,
                 quiet_s: float = 0.5, read_timeout_s: float = 0.05,
                 on_result: Callable[[CycleResult], None] | None = None,
                 after_results: Callable[[], None] | None = None, max_results: int = 20_000,
                 start: bool = True, on_records: Callable[[list[StreamRecord], list[float]], None] | None = None,
                 on_read: Callable[[str, float, float], None] | None = None,
                 config: MonitorConfig | None = None, max_queue_s: float = 10.0, drain_s: float = 5.0,
                 warmup_s: float = 120.0, replay_batch_s: float = 0.04,
                 before_ingest: Callable[[], None] | None = None) -> None:
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
        self.on_result, self.on_records, self.after_results = on_result, on_records, after_results
        self.before_ingest, self.on_read = before_ingest, on_read
        self._unsent = False  # results given to on_result under the lock and not yet to after_results
        self._history = ResultHistory(max_len=max_results)
        self.records_fed = 0
        self.errors: Counter[str] = Counter()  # the session's own trouble: recorder, on_result, pipeline bugs
        self._reader_counts: dict[str, Counter[str]] = {n: Counter() for n in self.sources}
        self._heard = dict.fromkeys(self.sources, time.monotonic())  # wall time a reader last got records
        self.max_queue_s = max_queue_s
        self._queue = IngestQueue(max_queue_s * info.tick_hz, info.tick_hz, measure=batch_contents, size=batch_bytes)
        self._realtime = {n: is_realtime(s) for n, s in self.sources.items()}
        self._paced_replays = [n for n, s in self.sources.items() if is_replay_paced(s)]
        self.replay_batch_s = replay_batch_s
        self.warmup_s = warmup_s
        self._warm = threading.Event()
        self._results_seen = 0
        self._start_s = math.inf
        self.drain_s = drain_s
        self._drain_until = math.inf  # set by stop(): past it the ingest thread drops what is still queued
        self.left_at_stop: tuple[int, float] | None = None  # (records, acquisition s) dropped when the drain ran out
        self._stop = threading.Event()
        self._cond = threading.Condition()  # guards results, pipeline counters and the merge's counters
        # the recorder's writes (ingest thread) against its close (stop): an ingest thread still running past the
        # drain must not write into, or race, the file being closed; what it delivers then is counted, not recorded
        self._recording = threading.Lock()
        self._recorder_closed = False
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
        self._start_s = time.monotonic()
        self._started = True
        self._heard = dict.fromkeys(self.sources, time.monotonic())
        self._ingest.start()
        for t in self._readers:
            t.start()
        return self

    def stop(self, timeout: float | None = None) -> None:
        """End the readers, drain (at most ``timeout`` s, default ``drain_s``) and flush, close sources and
        recorder. Idempotent."""
        if self._stopped:
            return
        self._stopped = True
        drain = self.drain_s = self.drain_s if timeout is None else timeout
        self._drain_until = time.monotonic() + drain
        self._stop.set()
        self._queue.close()  # a replay reader waiting for room gives up
        if self._started:
            for t in self._readers:  # all of them within the one drain, not a drain each
                t.join(max(0.0, self._drain_until - time.monotonic()))
            self._queue.put_marker(None, END)
            # the drain's deadline, plus the cycle in progress and the pipeline's flush
            self._ingest.join(max(0.0, self._drain_until - time.monotonic()) + 2.0)
        for name, src in self.sources.items():
            try:
                src.close()
            except Exception as exc:  # noqa: BLE001 - a close that fails must not keep the others open
                log.warning("closing %s: %s", name, exc)
        if self.recorder is not None:
            with self._recording:
                self.recorder.close()
                self._recorder_closed = True
        alive = [t.name for t in (*self._readers, self._ingest) if t.is_alive()]
        if alive:
            log.error("live session: threads still running after stop: %s", alive)

    @property
    def drain_until(self) -> float:
        """The monotonic time a stop's drain ends (inf while running): a wait in ``after_results`` ends there."""
        return self._drain_until

    def lag(self) -> IngestLag:
        """How far the ingest thread is behind the readers (never waits for the ingest thread)."""
        return self._queue.lag()

    def hold(self, max_bytes: int) -> None:
        """Keep what the real-time sources deliver beyond ``max_queue_s``, up to ``max_bytes`` of it, until
        ``release_hold`` and the ingest thread's catching up (service/ingest_queue.py: the hold): a warm-up's wait
        before the first record (service/warmup.py WarmStart)."""
        self._queue.hold(max_bytes)

    def release_hold(self) -> None:
        self._queue.release()

    @property
    def dropped_cycles(self) -> float | None:
        """The crank cycles the flywheel edges dropped while behind held (edges / edges a cycle: a replay's
        silences not counted, unlike ``lag().dropped_s``); None where no flywheel edge was dropped."""
        edges = self._queue.dropped_contents["teeth"]
        return edges_to_cycles(edges, self.info) if edges else None

    @property
    def realtime(self) -> bool:
        """Whether any source is real-time (its lag is a lag behind the engine, not a replay's read-ahead)."""
        return any(self._realtime.values())

    @property
    def threads(self) -> list[threading.Thread]:
        return [*self._readers, self._ingest]

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- what it has found ---------------------------------------------------------------------------------------
    def with_pipeline(self, fn):
        """``fn(pipeline)`` between two records, under the lock the ingest thread feeds the pipeline under: a
        consistent view of the running monitor (a checkpoint of its state). The monitor waits while ``fn`` runs:
        keep it short."""
        with self._cond:
            return fn(self.pipeline)

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
                               cylinder_twist=self.pipeline.cylinder_twist(),
                               restarts=Counter(self.pipeline.restarts),
                               holes=[h.to_dict(self.info.tick_hz) for h in self.pipeline.holes])
