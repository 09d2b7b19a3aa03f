"""StoreListener: the fan-out's consumer that keeps an engine's cycles, estimates, alerts and baselines in the store.

    listener = StoreListener(store, "genset-v20")      # store.register_engine(...) first
    fanout.add(listener)                              # service/listeners.py: on_message_received(ServiceEvent)
    listener.on_cycle(summary, cylinders)             # or directly: a CycleSummary dict and its CylinderLoss dicts
    listener.on_alert(alert)                          # an Alert dict (raised, updated, acknowledged, cleared)
    listener.stop()                                   # flushes what is pending

From a ServiceEvent the rows are built by the API's own builders (service/api_views.py: ``cycle_summary``,
``cylinder_losses``), so the store keeps exactly what the API shows; other builders can be given.

Rows are batched: a batch is committed when it holds ``batch_cycles`` cycles or its oldest row has waited
``max_delay_s`` (a timer thread sees to it when no new row comes), one transaction a batch. Estimates (the
per-cylinder losses, ~20 rows a cycle on a genset) are kept every ``estimate_every`` cycles and whenever a cylinder's
status or flags change, not every cycle; every cycle summary is kept. A new baseline is saved at once.

Failures never reach the caller. A store that is down (``StoreUnavailable``: a PostgreSQL connection being reopened,
service/store/sql_store.py) keeps each batch in a bounded backlog, in order, written when the store is back (the
timer tries every ``max_delay_s / 4``; the store's backoff makes a try while it is down cost nothing):
``stats['cycles_written_late']`` counts what was written so. Past ``backlog_cycles`` cycles (a batch of no cycle
counts as one) the oldest batches are dropped, counted in ``stats['lost_batches']``, ``stats['lost_cycles']``
(``lost_alert_updates``, ``lost_baselines``) and logged; so is what is still waiting at ``stop``. Any other failure
(a malformed row, a full disk) is counted (``stats['write_errors']``) and logged, the batch tried once more after
``retry_delay_s``, then lost, counted the same way, and the listener goes on. Rows the store refused because an
earlier run holds their keys (service/store/sql_store.py, runs) are counted in ``stats['rows_refused']`` and logged.
The default backlog, 7500 cycles, is 10 min of a genset-v20 at 1500 rpm, ~25 MB of rows (20 cylinders).

What is lost. The fan-out gives this listener its own bounded queue (``Fanout.queue_size`` events) and drops what
does not fit, counting it (``Fanout.drops``): a dropped event is a cycle the store never sees, as is a lost batch,
and a process killed between two commits loses the uncommitted batch (at most ``batch_cycles`` cycles or
``max_delay_s`` of them). Only committed rows are durable (service/store/sqlite.py says how durable). A genset-v20
at 1500 rpm makes 12.5 cycles/s; a batch of 64 such cycles (20 cylinders) with 40 estimate rows committed in 46-48 ms
(median, SQLite, synchronous=FULL, on a 2-core machine running 12-25 other jobs): ~1300 cycles/s, about 100 times
what one genset makes. Every 100 places of queue hold 8 s of a stalled disk before the first drop.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from frictionwatch.service.store.sql_store import SqlStore, StoreUnavailable

log = logging.getLogger(__name__)
BACKLOG_CYCLES = 7500
DROP_LOG_EVERY_S = 60.0  # a store down for hours drops a batch every few seconds: one line a minute says it


@dataclass
class _Batch:
    """One transaction's rows (or one baseline) as handed to the store; ``delayed``: the store was down for it."""

    cycles: list[dict]
    estimates: list[tuple[int, Sequence[dict]]] = field(default_factory=list)
    alerts: list[dict] = field(default_factory=list)
    figure: dict | None = None
    baseline: dict | None = None
    failures: int = 0
    delayed: bool = False

    @property
    def size(self) -> int:
        return max(len(self.cycles), 1)


