"""The store on a DB-API connection: one class for SQLite and PostgreSQL, their differences in ``Dialect``.

Rows go in and come out as the service contract's dicts (CycleSummary, CylinderLoss, Alert), read back as they were
written (service/store/columns.py maps them to columns).

Runs (issue 28): each start of a service is a run of each engine (``begin_run``; the first write begins one when
nobody did). A run numbers its cycles on from the newest cycle the store knows (``next_cycle``), every row written
carries its ``run_id``, and an upsert replaces only a row of its own run (a retried batch): a row of another run under
the same key is kept and the new one counted as refused (``write_batch``'s return), never silently overwritten.

Threads: one connection, every call under one lock, each write one transaction (``write_batch``: several kinds of
row in one). Other processes read the same SQLite file concurrently (WAL); PostgreSQL serves any number of clients.

A dropped connection (PostgreSQL: a server restart, a network cut, ``pg_terminate_backend``) is reopened: the call
that finds it gone fails with ``StoreUnavailable`` (a ``StoreError``), the next call reconnects, and while
reconnecting fails the calls fail at once with ``StoreUnavailable`` until the next attempt is due (backoff from
``RECONNECT_S[0]``, doubling, at most ``RECONNECT_S[1]``). ``connection`` counts it (lost, reconnects, failed
attempts). Whoever writes keeps what failed and writes it again (service/store/listener.py); a write whose COMMIT
was cut off is harmless to repeat (upserts of the run's own rows). SQLite is given no reopen: a file does not drop.
"""

from __future__ import annotations

import hashlib
import json
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from frictionwatch.service.store.columns import (
    ALERT_STATES,
    CYCLE_COLUMNS,
    LOSS_COLUMNS,
    StoreError,
    alert_params,
    cycle_params,
    extra_fields,
    from_columns,
    json_text,
    loss_params,
)
from frictionwatch.service.store.fleet import FleetStore
from frictionwatch.service.store.monitor_states import MonitorStateStore
from frictionwatch.service.store.schema import MIGRATIONS, SCHEMA_VERSION, VERSION_TABLE

log = logging.getLogger(__name__)
# reconnecting: the first attempt at the next call after the loss, then after 0.5 s, 1 s, 2 s, ... at most 30 s (a
# server restart takes seconds; 30 s bounds how late a store that is back is seen, at one cheap attempt per 30 s)
RECONNECT_S = (0.5, 30.0)


class StoreUnavailable(StoreError):
    """The store's connection is down (being reopened): what failed may be written again later."""


@dataclass(frozen=True)
class Dialect:
    """What differs between the backends. SQL is written with ``?`` placeholders."""

    name: str
    begin: str  # SQLite: BEGIN IMMEDIATE takes the write lock at once (no lock upgrade deadlock between writers)
    placeholder: str
    lock_rows: str  # appended to the SELECT of schema_version while migrating: one migrator at a time
    now: str  # the database's wall clock [Unix s] as an SQL expression: one clock for every process (leases)

    def sql(self, text: str) -> str:
        return text if self.placeholder == "?" else text.replace("?", self.placeholder)


@dataclass(frozen=True)
class Run:
    """One run of an engine: its id (1, 2, ... per engine), the wall-clock start [Unix s] and its first cycle index."""

    run_id: int
    started_at: float
    first_cycle: int
    model_version: int | None = field(default=None, compare=False)


