"""The store on a DB-API connection: one class for SQLite and PostgreSQL, their differences in ``Dialect``.

Rows go in and come out as the service contract's dicts (CycleSummary, CylinderLoss, Alert; docs in
service/store/__init__.py): known keys in columns, any key a helper added later in an ``extra`` JSON column, so a
row reads back as it was written. Non-finite numbers are stored as NULL and read back as None (the project's
convention: a value the data cannot give is None, never a number).

Threads: one connection, every call under one lock, each write one transaction (``write_batch``: several kinds of
row in one). Other processes read the same SQLite file concurrently (WAL); PostgreSQL serves any number of clients.
"""

from __future__ import annotations

import hashlib
import json
import math
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
from frictionwatch.service.store.schema import MIGRATIONS, SCHEMA_VERSION, VERSION_TABLE

CYCLE_COLUMNS = ("t_start_s", "rpm_mean", "load_torque_nm", "load_power_kw", "imep_bar", "pmax_bar",
                 "friction_balance_nm", "flags")
LOSS_COLUMNS = ("fmep_bar", "fmep_sigma_bar", "friction_torque_mean_nm", "friction_torque_sigma_nm", "coefficients",
                "coefficient_sigmas", "data_weight", "status", "reason", "flags")
JSON_COLUMNS = frozenset({"imep_bar", "pmax_bar", "flags", "coefficients", "coefficient_sigmas"})
ALERT_STATES = ("active", "acknowledged", "cleared")


class StoreError(Exception):
    """An expected failure of the store, said in one line (a newer schema, a malformed row, an unknown engine)."""


@dataclass(frozen=True)
class Dialect:
    """What differs between the backends. SQL is written with ``?`` placeholders."""

    name: str
    begin: str  # SQLite: BEGIN IMMEDIATE takes the write lock at once (no lock upgrade deadlock between writers)
    placeholder: str
    lock_rows: str  # appended to the SELECT of schema_version while migrating: one migrator at a time

    def sql(self, text: str) -> str:
        return text if self.placeholder == "?" else text.replace("?", self.placeholder)


