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

Failures never reach the caller: a failed write is counted (``stats['write_errors']``) and logged, the batch is tried
once more after ``retry_delay_s``; if that fails too the batch is lost, counted in ``stats['lost_batches']`` and
``stats['lost_cycles']``, and the listener goes on with the next one. Rows the store refused because an earlier run
holds their keys (service/store/sql_store.py, runs) are counted in ``stats['rows_refused']`` and logged.

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
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

from frictionwatch.service.store.sql_store import SqlStore

log = logging.getLogger(__name__)


class StoreListener:
    name = "store"

    def __init__(self, store: SqlStore, engine_id: str, *, batch_cycles: int = 64, max_delay_s: float = 1.0,
                 estimate_every: int = 25, retry_delay_s: float = 0.5,
                 on_commit: Callable[[list[int]], None] | None = None,
                 summary_of: Callable[[str, Any], dict] | None = None,
                 losses_of: Callable[[Any, Sequence[str]], list[dict]] | None = None) -> None:
        if not (batch_cycles >= 1 and max_delay_s > 0 and estimate_every >= 1 and retry_delay_s >= 0):
            raise ValueError("need batch_cycles >= 1, max_delay_s > 0, estimate_every >= 1, retry_delay_s >= 0")
        self.store, self.engine_id = store, engine_id
        self.batch_cycles, self.max_delay_s = batch_cycles, max_delay_s
        self.estimate_every, self.retry_delay_s = estimate_every, retry_delay_s
        self.on_commit = on_commit  # called with the cycle indices of each committed batch (tests, metrics)
        self._summary_of, self._losses_of = summary_of, losses_of  # CycleResult -> rows; the API's when None
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
            if self._summary_of is None or self._losses_of is None:
                from frictionwatch.service.api_views import cycle_summary, cylinder_losses

                self._summary_of = self._summary_of or cycle_summary
                self._losses_of = self._losses_of or cylinder_losses
            result, names, losses_of = event.result, tuple(event.term_names), self._losses_of
            self.on_cycle(self._summary_of(self.engine_id, result), lambda: losses_of(result, names))
        for alert in event.alerts:
            self.on_alert(alert)
        if event.baseline is not None:
            self.save_baseline(event.baseline)

    def save_baseline(self, baseline: dict) -> None:
        """Saved at once (with the pending rows first, so the store never holds a baseline newer than its cycles)."""
        with self._lock:
            self._flush_locked()
            self._retrying("baseline", lambda: self.store.save_baseline(self.engine_id, baseline), "lost_baselines")

    def on_cycle(self, summary: dict, cylinders: Sequence[dict] | Callable[[], Sequence[dict]] | None = None) -> None:
        """One cycle's CycleSummary and (optionally) its per-cylinder CylinderLoss rows.

        ``cylinders`` may be a function that builds the rows: it is called only for the cycles whose estimate is
        kept, every ``estimate_every`` cycles and whenever the cycle's flags differ from the cycle before (a status
        that changes without a flag, e.g. a cylinder newly resolved, is then kept at the next cadence point). With
        the rows themselves, any change of a cylinder's status or flags is kept at once."""
        with self._lock:
            self._cycles.append(summary)
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
        """End the timer and commit what is pending (the fan-out calls this once its queue is drained)."""
        self._stopped.set()
        self._timer.join()
        self.flush()

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

    def _retrying(self, what: str, write: Callable[[], None], lost: str) -> bool:
        """``write()``, once more after ``retry_delay_s`` if it fails; False (counted in ``stats[lost]``) if both
        fail."""
        for attempt in (1, 2):
            try:
                write()
                return True
            except Exception as e:  # noqa: BLE001 - a store failure must never stop the service
                self.stats["write_errors"] += 1
                log.warning("store %s: writing %s failed (attempt %d of 2): %s: %s", self.engine_id, what, attempt,
                            type(e).__name__, e)
                if attempt == 1:
                    time.sleep(self.retry_delay_s)
        self.stats[lost] += 1
        return False

    def _flush_when_due(self) -> None:
        while not self._stopped.wait(self.max_delay_s / 4):
            with self._lock:
                if self._oldest is not None and time.monotonic() - self._oldest >= self.max_delay_s:
                    self._flush_locked()

    def _flush_locked(self) -> None:
        cycles, estimates, alerts = self._cycles, self._estimates, list(self._alerts.values())
        if not (cycles or estimates or alerts):
            return
        self._cycles, self._estimates, self._alerts, self._oldest = [], [], {}, None
        what = f"{len(cycles)} cycles, {len(estimates)} estimates, {len(alerts)} alerts"
        refused: list[int] = []
        if not self._retrying(what, lambda: refused.append(self.store.write_batch(
                self.engine_id, cycles=cycles, estimates=estimates, alerts=alerts)), "lost_batches"):
            self.stats["lost_cycles"] += len(cycles)
            self.stats["lost_alert_updates"] += len(alerts)
            return
        self.stats["batches"] += 1
        self.stats["cycles_written"] += len(cycles)
        self.stats["estimates_written"] += len(estimates)
        self.stats["alert_updates_written"] += len(alerts)
        if refused and refused[-1]:  # rows of an earlier run under the same keys: kept, these dropped (sql_store)
            self.stats["rows_refused"] += refused[-1]
            log.warning("store %s: %d rows not written: an earlier run holds their cycles (another service writing "
                        "this engine?)", self.engine_id, refused[-1])
        if self.on_commit is not None:
            try:
                self.on_commit([int(c["cycle_index"]) for c in cycles])
            except Exception:  # noqa: BLE001 - an observer's failure is not the store's
                self.stats["on_commit_errors"] += 1
                log.exception("store %s: on_commit failed", self.engine_id)


def _status_key(cylinders: Sequence[dict]) -> tuple:
    return tuple((c.get("cylinder"), c.get("status"), tuple(c.get("flags") or ())) for c in cylinders)
