"""StoreListener: the fan-out's consumer that keeps an engine's cycles, estimates and alerts in the store.

    listener = StoreListener(store, "genset-v20")      # store.register_engine(...) first
    listener.on_cycle(summary, cylinders)             # a CycleSummary dict and its CylinderLoss dicts
    listener.on_alert(alert)                          # an Alert dict (raised, updated, acknowledged, cleared)
    listener.stop()                                   # flushes what is pending

Rows are batched: a batch is committed when it holds ``batch_cycles`` cycles or its oldest row has waited
``max_delay_s`` (a timer thread sees to it when no new row comes), one transaction a batch. Estimates (the
per-cylinder losses, ~20 rows a cycle on a genset) are kept every ``estimate_every`` cycles and whenever a cylinder's
status or flags change, not every cycle; every cycle summary is kept.

Failures never reach the caller: a failed write is counted (``stats['write_errors']``) and logged, the batch is tried
once more after ``retry_delay_s``; if that fails too the batch is lost, counted in ``stats['lost_batches']`` and
``stats['lost_cycles']``, and the listener goes on with the next one.

What is lost. The fan-out (service/listeners.py) gives this listener its own bounded queue and drops what does not
fit, counting it: a dropped result is a cycle the store never sees, as is a lost batch, and a process killed between
two commits loses the uncommitted batch (at most ``batch_cycles`` cycles or ``max_delay_s`` of them). Only committed
rows are durable (service/store/sqlite.py says how durable). Queue size: one genset-v20 at 1500 rpm makes 12.5
cycles/s and a batch of 64 cycles with their estimates commits in milliseconds on a local disk (see the figures in
the report of issue #17), so ``QUEUE_SIZE`` = 1024 results hold 80 s of a stalled disk before the first drop.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence

from frictionwatch.service.store.sql_store import SqlStore

log = logging.getLogger(__name__)


class StoreListener:
    QUEUE_SIZE = 1024  # what the fan-out should give this listener (module docstring: 80 s of genset-v20)

    def __init__(self, store: SqlStore, engine_id: str, *, batch_cycles: int = 64, max_delay_s: float = 1.0,
                 estimate_every: int = 25, retry_delay_s: float = 0.5,
                 on_commit: Callable[[list[int]], None] | None = None) -> None:
        if not (batch_cycles >= 1 and max_delay_s > 0 and estimate_every >= 1 and retry_delay_s >= 0):
            raise ValueError("need batch_cycles >= 1, max_delay_s > 0, estimate_every >= 1, retry_delay_s >= 0")
        self.store, self.engine_id = store, engine_id
        self.batch_cycles, self.max_delay_s = batch_cycles, max_delay_s
        self.estimate_every, self.retry_delay_s = estimate_every, retry_delay_s
        self.on_commit = on_commit  # called with the cycle indices of each committed batch (tests, metrics)
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
        for attempt in (1, 2):
            try:
                self.store.write_batch(self.engine_id, cycles=cycles, estimates=estimates, alerts=alerts)
                break
            except Exception as e:  # noqa: BLE001 - a store failure must never stop the service
                self.stats["write_errors"] += 1
                log.warning("store %s: writing %d cycles, %d estimates, %d alerts failed (attempt %d of 2): %s: %s",
                            self.engine_id, len(cycles), len(estimates), len(alerts), attempt, type(e).__name__, e)
                if attempt == 2:
                    self.stats["lost_batches"] += 1
                    self.stats["lost_cycles"] += len(cycles)
                    self.stats["lost_alert_updates"] += len(alerts)
                    return
                time.sleep(self.retry_delay_s)
        self.stats["batches"] += 1
        self.stats["cycles_written"] += len(cycles)
        self.stats["estimates_written"] += len(estimates)
        self.stats["alert_updates_written"] += len(alerts)
        if self.on_commit is not None:
            try:
                self.on_commit([int(c["cycle_index"]) for c in cycles])
            except Exception:  # noqa: BLE001 - an observer's failure is not the store's
                self.stats["on_commit_errors"] += 1
                log.exception("store %s: on_commit failed", self.engine_id)


def _status_key(cylinders: Sequence[dict]) -> tuple:
    return tuple((c.get("cylinder"), c.get("status"), tuple(c.get("flags") or ())) for c in cylinders)