class SqlStore:
    """The store interface (service/store/__init__.py) on an open connection; ``migrate`` runs on construction."""

    def __init__(self, conn: Any, dialect: Dialect, where: str) -> None:
        self._conn, self.dialect, self.where = conn, dialect, where
        self._lock = threading.RLock()
        self._model_version: dict[str, int] = {}
        self.schema_version = self._migrate()

    # ---- plumbing ---------------------------------------------------------------------------------------------
    @contextmanager
    def _transaction(self) -> Iterator[Any]:
        with self._lock:
            cur = self._conn.cursor()
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
            self._conn.close()

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
        with self._lock:
            rows = self._x(self._conn.cursor(), "SELECT version, toml_sha256, engine_toml, registered_at FROM "
                                                "model_versions WHERE engine_id = ? ORDER BY version",
                           (engine_id,)).fetchall()
        return [{"version": int(v), "toml_sha256": s, "engine_toml": t, "registered_at": a} for v, s, t, a in rows]

    def _version_of(self, engine_id: str) -> int:
        try:
            return self._model_version[engine_id]
        except KeyError:
            raise StoreError(f"engine {engine_id!r} is not registered in this store: register_engine first") from None

    # ---- writes -----------------------------------------------------------------------------------------------
    def write_cycles(self, engine_id: str, rows: Sequence[dict]) -> None:
        self.write_batch(engine_id, cycles=rows)

    def write_estimate(self, engine_id: str, cycle_index: int, cylinders: Sequence[dict]) -> None:
        self.write_batch(engine_id, estimates=[(cycle_index, cylinders)])

    def upsert_alert(self, engine_id: str, alert: dict) -> None:
        self.write_batch(engine_id, alerts=[alert])

    def write_batch(self, engine_id: str, cycles: Sequence[dict] = (),
                    estimates: Sequence[tuple[int, Sequence[dict]]] = (), alerts: Sequence[dict] = ()) -> None:
        """Cycle summaries, per-cylinder estimates and alerts in one transaction: all of them or none.

        A row already stored under the same key (engine, cycle[, cylinder]; engine, alert_id) is replaced: a
        retried batch writes the same rows again, and an alert changes state over its life."""
        version, now = self._version_of(engine_id), time.time()
        cycle_params = [_cycle_params(engine_id, version, r, now) for r in cycles]
        loss_params = [_loss_params(engine_id, int(i), c, now) for i, cyls in estimates for c in cyls]
        alert_params = [_alert_params(engine_id, a, now) for a in alerts]
        with self._transaction() as cur:
            if cycle_params:
                cur.executemany(self.dialect.sql(_upsert("cycles", ("engine_id", "cycle_index", "model_version",
                                                                    *CYCLE_COLUMNS, "extra", "written_at"), 2)),
                                cycle_params)
            if loss_params:
                cur.executemany(self.dialect.sql(_upsert("estimates", ("engine_id", "cycle_index", "cylinder",
                                                                       *LOSS_COLUMNS, "extra", "written_at"), 3)),
                                loss_params)
            if alert_params:
                cur.executemany(self.dialect.sql(_upsert("alerts", ("engine_id", "alert_id", "cylinder", "kind",
                                                                    "severity", "state", "raised_cycle", "doc",
                                                                    "updated_at"), 2)), alert_params)

    def save_baseline(self, engine_id: str, baseline: dict) -> None:
        self._version_of(engine_id)
        with self._transaction() as cur:
            seq = self._x(cur, "SELECT COALESCE(MAX(seq), 0) + 1 FROM baselines WHERE engine_id = ?",
                          (engine_id,)).fetchone()[0]
            self._x(cur, "INSERT INTO baselines (engine_id, seq, doc, saved_at) VALUES (?, ?, ?, ?)",
                    (engine_id, int(seq), _json(baseline), time.time()))

    # ---- reads ------------------------------------------------------------------------------------------------
    def _query(self, sql: str, params: Sequence = ()) -> list[tuple]:
        with self._lock:
            return self._x(self._conn.cursor(), sql, params).fetchall()

    def latest_cycle(self, engine_id: str) -> int | None:
        value = self._query("SELECT MAX(cycle_index) FROM cycles WHERE engine_id = ?", (engine_id,))[0][0]
        return None if value is None else int(value)

    def cycles(self, engine_id: str, first: int, last: int) -> list[dict]:
        """The CycleSummary rows with first <= cycle_index <= last, in order (``model_version`` added)."""
        rows = self._query(f"SELECT cycle_index, model_version, {', '.join(CYCLE_COLUMNS)}, extra FROM cycles "
                           "WHERE engine_id = ? AND cycle_index BETWEEN ? AND ? ORDER BY cycle_index",
                           (engine_id, int(first), int(last)))
        return [{"engine_id": engine_id, "cycle_index": int(r[0]), "model_version": r[1],
                 **_from_columns(CYCLE_COLUMNS, r[2:-1]), **_extra(r[-1])} for r in rows]

    def estimates(self, engine_id: str, first: int, last: int) -> list[dict]:
        """The CylinderLoss rows kept for cycles first..last, each with its ``cycle_index``, by cycle and cylinder."""
        rows = self._query(f"SELECT cycle_index, cylinder, {', '.join(LOSS_COLUMNS)}, extra FROM estimates "
                           "WHERE engine_id = ? AND cycle_index BETWEEN ? AND ? ORDER BY cycle_index, cylinder",
                           (engine_id, int(first), int(last)))
        return [{"cycle_index": int(r[0]), "cylinder": int(r[1]), **_from_columns(LOSS_COLUMNS, r[2:-1]),
                 **_extra(r[-1])} for r in rows]

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
    def apply_retention(self, keep_days: float, now: float | None = None, batch_rows: int = 5000) -> dict[str, int]:
        """Delete cycles and estimates written more than ``keep_days`` ago, ``batch_rows`` per transaction (a
        writer waits for one batch at most, never for the whole sweep). Alerts, baselines and model versions are
        kept whatever their age. Returns the rows deleted per table."""
        if not (keep_days > 0 and batch_rows > 0):
            raise StoreError(f"retention needs keep_days > 0 and batch_rows > 0, got {keep_days}, {batch_rows}")
        cutoff = (time.time() if now is None else now) - keep_days * 86400.0
        deleted = {}
        for table, key in (("cycles", "engine_id, cycle_index"), ("estimates", "engine_id, cycle_index, cylinder")):
            deleted[table] = 0
            while True:
                with self._transaction() as cur:
                    n = self._x(cur, f"DELETE FROM {table} WHERE ({key}) IN (SELECT {key} FROM {table} "
                                     "WHERE written_at < ? LIMIT ?)", (cutoff, batch_rows)).rowcount
                deleted[table] += n
                if n < batch_rows:
                    break
        return deleted