class SqlStore(FleetStore, MonitorStateStore):
    """The store interface (service/store/__init__.py) on an open connection; ``migrate`` runs on construction.

    ``reopen`` (PostgreSQL) makes a new connection and ``is_lost(conn)`` says whether a failed connection is gone
    (module doc: reconnecting); without ``reopen`` a lost connection stays lost. ``errors``: the driver's exception
    classes, raised on as a one-line StoreError naming the store (the driver's error chained)."""

    def __init__(self, conn: Any, dialect: Dialect, where: str, reopen: Callable[[], Any] | None = None,
                 is_lost: Callable[[Any], bool] | None = None, reconnect_s: tuple[float, float] = RECONNECT_S,
                 errors: tuple[type[BaseException], ...] = ()) -> None:
        self._conn, self.dialect, self.where, self._errors = conn, dialect, where, errors
        self._reopen, self._is_lost, self._reconnect_s = reopen, is_lost, reconnect_s
        self._next_attempt, self._backoff_s = 0.0, reconnect_s[0]
        self.connection: Counter[str] = Counter()  # lost, reconnects, reconnect_failures
        self._lock = threading.RLock()
        self._model_version: dict[str, int] = {}
        self._run: dict[str, Run] = {}  # the run this store object writes for each engine
        self.schema_version = self._migrate()

    # ---- plumbing ---------------------------------------------------------------------------------------------
    @contextmanager
    def _cursor(self) -> Iterator[Any]:
        """A cursor on the open connection (reopened if it was lost and an attempt is due), under the lock."""
        with self._lock:
            cur = self._connected().cursor()
            try:
                yield cur
            except Exception as e:
                if self._reopen is not None and self._conn is not None and self._is_lost(self._conn):
                    self._lost(e)
                    raise StoreUnavailable(f"{self.where}: connection lost: {_one_line(e)}") from None
                if isinstance(e, self._errors):
                    raise StoreError(f"{self.where}: {_one_line(e)}") from e
                raise

    def _connected(self) -> Any:
        if self._conn is not None:
            return self._conn
        now = time.monotonic()
        if self._reopen is None:
            raise StoreUnavailable(f"{self.where}: the connection is closed")
        if now < self._next_attempt:
            raise StoreUnavailable(f"{self.where}: connection lost; next attempt in {self._next_attempt - now:.1f} s")
        try:
            conn = self._reopen()
        except Exception as e:  # noqa: BLE001 - any failure to connect is the same to the caller: not now
            self.connection["reconnect_failures"] += 1
            self._next_attempt = now + self._backoff_s
            self._backoff_s = min(2.0 * self._backoff_s, self._reconnect_s[1])
            raise StoreUnavailable(f"{self.where}: reconnecting failed ({_one_line(e)}); next attempt in "
                                   f"{self._next_attempt - now:.1f} s") from None
        self._conn, self._backoff_s = conn, self._reconnect_s[0]
        self.connection["reconnects"] += 1
        log.warning("%s: reconnected", self.where)
        return conn

    def _lost(self, e: BaseException) -> None:
        try:
            self._conn.close()
        except Exception:  # noqa: BLE001 - it is gone already
            pass
        self._conn, self._next_attempt = None, 0.0  # the next call tries at once; the backoff starts if that fails
        self.connection["lost"] += 1
        log.warning("%s: connection lost (%s); reopening it at the next call", self.where, _one_line(e))

    @contextmanager
    def _transaction(self) -> Iterator[Any]:
        with self._cursor() as cur:
            cur.execute(self.dialect.begin)
            try:
                yield cur
            except BaseException:
                try:
                    cur.execute("ROLLBACK")
                except Exception:  # noqa: BLE001 - the engine already rolled back (SQLite does on some errors)
                    pass
                raise
            cur.execute("COMMIT")

    def _x(self, cur: Any, sql: str, params: Sequence = ()) -> Any:
        cur.execute(self.dialect.sql(sql), tuple(params))
        return cur

    def _migrate(self) -> int:
        """Bring the schema up to SCHEMA_VERSION, one migration per transaction; refuse a newer one."""
        with self._transaction() as cur:
            cur.execute(VERSION_TABLE)
            rows = self._x(cur, "SELECT version FROM schema_version").fetchall()
            if not rows:
                self._x(cur, "INSERT INTO schema_version (version) VALUES (0)")
        while True:
            with self._transaction() as cur:
                version = int(self._x(cur, "SELECT version FROM schema_version" + self.dialect.lock_rows).fetchone()[0])
                if version > SCHEMA_VERSION:
                    raise StoreError(f"{self.where}: schema version {version} is newer than this frictionwatch knows "
                                     f"({SCHEMA_VERSION}); use a newer frictionwatch or another store")
                if version == SCHEMA_VERSION:
                    return version
                for statement in MIGRATIONS[version]:
                    cur.execute(statement)
                self._x(cur, "UPDATE schema_version SET version = ?", (version + 1,))

    def close(self) -> None:
        with self._lock:
            if self._conn is not None:
                self._conn.close()
            self._conn, self._reopen = None, None  # closed for good: no reconnect

    # ---- engines and model versions ---------------------------------------------------------------------------
    def register_engine(self, engine_id: str, engine_toml: str) -> int:
        """The engine's model version for this TOML: the newest one if its text is the same, else a new one."""
        digest = hashlib.sha256(engine_toml.encode()).hexdigest()
        now = time.time()
        with self._transaction() as cur:
            self._x(cur, "INSERT INTO engines (engine_id, created_at) VALUES (?, ?) ON CONFLICT (engine_id) DO NOTHING",
                    (engine_id, now))
            row = self._x(cur, "SELECT version, toml_sha256 FROM model_versions WHERE engine_id = ? "
                               "ORDER BY version DESC LIMIT 1", (engine_id,)).fetchone()
            if row is not None and row[1] == digest:
                version = int(row[0])
            else:
                version = 1 if row is None else int(row[0]) + 1
                self._x(cur, "INSERT INTO model_versions (engine_id, version, toml_sha256, engine_toml, registered_at) "
                             "VALUES (?, ?, ?, ?, ?)", (engine_id, version, digest, engine_toml, now))
        self._model_version[engine_id] = version
        return version

    def model_versions(self, engine_id: str) -> list[dict]:
        rows = self._query("SELECT version, toml_sha256, engine_toml, registered_at FROM model_versions "
                           "WHERE engine_id = ? ORDER BY version", (engine_id,))
        return [{"version": int(v), "toml_sha256": s, "engine_toml": t, "registered_at": a} for v, s, t, a in rows]

    def _version_of(self, engine_id: str) -> int:
        try:
            return self._model_version[engine_id]
        except KeyError:
            raise StoreError(f"engine {engine_id!r} is not registered in this store: register_engine first") from None

    # ---- runs ---------------------------------------------------------------------------------------------------
    def begin_run(self, engine_id: str) -> Run:
        """A new run of the engine, numbering its cycles from ``next_cycle``; the rows this store writes for the
        engine from now on carry its id."""
        version = self._version_of(engine_id)
        with self._transaction() as cur:
            run_id = int(self._x(cur, "SELECT COALESCE(MAX(run_id), 0) + 1 FROM runs WHERE engine_id = ?",
                                 (engine_id,)).fetchone()[0])
            run = Run(run_id, time.time(), self._next_cycle(cur, engine_id), version)
            self._x(cur, "INSERT INTO runs (engine_id, run_id, started_at, first_cycle, model_version) "
                         "VALUES (?, ?, ?, ?, ?)", (engine_id, run.run_id, run.started_at, run.first_cycle, version))
        self._run[engine_id] = run
        return run

    def forget_run(self, engine_id: str, run_id: int) -> bool:
        """Delete a run that wrote nothing (a start that failed before its first cycle: left, it would number the
        next start one further, and the run before it would look as if it had not stopped cleanly, so its saved
        monitor state would not be taken back). A run with any cycle, estimate, alert or baseline row is kept.
        Returns whether it was deleted."""
        with self._transaction() as cur:
            for table in ("cycles", "estimates", "alerts", "baselines"):
                if self._x(cur, f"SELECT 1 FROM {table} WHERE engine_id = ? AND run_id = ? LIMIT 1",
                           (engine_id, run_id)).fetchone() is not None:
                    return False
            self._x(cur, "DELETE FROM runs WHERE engine_id = ? AND run_id = ?", (engine_id, run_id))
        if self._run.get(engine_id) is not None and self._run[engine_id].run_id == run_id:
            del self._run[engine_id]
        return True

    def run_of(self, engine_id: str) -> Run:
        """The run this store object writes for the engine (begun now if none was)."""
        run = self._run.get(engine_id)
        return run if run is not None else self.begin_run(engine_id)

    def next_cycle(self, engine_id: str) -> int:
        """The first cycle index after everything the store knows of the engine (0 for a new one)."""
        with self._transaction() as cur:
            return self._next_cycle(cur, engine_id)

    def _next_cycle(self, cur: Any, engine_id: str) -> int:
        # runs.last_cycle survives retention; alerts and estimates name cycles too (a cycle row may be lost alone)
        row = self._x(cur, "SELECT MAX(c) FROM (SELECT MAX(cycle_index) AS c FROM cycles WHERE engine_id = ? "
                           "UNION ALL SELECT MAX(cycle_index) FROM estimates WHERE engine_id = ? "
                           "UNION ALL SELECT MAX(raised_cycle) FROM alerts WHERE engine_id = ? "
                           "UNION ALL SELECT MAX(last_cycle) FROM runs WHERE engine_id = ? "
                           "UNION ALL SELECT MAX(first_cycle) - 1 FROM runs WHERE engine_id = ?) AS known",
                      (engine_id,) * 5).fetchone()
        return 0 if row[0] is None else int(row[0]) + 1

    def runs(self, engine_id: str) -> list[dict]:
        rows = self._query("SELECT run_id, started_at, first_cycle, last_cycle, model_version FROM runs "
                           "WHERE engine_id = ? ORDER BY run_id", (engine_id,))
        return [{"run_id": int(r), "started_at": s, "first_cycle": int(f), "last_cycle": None if la is None
                 else int(la), "model_version": v} for r, s, f, la, v in rows]

    # ---- writes -----------------------------------------------------------------------------------------------
    def write_cycles(self, engine_id: str, rows: Sequence[dict]) -> int:
        return self.write_batch(engine_id, cycles=rows)

    def write_estimate(self, engine_id: str, cycle_index: int, cylinders: Sequence[dict]) -> int:
        return self.write_batch(engine_id, estimates=[(cycle_index, cylinders)])

    def upsert_alert(self, engine_id: str, alert: dict) -> int:
        return self.write_batch(engine_id, alerts=[alert])

    def write_batch(self, engine_id: str, cycles: Sequence[dict] = (),
                    estimates: Sequence[tuple[int, Sequence[dict]]] = (), alerts: Sequence[dict] = (),
                    engine_figure: dict | None = None) -> int:
        """Cycle summaries, per-cylinder estimates and alerts in one transaction: all of them or none. Returns the
        number of rows refused (module doc: a row of another run under the same key is kept, the new one dropped).
        The newest cycle becomes the engine's row in ``engine_latest`` (the fleet view), with ``engine_figure``
        (the engine's friction figure at that cycle: fmep_bar, fmep_sigma_bar, status, reason) when given.

        A row this run already stored under the same key (engine, cycle[, cylinder]) is replaced: a retried batch
        writes the same rows again. An alert (engine, alert_id) is replaced by a later state of the same alert (the
        same kind raised at the same cycle), whichever run writes it: an alert lives across restarts."""
        version, now = self._version_of(engine_id), time.time()
        run = self.run_of(engine_id).run_id
        cycle_rows = [(*cycle_params(engine_id, version, r, now), run) for r in cycles]
        loss_rows = [(*loss_params(engine_id, int(i), c, now), run) for i, cyls in estimates for c in cyls]
        alert_rows = [(*alert_params(engine_id, a, now), run) for a in alerts]
        same_run = "{t}.run_id = excluded.run_id"
        written = 0
        with self._transaction() as cur:
            if cycle_rows:
                cur.executemany(self.dialect.sql(_upsert("cycles", ("engine_id", "cycle_index", "model_version",
                                                                    *CYCLE_COLUMNS, "extra", "written_at", "run_id"),
                                                         2, same_run)), cycle_rows)
                written += cur.rowcount
                self._x(cur, "UPDATE runs SET last_cycle = ? WHERE engine_id = ? AND run_id = ? AND "
                             "(last_cycle IS NULL OR last_cycle < ?)",
                        (max(r[1] for r in cycle_rows), engine_id, run, max(r[1] for r in cycle_rows)))
                self._latest(cur, engine_id, run, max(cycles, key=lambda r: int(r["cycle_index"])), engine_figure)
            if loss_rows:
                cur.executemany(self.dialect.sql(_upsert("estimates", ("engine_id", "cycle_index", "cylinder",
                                                                       *LOSS_COLUMNS, "extra", "written_at", "run_id"),
                                                         3, same_run)), loss_rows)
                written += cur.rowcount
            if alert_rows:
                cur.executemany(self.dialect.sql(_upsert("alerts", ("engine_id", "alert_id", "cylinder", "kind",
                                                                    "severity", "state", "raised_cycle", "doc",
                                                                    "updated_at", "run_id"), 2, SAME_ALERT)),
                                alert_rows)
                written += cur.rowcount
        return len(cycle_rows) + len(loss_rows) + len(alert_rows) - written

    def save_baseline(self, engine_id: str, baseline: dict) -> None:
        """Kept beside every earlier one (auditable); ``load_baseline`` gives the newest."""
        self._version_of(engine_id)
        run = self.run_of(engine_id).run_id
        with self._transaction() as cur:
            seq = self._x(cur, "SELECT COALESCE(MAX(seq), 0) + 1 FROM baselines WHERE engine_id = ?",
                          (engine_id,)).fetchone()[0]
            self._x(cur, "INSERT INTO baselines (engine_id, seq, doc, saved_at, run_id) VALUES (?, ?, ?, ?, ?)",
                    (engine_id, int(seq), json_text(baseline), time.time(), run))

    # ---- reads ------------------------------------------------------------------------------------------------
    def _query(self, sql: str, params: Sequence = ()) -> list[tuple]:
        with self._cursor() as cur:
            return self._x(cur, sql, params).fetchall()

    def latest_cycle(self, engine_id: str) -> int | None:
        value = self._query("SELECT MAX(cycle_index) FROM cycles WHERE engine_id = ?", (engine_id,))[0][0]
        return None if value is None else int(value)

    def cycles(self, engine_id: str, first: int, last: int) -> list[dict]:
        """The CycleSummary rows with first <= cycle_index <= last, in order (``model_version`` and ``run_id``
        added; run_id None: written before runs were recorded)."""
        rows = self._query(f"SELECT cycle_index, model_version, run_id, {', '.join(CYCLE_COLUMNS)}, extra FROM cycles "
                           "WHERE engine_id = ? AND cycle_index BETWEEN ? AND ? ORDER BY cycle_index",
                           (engine_id, int(first), int(last)))
        return [{"engine_id": engine_id, "cycle_index": int(r[0]), "model_version": r[1], "run_id": r[2],
                 **from_columns(CYCLE_COLUMNS, r[3:-1]), **extra_fields(r[-1])} for r in rows]

    def estimates(self, engine_id: str, first: int, last: int) -> list[dict]:
        """The CylinderLoss rows kept for cycles first..last, each with its ``cycle_index`` and ``run_id``, by cycle
        and cylinder."""
        rows = self._query(f"SELECT cycle_index, cylinder, run_id, {', '.join(LOSS_COLUMNS)}, extra FROM estimates "
                           "WHERE engine_id = ? AND cycle_index BETWEEN ? AND ? ORDER BY cycle_index, cylinder",
                           (engine_id, int(first), int(last)))
        return [{"cycle_index": int(r[0]), "cylinder": int(r[1]), "run_id": r[2], **from_columns(LOSS_COLUMNS, r[3:-1]),
                 **extra_fields(r[-1])} for r in rows]

    def load_alerts(self, engine_id: str, state: str | None = None) -> list[dict]:
        """Every alert of the engine (state None) or those in one state, by alert_id."""
        if state is None:
            rows = self._query("SELECT doc FROM alerts WHERE engine_id = ? ORDER BY alert_id", (engine_id,))
        elif state in ALERT_STATES:
            rows = self._query("SELECT doc FROM alerts WHERE engine_id = ? AND state = ? ORDER BY alert_id",
                               (engine_id, state))
        else:
            raise StoreError(f"unknown alert state {state!r}; known: {', '.join(ALERT_STATES)}")
        return [json.loads(r[0]) for r in rows]

    def load_baseline(self, engine_id: str) -> dict | None:
        rows = self._query("SELECT doc FROM baselines WHERE engine_id = ? ORDER BY seq DESC LIMIT 1", (engine_id,))
        return json.loads(rows[0][0]) if rows else None

    # ---- retention --------------------------------------------------------------------------------------------
    def apply_retention(self, keep_days: float, now: float | None = None, batch_rows: int = 5000,
                        engine_ids: Sequence[str] | None = None) -> dict[str, int]:
        """Delete cycles and estimates written more than ``keep_days`` ago, ``batch_rows`` per transaction (a
        writer waits for one batch at most, never for the whole sweep); only those of ``engine_ids`` when given (a
        database several processes share: each sweeps its own engines). Alerts, baselines and model versions are
        kept whatever their age. Returns the rows deleted per table."""
        if not (keep_days > 0 and batch_rows > 0):
            raise StoreError(f"retention needs keep_days > 0 and batch_rows > 0, got {keep_days}, {batch_rows}")
        cutoff = (time.time() if now is None else now) - keep_days * 86400.0
        if engine_ids is not None and not engine_ids:
            return {"cycles": 0, "estimates": 0}
        only = "" if engine_ids is None else f" AND engine_id IN ({', '.join('?' * len(engine_ids))})"
        deleted = {}
        for table, key in (("cycles", "engine_id, cycle_index"), ("estimates", "engine_id, cycle_index, cylinder")):
            deleted[table] = 0
            while True:
                with self._transaction() as cur:
                    n = self._x(cur, f"DELETE FROM {table} WHERE ({key}) IN (SELECT {key} FROM {table} "
                                     f"WHERE written_at < ?{only} LIMIT ?)",
                                (cutoff, *(engine_ids or ()), batch_rows)).rowcount
                deleted[table] += n
                if n < batch_rows:
                    break
        return deleted


def _one_line(e: BaseException) -> str:
    text = str(e).strip()
    return f"{type(e).__name__}: {text.splitlines()[0] if text else ''}"


# an alert row is another state of the same alert when its kind and raised cycle agree (an alert engine that had
# lost its ids would otherwise overwrite an older alert with a new one under the same id)
SAME_ALERT = "{t}.kind = excluded.kind AND COALESCE({t}.raised_cycle, -1) = COALESCE(excluded.raised_cycle, -1)"


def _upsert(table: str, columns: Sequence[str], n_key: int, only_if: str) -> str:
    """INSERT ... ON CONFLICT (key) DO UPDATE ... WHERE ``only_if`` (``{t}``: the table): SQLite >= 3.24 and
    PostgreSQL read the same text. A conflicting row that fails ``only_if`` is left as it is (rowcount 0)."""
    key, rest = columns[:n_key], columns[n_key:]
    return (f"INSERT INTO {table} ({', '.join(columns)}) VALUES ({', '.join('?' * len(columns))}) "
            f"ON CONFLICT ({', '.join(key)}) DO UPDATE SET {', '.join(f'{c} = excluded.{c}' for c in rest)} "
            f"WHERE {only_if.format(t=table)}")