class StoreListener:
    name = "store"

    def __init__(self, store: SqlStore, engine_id: str, *, batch_cycles: int = 64, max_delay_s: float = 1.0,
                 estimate_every: int = 25, retry_delay_s: float = 0.5, backlog_cycles: int = BACKLOG_CYCLES,
                 on_commit: Callable[[list[int]], None] | None = None,
                 summary_of: Callable[[str, Any], dict] | None = None,
                 losses_of: Callable[[Any, Sequence[str]], list[dict]] | None = None,
                 figure_of: Callable[[Any], dict] | None = None) -> None:
        if not (batch_cycles >= 1 and max_delay_s > 0 and estimate_every >= 1 and retry_delay_s >= 0
                and backlog_cycles >= batch_cycles):
            raise ValueError("need batch_cycles >= 1, max_delay_s > 0, estimate_every >= 1, retry_delay_s >= 0, "
                             "backlog_cycles >= batch_cycles")
        self.store, self.engine_id = store, engine_id
        self.batch_cycles, self.max_delay_s = batch_cycles, max_delay_s
        self.estimate_every, self.retry_delay_s = estimate_every, retry_delay_s
        self.on_commit = on_commit  # called with the cycle indices of each committed batch (tests, metrics)
        self._summary_of, self._losses_of = summary_of, losses_of  # CycleResult -> rows; the API's when None
        self._figure_of = figure_of  # CycleResult -> the engine's friction figure (fleet view); the API's when None
        self.backlog_cycles = backlog_cycles
        self._backlog: deque[_Batch] = deque()  # batches handed over and not yet written, oldest first
        self._waiting = 0  # the cycles in them
        self._down = False  # the store said it is unavailable and has not taken a batch since
        self._drop_logged = -DROP_LOG_EVERY_S  # monotonic time of the last "backlog full" line
        self._figure: dict | Callable[[], dict] | None = None  # the newest pending cycle's engine figure
        self.stats: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._cycles: list[dict] = []
        self._estimates: list[tuple[int, Sequence[dict]]] = []
        self._alerts: dict[int, dict] = {}  # by alert_id: only an alert's newest state is written
        self._oldest: float | None = None  # monotonic time of the oldest pending row
        self._last_estimate: tuple[int, tuple] | None = None  # (cycle, statuses and flags) of the last kept
        self._last_flags: tuple[str, ...] = ()  # the previous cycle's flags (cylinders given as a function)
        self._stopped = threading.Event()
        self._timer = threading.Thread(target=self._flush_when_due, name=f"store-{engine_id}", daemon=True)
        self._timer.start()

    # ---- what the fan-out calls -------------------------------------------------------------------------------
    def on_message_received(self, event: Any) -> None:
        """A ServiceEvent (service/listeners.py): its cycle (``result``), alert changes and new baseline."""
        if event.result is not None:
            if self._summary_of is None or self._losses_of is None or self._figure_of is None:
                from frictionwatch.service.api_views import cycle_summary, cylinder_losses, engine_figure

                self._summary_of = self._summary_of or cycle_summary
                self._losses_of = self._losses_of or cylinder_losses
                self._figure_of = self._figure_of or engine_figure
            result, names, losses_of, figure_of = event.result, tuple(event.term_names), self._losses_of, self._figure_of
            summary = self._summary_of(self.engine_id, result)
            if getattr(event, "hole", None) is not None:  # the first cycle after a hole dropped while behind says it (``extra``)
                summary["missing_before"] = event.hole
            self.on_cycle(summary, lambda: losses_of(result, names), engine_figure=lambda: figure_of(result))
        for alert in event.alerts:
            self.on_alert(alert)
        if event.baseline is not None:
            self.save_baseline(event.baseline)

    def save_baseline(self, baseline: dict) -> None:
        """Saved at once (with the pending rows first, so the store never holds a baseline newer than its cycles)."""
        with self._lock:
            self._flush_locked(drain=False)
            self._push(_Batch([], baseline=baseline))
            self._drain_locked()

    def on_cycle(self, summary: dict, cylinders: Sequence[dict] | Callable[[], Sequence[dict]] | None = None,
                 engine_figure: dict | Callable[[], dict] | None = None) -> None:
        """One cycle's CycleSummary and (optionally) its per-cylinder CylinderLoss rows.

        ``cylinders`` may be a function that builds the rows: it is called only for the cycles whose estimate is
        kept, every ``estimate_every`` cycles and whenever the cycle's flags differ from the cycle before (a status
        that changes without a flag, e.g. a cylinder newly resolved, is then kept at the next cadence point). With
        the rows themselves, any change of a cylinder's status or flags is kept at once. ``engine_figure`` (or a
        function that builds it, called once a batch for its newest cycle) goes to the fleet view."""
        with self._lock:
            self._cycles.append(summary)
            self._figure = engine_figure
            cycle = int(summary["cycle_index"])
            if callable(cylinders):
                flags = tuple(summary.get("flags") or ())
                if self._due(cycle) or flags != self._last_flags:
                    rows = cylinders()
                    self._last_estimate = (cycle, _status_key(rows))
                    self._estimates.append((cycle, rows))
                self._last_flags = flags
            elif cylinders is not None and self._keep_estimate(cycle, cylinders):
                self._estimates.append((cycle, cylinders))
            self._pending_since()
            if len(self._cycles) >= self.batch_cycles:
                self._flush_locked()

    def on_alert(self, alert: dict) -> None:
        with self._lock:
            self._alerts[int(alert["alert_id"])] = alert
            self._pending_since()

    def flush(self) -> None:
        with self._lock:
            self._flush_locked()

    def stop(self) -> None:
        """End the timer and commit what is pending (the fan-out calls this once its queue is drained); what the
        store cannot take now is lost, counted and logged."""
        self._stopped.set()
        self._timer.join()
        with self._lock:
            self._flush_locked()
            if self._backlog:
                log.error("store %s: %d cycles not written at stop: the store is unavailable", self.engine_id,
                          self._waiting)
                while self._backlog:
                    self._lose(self._pop())

    @property
    def backlog(self) -> int:
        """Cycles handed to the store and not yet written (the store down), at most ``backlog_cycles``."""
        return self._waiting  # an int kept under the lock: read without it (/health must not wait for a write)

    def _push(self, batch: _Batch) -> None:
        self._backlog.append(batch)
        self._waiting += len(batch.cycles)

    def _pop(self) -> _Batch:
        batch = self._backlog.popleft()
        self._waiting -= len(batch.cycles)
        return batch

    # ---- inside -----------------------------------------------------------------------------------------------
    def _due(self, cycle: int) -> bool:
        last = self._last_estimate
        return last is None or not (0 <= cycle - last[0] < self.estimate_every)

    def _keep_estimate(self, cycle: int, cylinders: Sequence[dict]) -> bool:
        key = _status_key(cylinders)
        if not self._due(cycle) and key == self._last_estimate[1]:
            return False
        self._last_estimate = (cycle, key)
        return True

    def _pending_since(self) -> None:
        if self._oldest is None:
            self._oldest = time.monotonic()

    def _flush_when_due(self) -> None:
        while not self._stopped.wait(self.max_delay_s / 4):
            with self._lock:
                if self._backlog or (self._oldest is not None and time.monotonic() - self._oldest >= self.max_delay_s):
                    self._flush_locked()

    def _flush_locked(self, drain: bool = True) -> None:
        """The pending rows become a batch at the end of the backlog; then the backlog is written, oldest first."""
        if self._cycles or self._estimates or self._alerts:
            figure = self._figure
            if callable(figure):
                try:
                    figure = figure()
                except Exception:  # noqa: BLE001 - the fleet view's figure is not worth a batch
                    self.stats["figure_errors"] += 1
                    log.exception("store %s: the engine figure for the fleet view failed", self.engine_id)
                    figure = None
            self._push(_Batch(self._cycles, self._estimates, list(self._alerts.values()), figure))
            self._cycles, self._estimates, self._alerts, self._oldest, self._figure = [], [], {}, None, None
        if drain:
            self._drain_locked()

    def _drain_locked(self) -> None:
        while self._backlog:
            batch = self._backlog[0]
            what = f"{len(batch.cycles)} cycles, {len(batch.estimates)} estimates, {len(batch.alerts)} alerts" + (
                ", a baseline" if batch.baseline is not None else "")
            try:
                refused = self._write(batch)
            except StoreUnavailable as e:
                self.stats["write_errors"] += 1
                for waiting in self._backlog:
                    waiting.delayed = True
                if not self._down:
                    self._down = True
                    log.warning("store %s: unavailable (%s); keeping batches (at most %d cycles) until it is back",
                                self.engine_id, e, self.backlog_cycles)
                self._bound_backlog()
                return
            except Exception as e:  # noqa: BLE001 - a store failure must never stop the service
                self.stats["write_errors"] += 1
                batch.failures += 1
                log.warning("store %s: writing %s failed (attempt %d of 2): %s: %s", self.engine_id, what,
                            batch.failures, type(e).__name__, e)
                if batch.failures < 2:
                    time.sleep(self.retry_delay_s)
                else:
                    self._lose(self._pop())
                continue
            self._pop()
            self._written(batch, refused)
        if self._down:
            self._down = False
            log.warning("store %s: available again; %d cycles written late so far", self.engine_id,
                        self.stats["cycles_written_late"])

    def _write(self, batch: _Batch) -> int:
        if batch.baseline is not None:
            self.store.save_baseline(self.engine_id, batch.baseline)
            return 0
        return self.store.write_batch(self.engine_id, cycles=batch.cycles, estimates=batch.estimates,
                                      alerts=batch.alerts, engine_figure=batch.figure)

    def _bound_backlog(self) -> None:
        dropped = 0
        while len(self._backlog) > 1 and sum(b.size for b in self._backlog) > self.backlog_cycles:
            batch = self._pop()
            dropped += len(batch.cycles)
            self._lose(batch)
        if dropped and time.monotonic() - self._drop_logged >= DROP_LOG_EVERY_S:
            self._drop_logged = time.monotonic()
            log.error("store %s: the store is still unavailable and the backlog is full (%d cycles): the oldest %d "
                      "cycles dropped (%d lost so far; said at most once a minute)", self.engine_id, self.backlog_cycles, dropped,
                      self.stats["lost_cycles"])

    def _lose(self, batch: _Batch) -> None:
        self.stats["lost_batches"] += 1
        self.stats["lost_cycles"] += len(batch.cycles)
        self.stats["lost_alert_updates"] += len(batch.alerts)
        self.stats["lost_baselines"] += batch.baseline is not None

    def _written(self, batch: _Batch, refused: int) -> None:
        if batch.baseline is not None:
            self.stats["baselines_written"] += 1
            return
        cycles = batch.cycles
        self.stats["batches"] += 1
        self.stats["cycles_written"] += len(cycles)
        self.stats["estimates_written"] += len(batch.estimates)
        self.stats["alert_updates_written"] += len(batch.alerts)
        if batch.delayed:
            self.stats["cycles_written_late"] += len(cycles)
        if refused:  # rows of an earlier run under the same keys: kept, these dropped (sql_store)
            self.stats["rows_refused"] += refused
            log.warning("store %s: %d rows not written: an earlier run holds their cycles (another service writing "
                        "this engine?)", self.engine_id, refused)
        if self.on_commit is not None:
            try:
                self.on_commit([int(c["cycle_index"]) for c in cycles])
            except Exception:  # noqa: BLE001 - an observer's failure is not the store's
                self.stats["on_commit_errors"] += 1
                log.exception("store %s: on_commit failed", self.engine_id)


def _status_key(cylinders: Sequence[dict]) -> tuple:
    return tuple((c.get("cylinder"), c.get("status"), tuple(c.get("flags") or ())) for c in cylinders)