def _upsert(table: str, columns: Sequence[str], n_key: int) -> str:
    """INSERT ... ON CONFLICT (key) DO UPDATE: SQLite >= 3.24 and PostgreSQL read the same text."""
    key, rest = columns[:n_key], columns[n_key:]
    return (f"INSERT INTO {table} ({', '.join(columns)}) VALUES ({', '.join('?' * len(columns))}) "
            f"ON CONFLICT ({', '.join(key)}) DO UPDATE SET {', '.join(f'{c} = excluded.{c}' for c in rest)}")


def _finite(value: Any) -> Any:
    """Non-finite floats -> None, through lists and dicts (numpy scalars become floats)."""
    if isinstance(value, dict):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, np.ndarray):
        return _finite(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _json(value: Any) -> str:
    try:  # the common case: plain JSON, all numbers finite (the contract's dicts)
        return json.dumps(value, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError):  # numpy values, NaN or inf somewhere: the slow walk
        return json.dumps(_finite(value), separators=(",", ":"), allow_nan=False)


def _column(name: str, value: Any) -> Any:
    if name in JSON_COLUMNS:
        return _json(value)
    if isinstance(value, str) or value is None:
        return value
    v = float(value)
    return v if math.isfinite(v) else None


def _from_columns(names: Sequence[str], values: Sequence) -> dict:
    return {n: json.loads(v) if n in JSON_COLUMNS else v for n, v in zip(names, values)}


def _extra(text: str | None) -> dict:
    return json.loads(text) if text else {}


def _take(row: dict, names: Sequence[str], what: str) -> list:
    missing = [n for n in names if n not in row]
    if missing:
        raise StoreError(f"{what} lacks {', '.join(missing)}")
    return [_column(n, row[n]) for n in names]


def _extra_of(row: dict, known: Sequence[str]) -> str | None:
    rest = {k: v for k, v in row.items() if k not in known}
    return _json(rest) if rest else None


def _cycle_params(engine_id: str, version: int, row: dict, now: float) -> tuple:
    if "cycle_index" not in row:
        raise StoreError("cycle row lacks cycle_index")
    values = _take(row, CYCLE_COLUMNS, f"cycle row {row['cycle_index']}")
    known = ("engine_id", "cycle_index", "model_version", *CYCLE_COLUMNS)
    return (engine_id, int(row["cycle_index"]), version, *values, _extra_of(row, known), now)


def _loss_params(engine_id: str, cycle_index: int, row: dict, now: float) -> tuple:
    if "cylinder" not in row:
        raise StoreError(f"estimate row of cycle {cycle_index} lacks cylinder")
    values = _take(row, LOSS_COLUMNS, f"estimate row of cycle {cycle_index} cylinder {row['cylinder']}")
    known = ("engine_id", "cycle_index", "cylinder", *LOSS_COLUMNS)
    return (engine_id, cycle_index, int(row["cylinder"]), *values, _extra_of(row, known), now)


def _alert_params(engine_id: str, alert: dict, now: float) -> tuple:
    missing = [k for k in ("alert_id", "kind", "severity", "state") if k not in alert]
    if missing:
        raise StoreError(f"alert lacks {', '.join(missing)}")
    if alert["state"] not in ALERT_STATES:
        raise StoreError(f"alert {alert['alert_id']}: unknown state {alert['state']!r}")
    cyl, raised = alert.get("cylinder"), alert.get("raised_cycle")
    return (engine_id, int(alert["alert_id"]), None if cyl is None else int(cyl), str(alert["kind"]),
            str(alert["severity"]), str(alert["state"]), None if raised is None else int(raised),
            _json({**alert, "engine_id": engine_id}), now)
