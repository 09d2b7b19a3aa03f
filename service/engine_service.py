"""One engine of the service: a LiveSession (sources -> one pipeline), its alert engine, and the fan-out of results.

    svc = EngineService("genset-v20", model, info, {"log": source}, alerts=AlertEngine factory or None,
                        listeners=[store_listener])
    svc.start() ... svc.stop()
    svc.state.snapshot()          # what the API reads (service.listeners.LatestState)

Threads: the session's readers and ingest thread, one thread per listener. On the ingest thread, right after each
result and under the session's lock: the counters the API reads, the alert engine's update (cheap, its state is the
engine's own) and the cycle's event, queued (service/event_outbox.py); then, the lock released, the event handed to
the fan-out. An engine's source never waits there (a full listener queue drops, counted); a log read as fast as it
can be (``session.realtime`` False) waits for its listeners' room, so that a store slower than the replay keeps
every cycle, until a stop's deadline at the latest. Acknowledge and re-baseline come from the API's threads (the
alert engine is guarded by a lock) and never wait; their events keep their place among the cycles'.

Latency. Each source is wrapped so the time its reader got each batch is kept with the batch's newest tick; a
result's arrival time is when, for the last source to get there, the batch reaching the cycle's end tick was read.
``result_s - arrived_s`` is what the metrics histogram shows (record arrival -> result).

Backlog. ``backlog()`` says how far the ingest is behind its sources (service/ingest_queue.py: the queue is bounded
by ``max_queue_s`` of acquisition, real-time sources keep the newest and count what is dropped), in cycles at the
newest result's speed; /health, /metrics and the dashboard show it.

Recorded window. The ingest thread also keeps references to the newest ``recent_s`` (30 s) of raw records
(``RecentRecords``) for the discrepancy workflow on demand (service/discrepancy_jobs.py, POST .../discrepancy).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.monitor.calibration.tdc_watch import WINDOW_CYCLES, TdcWatchState
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.types import AcquisitionInfo, StreamRecord
from frictionwatch.drivers.source import Source
from frictionwatch.service.alert_baseline import Baseline
from frictionwatch.service.event_outbox import EventOutbox
from frictionwatch.service.listeners import Fanout, LatestState, ServiceEvent
from frictionwatch.service.live import LiveSession, record_key
from frictionwatch.service.monitor_snapshot import pickled
from frictionwatch.service.security import valid_engine_id
from frictionwatch.service.warmup import HOLD_BYTES, WarmStart, WarmUpProgress

log = logging.getLogger(__name__)

AlertsFactory = Callable[[str, Any], Any]  # (engine id, EngineSpec) -> an AlertEngine (contract: update, active,
#                                            history, acknowledge, rebaseline, baseline; optionally ring_condition)
STAMPS_KEPT = 4096  # batches remembered per source for the latency (a few seconds of a genset's records)
CYCLE_REVS = 2.0  # crank revolutions per (four-stroke) cycle: turns queued seconds into cycles
LISTENER_STOP_S = 2.0  # what a stop gives the listeners (the store's last batch) after the drain
RECENT_S = 30.0  # raw records kept for an on-demand discrepancy run: genset-v20 pressure ~3.2 MB/s -> ~100 MB


class RecentRecords:
    """The engine's newest raw stream records spanning at most ``window_s`` of acquisition time (by each record's
    last tick, ``record_key``), in the merged order the pipeline saw them. ``append`` / ``extend`` run on the ingest
    thread and keep a reference (records are never modified after they are made); ``window`` copies the list of references
    under the lock, so a reader never holds the ingest thread up for more than that copy."""

    def __init__(self, window_s: float, tick_hz: float) -> None:
        if not window_s > 0:
            raise ValueError(f"the record window must be > 0 s, got {window_s}")
        self.window_s, self.span = float(window_s), float(window_s) * float(tick_hz)
        self._items: deque[tuple[float, StreamRecord]] = deque()
        self._lock = threading.Lock()

    def append(self, record: StreamRecord) -> None:
        self.extend([record])

    def extend(self, records: list[StreamRecord], keys: list[float] | None = None) -> None:
        """``append`` each of ``records`` (in order) under one taking of the lock (the ingest thread's batch);
        ``keys``: their ``record_key``s as the session carries them (worked out here when None)."""
        if not records:
            return
        if keys is None:
            keys = [record_key(r) for r in records]
        with self._lock:
            items = self._items
            items.extend(zip(keys, records, strict=True))
            newest = max(keys)  # what appending them one by one would have trimmed to
            while items[0][0] < newest - self.span:
                items.popleft()

    def window(self, span_s: float | None = None) -> list[StreamRecord]:
        """The records of the newest ``span_s`` of acquisition time (all held when None), oldest first."""
        with self._lock:
            items = list(self._items)
        if span_s is not None and items:
            first = items[-1][0] - span_s * self.span / self.window_s
            items = [it for it in items if it[0] >= first]
        return [r for _, r in items]

    def __len__(self) -> int:
        return len(self._items)


class StampedSource(Source):
    """A source as it is, plus (newest tick, monotonic time) of each batch its reader got (``stamp``, called by the
    session's reader with the batch's keys worked out once)."""

    def __init__(self, inner: Source) -> None:
        super().__init__()
        self.inner = inner
        self.damage = inner.damage
        self.info, self.engine_toml = inner.info, inner.engine_toml
        self.stamps: deque[tuple[float, float]] = deque(maxlen=STAMPS_KEPT)

    def _read_internal(self, timeout: float | None) -> list[StreamRecord]:
        return self.inner.read(timeout)

    def stamp(self, newest_key: float, read_s: float) -> None:
        """The session's ``on_read`` for this source: a batch reaching ``newest_key`` was read at ``read_s``."""
        self.stamps.append((newest_key, read_s))

    def _close_internal(self) -> None:
        self.inner.close()

    def arrival(self, tick: float) -> float | None:
        """When the first batch reaching ``tick`` was read (None: not yet, or no longer remembered). Results come in
        tick order, so older stamps are let go."""
        stamps = self.stamps
        while len(stamps) > 1 and stamps[0][0] < tick:
            stamps.popleft()
        return stamps[0][1] if stamps and stamps[0][0] >= tick else None


@dataclass(frozen=True)
class TdcWatchView:
    """The pipeline's TDC watch (core.monitor.calibration.tdc_watch) as of the newest published result: its state
    (the newest window's estimates and flags, the cycles gathered towards the next window), the cycle that closed
    the newest window (None before the first) and the window's length in cycles."""

    state: TdcWatchState
    window_cycle: int | None
    window_cycles: int = WINDOW_CYCLES


class EngineService:
    """See the module docstring. ``sources``: {name: Source} (the service closes them); ``urls``: how they were
    named (shown by /engines); ``alerts``: a factory of the engine's AlertEngine, or None (no alerts)."""

    def __init__(self, engine_id: str, model: EngineModel, info: AcquisitionInfo, sources: Mapping[str, Source], *,
                 urls: Iterable[str] = (), alerts: AlertsFactory | None = None, listeners: Iterable[Any] = (),
                 history_cycles: int = 5000, queue_size: int = 256, recent_s: float = RECENT_S,
                 warm: bool = False, hold_bytes: int = HOLD_BYTES, **session_options: Any) -> None:
        if not valid_engine_id(engine_id):
            raise ValueError(f"engine id {engine_id!r} must be 1-40 of a-z, 0-9 and '-'")
        self.engine_id, self.model, self.spec, self.info = engine_id, model, model.spec, info
        self.urls = list(urls)
        self.alerts = alerts(engine_id, model.spec) if alerts is not None else None
        if self.alerts is not None and self.alerts.baseline is None and model.calibration.baseline:
            # no stored baseline (--data-dir) yet: the commissioned one, so that the first cycle is compared with
            # the engine as commissioned, not learnt as the normal state (a wear present at start would be)
            self.alerts.baseline = Baseline.from_dict(json.loads(model.calibration.baseline))
        self._alerts_lock = threading.Lock()
        self.state = LatestState(max_results=history_cycles)
        self.fanout = Fanout([self.state, *listeners], queue_size=queue_size)
        self.outbox = EventOutbox(self.fanout)
        self._stamped = {name: StampedSource(src) for name, src in sources.items()}
        self.recent = RecentRecords(recent_s, info.tick_hz)  # what a discrepancy run on a recorded window reads
        self.session = LiveSession(model, info, self._stamped, on_result=self._on_result, start=False,
                                   after_results=self._send, max_results=max(64, history_cycles),
                                   on_records=self.recent.extend, before_ingest=self._load_kernels,
                                   on_read=lambda name, key, t: self._stamped[name].stamp(key, t),
                                   **session_options)
        # a source that can wait (a log read as fast as possible) waits for the listeners, until a stop's deadline
        self._until = None if self.session.realtime else (lambda: self.session.drain_until)
        self._stopped = False
        self.term_names = self._monitor_terms()  # the columns of the monitor's estimates, named
        self._terms_of: Any = None  # the monitor's view the names were read from (_on_result: None, not read yet)
        self._counts_mark: tuple | None = None  # what the counts below were copied at (_on_result)
        self.started_s: float | None = None
        self.last_result_s: float | None = None
        self.alert_errors = 0
        # counts as of the newest result, copied on the ingest thread: the API reads these, never the session's
        # own counters, which wait on the session's lock for the cycle being analysed (~20 ms on a genset)
        self.cycles_ok = 0
        self.skipped: dict[str, int] = {}
        self.restarts: dict[str, int] = {}  # stream restarts met (a looped replay's seams): not lost cycles
        self._holes_given = 0  # the pipeline's holes already handed on with the first result after them
        self.tdc_watch = TdcWatchView(TdcWatchState.empty(), None)  # replaced whole on the ingest thread
        # ``warm``: before the first record, the pipeline's kernels compiled (service/warmup.py); a board's input
        # meanwhile held up to ``hold_bytes`` (0: not held; what the queue's max_queue_s cannot hold is dropped)
        self.warm_start = (WarmStart(self.engine_id, model, info, self.session, self.alerts, hold_bytes) if warm
                           else None)

    @property
    def config(self) -> MonitorConfig:
        """The monitor's settings the engine runs with (MonitorConfig: ``sensor_health`` None = the speed-based
        stage off, the default)."""
        return self.session.pipeline.config

    # --- life cycle ----------------------------------------------------------------------------------------------
    def add_listener(self, listener: Any) -> None:
        self.fanout.add(listener)

    def number_cycles_from(self, first_index: int) -> None:
        """Number this run's cycles from ``first_index`` on (before ``start``): a store's next cycle, so that a
        restart continues the engine's numbering instead of writing cycle 0 again (issue 28). The assembler gives
        the indices; the core only compares neighbours (index == previous + 1), so an offset changes nothing else."""
        if self.started_s is not None:
            raise RuntimeError(f"{self.engine_id}: the cycle numbering is set before start")
        self.session.pipeline.assembler.number_from(first_index)

    def monitor_checkpoint(self) -> tuple[bytes, int] | None:
        """The monitor's carried state (core CyclePipeline.carried), pickled between two records
        (service.monitor_snapshot.pickled), and the newest cycle it holds; None before the first cycle (of this run:
        a state taken back and not moved since is in the store already). Running or stopped: it holds the monitor
        for the pickling (~ms). The newest cycle is the monitor's own, not the assembler's newest index: a cycle the
        assembler has cut may still wait for its pressure or load (then it is not in the state, and a checkpoint
        labelled with it claimed one cycle too many)."""
        def take(pipeline) -> tuple[bytes, int] | None:
            carried, newest = pipeline.cycles.carried(), pipeline.cycles.newest_cycle
            return None if carried is None or newest is None else (pickled(carried), newest)
        return self.session.with_pipeline(take)

    def resume_monitor(self, carried: dict) -> None:
        """Go on from an earlier run's ``monitor_checkpoint`` (before ``start``; ValueError if it does not fit)."""
        if self.started_s is not None:
            raise RuntimeError(f"{self.engine_id}: the monitor's state is taken back before start")
        self.session.pipeline.cycles.resume(carried)

    def start(self) -> EngineService:
        self.started_s = time.monotonic()
        self.fanout.start()
        if self.warm_start is None:
            self.session.start()
        else:
            self.warm_start.start()
        return self

    @property
    def warmup(self) -> WarmUpProgress | None:
        """The warm-up's progress (None: this engine has none)."""
        return None if self.warm_start is None else self.warm_start.progress

    @property
    def warming_up(self) -> bool:
        """Whether the warm-up runs now (the engine analyses nothing yet)."""
        return self.warm_start is not None and self.started_s is not None and self.warm_start.warming_up

    @property
    def compiled_after_warm_up(self) -> int | None:
        """Kernels this process compiled from the end of the warm-up to the stop (None: no warm-up, or not over)."""
        return None if self.warm_start is None else self.warm_start.compiled_after

    def stop(self, timeout: float | None = None) -> None:
        """Stop the session (its ingest thread gets ``timeout`` to drain, default the session's ``drain_s``, serve
        --drain-s; a backlog beyond that is abandoned with the process; a replay waiting for its listeners waits no
        longer than that), then the listeners after they have delivered what is queued (at most
        ``LISTENER_STOP_S``, or ``timeout``, and listeners.IN_HAND_S for an event in hand). So it takes at most the
        drain, 2 s (the session's, for the cycle in progress and its flush), the listeners' time and 0.5 s. What was
        left, records not analysed and events a listener never got (``fanout.left``), is said in one line.
        Idempotent."""
        if self._stopped:
            return
        self._stopped = True
        if self.warm_start is not None:  # a session the warm-up has not started yet never starts
            self.warm_start.cancel()
        self.session.stop(timeout)
        self.skipped, self.restarts = dict(self.session.skipped), dict(self.session.restarts)
        self.fanout.stop(LISTENER_STOP_S if timeout is None else timeout)
        said = []
        left = self.session.left_at_stop
        if left is not None and left[0]:
            newest = self.state.newest
            cycles = (f"~{left[1] * newest.rpm_mean / 60.0 / CYCLE_REVS:.0f} cycles" if newest is not None
                      and newest.rpm_mean > 0 else "cycles unknown")
            said.append(f"{cycles} ({left[1]:.1f} s of acquisition, {left[0]} records) not analysed")
        events = [f"{name} {n}" for name, n in self.fanout.left.items() if n]
        if events:
            said.append(f"events not handed to listeners: {', '.join(events)}")
        if said:
            log.warning("%s: stopped; the stop's time was up: %s", self.engine_id, "; ".join(said))

    def backlog(self) -> dict:
        """The ingest's lag (live.LiveSession.lag) with cycles estimated at the newest result's speed (None before
        the first result). ``realtime``: whether a source runs at the engine's pace (a fast replay's queue is
        read-ahead, not lag)."""
        lag = asdict(self.session.lag())
        newest = self.state.newest
        rpm = float(newest.rpm_mean) if newest is not None else float("nan")
        per_s = rpm / 60.0 / CYCLE_REVS if rpm > 0 else None
        # the dropped cycles from the flywheel edges dropped (a replay's silences are not cycles), else by the time
        edges = self.session.dropped_cycles
        return {**lag, "queued_cycles": None if per_s is None else lag["queued_s"] * per_s,
                "dropped_cycles": edges if edges is not None else None if per_s is None else lag["dropped_s"] * per_s,
                "realtime": self.session.realtime, "max_queue_s": self.session.max_queue_s}

    @property
    def holes(self) -> list[dict]:
        """The stretches dropped while behind that the pipeline met (service/stream_holes.py), oldest first."""
        return self.session.with_pipeline(lambda pipe: [h.to_dict(self.info.tick_hz) for h in pipe.holes])

    @property
    def running(self) -> bool:
        warming = self.warm_start is not None and self.warm_start.thread_alive
        return self.started_s is not None and (warming or any(t.is_alive() for t in self.session.threads))

    @property
    def sources_ended(self) -> bool:
        return len(self.session.merge.ended) == len(self.session.sources)

    # --- the ingest thread ---------------------------------------------------------------------------------------
    def _on_result(self, result: CycleResult) -> None:
        now = time.monotonic()
        self.last_result_s = now
        self.cycles_ok += 1
        pipe = self.session.pipeline
        # the session's lock is held here (its on_result). The counts are copied where they changed: the assembler's
        # losses, the monitor's skips and the restarts only grow, so their totals (and the assembler, replaced at a
        # restart) say whether they did; summing the counters into a new one each cycle was most of this glue's time
        asm = pipe.assembler
        mark = (id(asm), asm.lost, sum(pipe.cycles.skipped.values()), sum(pipe.restarts.values()))
        if mark != self._counts_mark:
            self._counts_mark = mark
            self.skipped = dict(pipe.skipped)
            self.restarts = dict(pipe.restarts)
        watch, window_cycle = pipe.tdc_watch, pipe.tdc_window_cycle
        if watch is not self.tdc_watch.state or window_cycle != self.tdc_watch.window_cycle:
            self.tdc_watch = TdcWatchView(watch, window_cycle)
        if pipe.view is not self._terms_of:  # a model with a friction shape has its view from the first cycle
            self._terms_of, self.term_names = pipe.view, self._monitor_terms()
        arrived = self._arrival(result)
        hole = self._hole_before(result) if pipe.holes_met != self._holes_given else None
        if self.alerts is None:
            self.outbox.put(ServiceEvent(self.engine_id, result, now, arrived, term_names=self.term_names,
                                         hole=hole))
            return
        alerts: tuple[dict, ...] = ()
        learnt: dict | None = None
        with self._alerts_lock:  # the event queued under it: in the order the alert engine changed
            try:
                before = self.alerts.baseline
                alerts = tuple(self._alert_dict(ev.alert) for ev in self.alerts.update(result))
                if self.alerts.baseline is not before and self.alerts.baseline is not None:
                    learnt = self.alerts.baseline.to_dict()  # a band or a friction reference learnt: kept
            except Exception as exc:  # noqa: BLE001 - a fault in the alert layer must not stop the monitor
                if self.alert_errors == 0:
                    log.error("%s: alert update failed: %s", self.engine_id, exc, exc_info=exc)
                self.alert_errors += 1
            self.outbox.put(ServiceEvent(self.engine_id, result, now, arrived, alerts, term_names=self.term_names,
                                         baseline=learnt, hole=hole))

    def _hole_before(self, result: CycleResult) -> dict | None:
        """The holes the pipeline met since the last handed on, in order, each once a result at or after its next
        cycle comes (the session's lock held): what a stored row and the API say of the cycles missing before it.
        Two holes before one result (a cycle between them that the monitor refused): the newer is given."""
        pipe = self.session.pipeline
        new = min(pipe.holes_met - self._holes_given, len(pipe.holes))
        given = None
        for hole in list(pipe.holes)[len(pipe.holes) - new:]:
            if hole.first_missing is not None:  # else a hole that did not cut the cycles (second wheel, pressure)
                if hole.next_cycle is None or result.index < hole.next_cycle:
                    break
                given = hole.to_dict(self.info.tick_hz)
            self._holes_given += 1
        return given

    def _load_kernels(self) -> None:
        """The session's ``before_ingest``: the alert engine's kernel compiled or loaded before the first record (an
        alert engine of its own may have none to load)."""
        load = getattr(self.alerts, "load_kernels", None)
        if load is not None:
            load()

    def _send(self) -> None:
        """The session's ``after_results`` (its lock released): the queued events to the fan-out."""
        self.outbox.send(self._until)

    def _monitor_terms(self) -> tuple[str, ...]:
        """The loss terms the monitor identifies: those of the model's view (service.pipeline.EnginePipeline)."""
        view = self.session.pipeline.view
        return tuple((view.terms if view is not None else self.model.terms).names)

    def _arrival(self, result: CycleResult) -> float | None:
        end_tick = (result.t_start + 120.0 / result.rpm_mean) * self.info.tick_hz if result.rpm_mean > 0 else None
        if end_tick is None:
            return None
        times = [t for s in self._stamped.values() if (t := s.arrival(end_tick)) is not None]
        return max(times) if times else None

    # --- alerts (API threads) ------------------------------------------------------------------------------------
    def _alert_dict(self, alert: Any) -> dict:
        return {"engine_id": self.engine_id, **alert.to_dict()}

    def alert_list(self, active_only: bool, limit: int | None = None) -> tuple[list[dict], int]:
        """The open alerts (``active_only``) or the history (the alert engine keeps the newest
        AlertConfig.max_history cleared ones and every open one), by alert id; only the newest ``limit`` converted
        and returned. Also returns how many there are."""
        if self.alerts is None:
            return [], 0
        with self._alerts_lock:  # the ingest thread takes this lock each cycle: only the copy is made under it
            alerts = self.alerts.active() if active_only else self.alerts.history()
        shown = alerts if limit is None else alerts[-limit:] if limit > 0 else []
        return [self._alert_dict(a) for a in shown], len(alerts)

    def ring_condition(self) -> list[dict]:
        """Each cylinder's newest ring-condition figure (AlertEngine.ring_condition); [] without alerts."""
        figures = getattr(self.alerts, "ring_condition", None)  # an alert engine of its own may have none
        if figures is None:
            return []
        with self._alerts_lock:
            return figures()

    def acknowledge(self, alert_id: int, by: str) -> dict:
        """Raises LookupError when the engine has no such alert (the alert engine's KeyError)."""
        if self.alerts is None:
            raise LookupError(f"engine {self.engine_id} runs without alerts")
        with self._alerts_lock:
            try:
                alert = self._alert_dict(self.alerts.acknowledge(alert_id, by))
            except KeyError as exc:
                raise LookupError(f"engine {self.engine_id} has no alert {alert_id}") from exc
            self.outbox.put(ServiceEvent(self.engine_id, None, time.monotonic(), alerts=(alert,)))
        self.outbox.send_own()
        return alert

    def rebaseline(self) -> dict:
        if self.alerts is None:
            raise LookupError(f"engine {self.engine_id} runs without alerts")
        with self._alerts_lock:
            self.alerts.rebaseline()
            baseline = self.alerts.baseline
            doc = baseline.to_dict() if baseline is not None else None
            # a store keeps the reset too: a restart before the new baseline is learnt must not bring the old one back
            self.outbox.put(ServiceEvent(self.engine_id, None, time.monotonic(),
                                         baseline=doc if doc is not None else {"reset": True, "at_s": time.time()}))
        self.outbox.send_own()
        return {"ok": True, "engine_id": self.engine_id, "baseline": doc}
