"""`serve --data-dir DIR` or `serve --store postgresql://...`: what a restarted service takes back from its store
(service/store), one writer per engine id, and the retention that keeps the store from growing for ever.

At start, per engine (``DataDir.attach``): a new run in the store (issue 28), the cycle numbering continued after
the newest cycle stored (a restart appends, never overwrites), the alert history and open alerts with their
acknowledgements taken back into the alert engine (ids numbered on), and the newest learnt baseline (every load
band and friction reference learnt so far, saved as learnt) in force, so nothing is relearnt and a ring worn while
the service was down is not learnt as the healthy state. A re-baseline saved as a reset keeps the old baseline out.

The monitor's smoothed estimates (its whole carried state: accumulated information, tooth learner, sensor and
condition state, the calibration watches) are saved at a clean stop (``close``, after the engines stopped) and, while
the engines run, every ``checkpoint_s`` (a checkpoint: pickled between two records under the monitor's lock, ~ms,
stored from a thread of its own), and taken back at the next start when it is the very next run of the engine, with
the same engine model (model version) and the same core/ code (service/monitor_snapshot.py: its fingerprint; the text
is read without loading any code). After a ``kill -9`` that is the newest checkpoint: the start line says from which
cycle, and the cycles stored after it are not in the smoothed estimates (they were analysed and stored; the estimates
go on as after a data gap). Else they start again as at a first start: the first cycles of the run are its warm-up
(with the 4 h forgetting, hours of it), and the start line says which and why. Not restored: the EWMA / latch counts of the alert statistics; a
band being learnt when the service stopped is learnt again from its first cycle.

One writer per engine id (service/store/fleet.py): ``attach`` claims the engine's lease before anything else and
refuses (StoreError, one line) an engine another live process writes; a thread renews the leases every
``HEARTBEAT_S`` and logs, counts (``leases``) and tries to take back a lease it finds lost; ``close`` releases them.

Retention (``--keep-days N``): cycles and estimates written more than N days ago are deleted at start and then
every hour, in batches (service.store.sql_store.SqlStore.apply_retention); alerts, baselines, runs and model
versions are kept whatever their age. In a ``--data-dir`` (this process's own file) every engine is swept; in a
``--store`` URL (a database other processes may share) only the engines this process attached.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from pathlib import Path
from typing import Any

from frictionwatch.service.alert_baseline import Baseline
from frictionwatch.service.monitor_snapshot import SnapshotError, encode, fingerprint, loads
from frictionwatch.service.store import StoreError, StoreListener, open_store
from frictionwatch.service.store.fleet import HEARTBEAT_S, LEASE_TIMEOUT_S, Writer

log = logging.getLogger(__name__)
RETENTION_EVERY_S = 3600.0
# how often a running engine's monitor state is saved against a crash: what a kill -9 loses of the smoothed
# estimates (~1.5 MB stored per genset-v20 each time; the pickling holds its monitor ~ms)
CHECKPOINT_S = 600.0


def is_reset(doc: dict | None) -> bool:
    """Whether a stored baseline document is a re-baseline's reset (service.engine_service.EngineService.rebaseline)."""
    return bool(doc and doc.get("reset"))


