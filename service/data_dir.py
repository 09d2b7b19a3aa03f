"""`serve --data-dir DIR`: what a restarted service takes back from DIR/frictionwatch.db (service/store), and the
retention that keeps the file from growing for ever.

At start, per engine (``DataDir.attach``): a new run in the store (issue 28), the cycle numbering continued after
the newest cycle stored (a restart appends, never overwrites), the alert history and open alerts with their
acknowledgements taken back into the alert engine (ids numbered on), and the newest learnt baseline (every load
band and friction reference learnt so far, saved as learnt) in force, so nothing is relearnt and a ring worn while
the service was down is not learnt as the healthy state. A re-baseline saved as a reset keeps the old baseline out.

Not restored: the monitor's smoothed estimates and the EWMA / latch counts of the alert statistics. They start again
as at a first start: the first cycles of a run are its warm-up (the ``runs`` table says where each run began; the
/losses window's ``effective_cycles`` says how many cycles a smoothed figure rests on), and said so at start. A band
being learnt when the service stopped is learnt again from its first cycle.

Retention (``--keep-days N``): cycles and estimates written more than N days ago are deleted at start and then
every hour, in batches (service.store.sql_store.SqlStore.apply_retention); alerts, baselines, runs and model
versions are kept whatever their age.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from pathlib import Path
from typing import Any

from frictionwatch.service.alert_baseline import Baseline
from frictionwatch.service.store import StoreListener, open_store

log = logging.getLogger(__name__)
RETENTION_EVERY_S = 3600.0


def is_reset(doc: dict | None) -> bool:
    """Whether a stored baseline document is a re-baseline's reset (service.engine_service.EngineService.rebaseline)."""
    return bool(doc and doc.get("reset"))


class DataDir:
    """--data-dir: the store (SQLite in WAL mode) at DIR/frictionwatch.db; each engine registered (its model
    version), begun as a new run and given back what the store kept (module doc); a StoreListener joins its fan-out.

    ``where``: the folder (a Path), or a store URL (a str, service/store: ``postgresql://...``). serve passes the
    folder only; the URL lets the same restart behaviour be checked on PostgreSQL
    (tests/service/test_restart_store_backends.py)."""

    def __init__(self, where: Path | str, keep_days: float | None = None,
                 retention_every_s: float = RETENTION_EVERY_S) -> None:
        if keep_days is not None and not keep_days > 0:
            raise ValueError(f"--keep-days must be > 0, got {keep_days}")
        if isinstance(where, Path):
            if where.exists() and not where.is_dir():
                raise NotADirectoryError(f"--data-dir {where} is a file, expected a folder")
            where.mkdir(parents=True, exist_ok=True)
            where = str(where / "frictionwatch.db")
        self.store = open_store(where)
        self._listener = StoreListener
        self.keep_days, self.retention_every_s = keep_days, retention_every_s
        self.retention: Counter[str] = Counter()  # rows deleted by table, sweeps, errors
        self._stop = threading.Event()
        self._retention_thread: threading.Thread | None = None

    def with_baseline(self, make):
        """An alerts factory (engine_id, spec) that gives the engine's newest stored baseline to ``make``."""
        def factory(engine_id, spec):
            saved = self.store.load_baseline(engine_id)
            if saved is None or is_reset(saved):
                return make(engine_id, spec)
            return make(engine_id, spec, baseline=Baseline.from_dict(saved))
        return factory

    def attach(self, svc: Any) -> str:
        """Register the engine, begin its run (the cycle numbering continued), give its alert engine back its
        alerts, and join the store to its fan-out (before ``svc.start``). Returns a line saying what was taken
        back."""
        store, engine_id = self.store, svc.engine_id
        store.register_engine(engine_id, svc.model.to_toml())
        run = store.begin_run(engine_id)
        svc.number_cycles_from(run.first_cycle)
        said = [f"{engine_id}: run {run.run_id}, cycles from {run.first_cycle}"]
        alerts = svc.alerts
        if alerts is not None and hasattr(alerts, "restore"):
            if is_reset(store.load_baseline(engine_id)):  # re-baselined last: not the commissioned one either
                alerts.baseline = None
            kept = store.load_alerts(engine_id)
            for line in alerts.restore(kept):
                log.warning("%s: a stored alert not taken back: %s", engine_id, line)
            n_open = sum(a["state"] != "cleared" for a in kept)
            bands = 0 if alerts.baseline is None else len(alerts.baseline.bands)
            said.append(f"{len(kept)} alerts taken back ({n_open} open), baseline of {bands} load bands")
        if run.run_id > 1:
            said.append("the smoothed estimates start again: the first cycles of this run are a warm-up")
        svc.add_listener(self._listener(store, engine_id))
        return "; ".join(said)

    def start_retention(self) -> None:
        """Sweep now and every ``retention_every_s`` on a thread of its own (no-op without ``keep_days``)."""
        if self.keep_days is None or self._retention_thread is not None:
            return
        self._retention_thread = threading.Thread(target=self._retention_loop, name="store-retention", daemon=True)
        self._retention_thread.start()

    def sweep(self) -> dict[str, int]:
        """One retention sweep; a failure is counted and logged, never raised (the service goes on)."""
        try:
            deleted = self.store.apply_retention(self.keep_days)
        except Exception as exc:  # noqa: BLE001 - a failed sweep is tried again at the next one
            self.retention["errors"] += 1
            log.warning("store retention failed: %s: %s", type(exc).__name__, exc)
            return {}
        self.retention.update(deleted)
        self.retention["sweeps"] += 1
        if any(deleted.values()):
            log.info("store retention: deleted %s (older than %g days)", deleted, self.keep_days)
        return deleted

    def _retention_loop(self) -> None:
        while True:
            self.sweep()
            if self._stop.wait(self.retention_every_s):
                return

    def close(self) -> None:
        self._stop.set()
        if self._retention_thread is not None:
            self._retention_thread.join(timeout=30.0)
        self.store.close()