class DataDir:
    """--data-dir: the store (SQLite in WAL mode) at DIR/frictionwatch.db; each engine registered (its model
    version), begun as a new run and given back what the store kept (module doc); a StoreListener joins its fan-out.

    ``where``: the folder (a Path: ``--data-dir``), or a store URL (a str: ``--store``, service/store:
    ``postgresql://...``, shared with other processes). ``lease_timeout_s``, ``heartbeat_s``: the leases'
    (service/store/fleet.py; shorter in tests)."""

    def __init__(self, where: Path | str, keep_days: float | None = None,
                 retention_every_s: float = RETENTION_EVERY_S, lease_timeout_s: float = LEASE_TIMEOUT_S,
                 heartbeat_s: float = HEARTBEAT_S, checkpoint_s: float = CHECKPOINT_S) -> None:
        if keep_days is not None and not keep_days > 0:
            raise ValueError(f"--keep-days must be > 0, got {keep_days}")
        if not checkpoint_s > 0:
            raise ValueError(f"--checkpoint-s must be > 0, got {checkpoint_s}")
        if not 0 < heartbeat_s < lease_timeout_s:
            raise ValueError(f"need 0 < heartbeat_s < lease_timeout_s, got {heartbeat_s}, {lease_timeout_s}")
        self.shared = not isinstance(where, Path)
        if isinstance(where, Path):
            if where.exists() and not where.is_dir():
                raise NotADirectoryError(f"--data-dir {where} is a file, expected a folder")
            where.mkdir(parents=True, exist_ok=True)
            where = str(where / "frictionwatch.db")
        self.store = open_store(where)
        self._listener = StoreListener
        self.listeners: dict[str, StoreListener] = {}
        self.keep_days, self.retention_every_s = keep_days, retention_every_s
        self.retention: Counter[str] = Counter()  # rows deleted by table, sweeps, errors
        self.writer, self.lease_timeout_s, self.heartbeat_s = Writer.this_process(), lease_timeout_s, heartbeat_s
        self.engines: list[str] = []  # the engines this process writes (holds the lease of)
        self.leases: Counter[str] = Counter()  # heartbeats, heartbeat_errors, lost, taken_back
        self._stop = threading.Event()
        self._retention_thread: threading.Thread | None = None
        self._heartbeat_thread: threading.Thread | None = None
        self._services: list[Any] = []  # the engines attached: their monitor state is saved at close
        self.runs: dict[str, Any] = {}  # the run each attached engine began
        self.checkpoint_s = checkpoint_s
        self.checkpoints: Counter[str] = Counter()  # saved, errors
        self._checkpoint_thread: threading.Thread | None = None

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
        took_over = store.claim_engine(engine_id, self.writer, self.lease_timeout_s)  # StoreError: another writes it
        self.engines.append(engine_id)
        self._start_heartbeat()
        store.register_engine(engine_id, svc.model.to_toml())
        run = self.runs[engine_id] = store.begin_run(engine_id)
        svc.number_cycles_from(run.first_cycle)
        said = [f"{engine_id}: run {run.run_id}, cycles from {run.first_cycle}"]
        if took_over is not None:
            said.append(f"the lease of {took_over} taken over")
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
            said.append(self._resume(svc, run))
        self._services.append(svc)
        listener = self.listeners[engine_id] = self._listener(store, engine_id)
        svc.add_listener(listener)
        return "; ".join(said)

    def _resume(self, svc: Any, run: Any) -> str:
        """Take back the monitor state the engine's previous run saved at its stop, if it may (module doc)."""
        try:
            saved = self.store.load_monitor_state(svc.engine_id)
        except StoreError as exc:  # optional: a start is not refused for it
            log.warning("%s: the saved monitor state not read: %s", svc.engine_id, exc)
            saved, why = None, f"it could not be read: {exc}"
        else:
            why = _why_not(saved, run)
        if saved is not None and why is None:
            try:
                svc.resume_monitor(loads(saved["doc"]))
                return f"the smoothed estimates taken back from run {saved['run_id']} ({self._when(saved, run)})"
            except (SnapshotError, ValueError) as exc:
                log.warning("%s: the saved monitor state not taken back: %s", svc.engine_id, exc)
                why = f"the saved state did not fit: {exc}"
        return f"the smoothed estimates start again ({why}): the first cycles of this run are a warm-up"

    @staticmethod
    def _when(saved: dict, run: Any) -> str:
        """Whether a taken-back state was saved at its run's stop or is a checkpoint from before a crash."""
        last = run.first_cycle - 1  # the newest cycle the store knew when this run began
        at = saved.get("last_cycle")
        if at is None or at >= last:
            return "saved at its stop"
        return (f"a checkpoint at cycle {at}: it did not stop cleanly, and its {last - at} cycles after the "
                "checkpoint are stored but not in the smoothed estimates")

    def save_states(self) -> int:
        """Save each attached engine's monitor state (after its stop; one still running is skipped and logged).
        Returns how many were saved; a failure is logged, never raised."""
        for svc in self._services:
            if svc.running:
                log.warning("%s: still running at close: its monitor state is not saved", svc.engine_id)
        return self._save_states([s for s in self._services if not s.running], "at the stop")

    def _start_heartbeat(self) -> None:
        if self._heartbeat_thread is None:
            self._heartbeat_thread = threading.Thread(target=self._heartbeat_loop, name="store-leases", daemon=True)
            self._heartbeat_thread.start()

    def _heartbeat_loop(self) -> None:
        while not self._stop.wait(self.heartbeat_s):
            self.renew()

    def renew(self) -> list[str]:
        """Renew this process's leases; one it no longer holds (taken over while the store was out of reach for
        longer than the timeout) is logged, counted and claimed back when its holder is gone. Returns those lost."""
        try:
            lost = self.store.heartbeat(list(self.engines), self.writer)
        except Exception as exc:  # noqa: BLE001 - the store down: the next heartbeat tries again
            self.leases["heartbeat_errors"] += 1
            log.warning("store leases: heartbeat failed: %s: %s", type(exc).__name__, exc)
            return []
        self.leases["heartbeats"] += 1
        for engine_id in lost:
            self.leases["lost"] += 1
            try:
                self.store.claim_engine(engine_id, self.writer, self.lease_timeout_s)
                self.leases["taken_back"] += 1
                log.error("store leases: %s: the lease had been lost (the store out of reach too long?) and is "
                          "taken back", engine_id)
            except StoreError as exc:
                log.error("store leases: %s: lost to another writer, whose rows and ours now compete: %s",
                          engine_id, exc)
        return lost

    def start_checkpoints(self) -> None:
        """Save each running engine's monitor state every ``checkpoint_s`` on a thread of its own (module doc)."""
        if self._checkpoint_thread is None:
            self._checkpoint_thread = threading.Thread(target=self._checkpoint_loop, name="store-checkpoints",
                                                       daemon=True)
            self._checkpoint_thread.start()

    def checkpoint(self) -> int:
        """Save each running engine's monitor state now; returns how many were saved. A failure is counted and
        logged, never raised."""
        saved = self._save_states([s for s in self._services if s.running], "checkpoint")
        self.checkpoints["saved"] += saved
        return saved

    def _save_states(self, services: list, what: str) -> int:
        """Each of ``services``' monitor state as its monitor holds it between two records
        (EngineService.monitor_checkpoint), stored; how many were. A failure is logged (and for checkpoints counted),
        never raised: the next checkpoint tries again, the next start is a warm-up that says so."""
        saved, code = 0, None
        for svc in services:
            try:
                taken = svc.monitor_checkpoint()
                if taken is None:  # before the first cycle
                    continue
                code = code or fingerprint()
                self.store.save_monitor_state(svc.engine_id, code, encode(taken[0]), taken[1])
                saved += 1
            except Exception as exc:  # noqa: BLE001 - see the docstring
                if what == "checkpoint":
                    self.checkpoints["errors"] += 1
                log.warning("%s: the monitor state (%s) not saved: %s: %s", svc.engine_id, what,
                            type(exc).__name__, exc)
        return saved

    def _checkpoint_loop(self) -> None:
        while not self._stop.wait(self.checkpoint_s):
            self.checkpoint()

    def start_retention(self) -> None:
        """Sweep now and every ``retention_every_s`` on a thread of its own (no-op without ``keep_days``)."""
        if self.keep_days is None or self._retention_thread is not None:
            return
        self._retention_thread = threading.Thread(target=self._retention_loop, name="store-retention", daemon=True)
        self._retention_thread.start()

    def sweep(self) -> dict[str, int]:
        """One retention sweep; a failure is counted and logged, never raised (the service goes on)."""
        try:
            deleted = self.store.apply_retention(self.keep_days, engine_ids=list(self.engines) if self.shared else None)
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

    def close(self, failed_start: bool = False) -> None:
        """Stop the threads (a checkpoint in flight finishes first, so none lands after the stop's save), save the
        stopped engines' monitor states, release the leases (a successor may start at once) and close the store.
        ``failed_start``: serve did not come up; the runs it began are forgotten where they wrote nothing
        (SqlStore.forget_run) and no monitor state is saved (none was made by this run)."""
        self._stop.set()
        for thread in (self._checkpoint_thread, self._retention_thread, self._heartbeat_thread):
            if thread is not None:
                thread.join(timeout=30.0)
        if failed_start:
            for engine_id, run in self.runs.items():
                try:
                    self.store.forget_run(engine_id, run.run_id)
                except Exception as exc:  # noqa: BLE001 - an empty run left behind is logged, not raised
                    log.warning("%s: the failed start's run %d not forgotten: %s", engine_id, run.run_id, exc)
        else:
            self.save_states()
        try:
            self.store.release(list(self.engines), self.writer)
        except Exception as exc:  # noqa: BLE001 - they go stale after the timeout instead
            log.warning("store leases: not released (stale after %g s): %s: %s", self.lease_timeout_s,
                        type(exc).__name__, exc)
        self.store.close()


def _why_not(saved: dict | None, run: Any) -> str | None:
    """Why a saved monitor state may not be taken back by ``run`` (None: it may)."""
    if saved is None:
        return "no earlier run saved one (at a clean stop or a checkpoint)"
    if saved["run_id"] != run.run_id - 1:
        return f"the saved state is run {saved['run_id']}'s; run {run.run_id - 1} did not stop cleanly"
    if saved["model_version"] != run.model_version:
        return "the engine model changed"
    if saved["fingerprint"] != fingerprint():
        return "the saved state was made by another version of frictionwatch's core"
    return None
