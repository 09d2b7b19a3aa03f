"""What several processes writing one store share (issue 28 item 7): one writer per engine id, and a fleet view.

    me = Writer.this_process()                          # host, pid and a token of this start
    store.claim_engine("genset-1", me)                  # or StoreError: another live process writes genset-1
    store.heartbeat(["genset-1"], me) -> [ids lost]     # every HEARTBEAT_S; [] while the leases are this process's
    store.release(["genset-1"], me)                     # at a clean stop: a successor starts at once
    store.fleet() -> [{engine_id, writer, last cycle, engine FMEP with sigma and status, alert counts}, ...]

Leases. Each engine id has at most one row in ``writers``: the process that writes it, and its heartbeat on the
database's clock (``Dialect.now``: the boxes' clocks need not agree). Claiming an engine another writer holds is
refused while that writer is live: its heartbeat younger than ``LEASE_TIMEOUT_S``, and, when it runs on this host,
its process still running. A lease past the timeout (a process killed on another box, or cut off from the database
that long) is taken over and the takeover logged; one left by a process of this host that no longer runs is taken
over at once (a restart after ``kill -9``). Timing, not tuned on data: a heartbeat every 10 s, stale after 60 s,
so five heartbeats in a row must fail (a database restart takes seconds) before another process may take over.

The fleet view reads ``engines``, ``writers`` and ``engine_latest`` (one row per engine, written in each batch's
transaction by ``SqlStore.write_batch``) by their primary keys, and counts open alerts on the (engine_id, state)
index: its work grows with the number of engines, never with the cycles stored.
"""

from __future__ import annotations

import logging
import os
import socket
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from frictionwatch.service.store.columns import StoreError

log = logging.getLogger(__name__)
HEARTBEAT_S, LEASE_TIMEOUT_S = 10.0, 60.0
MAX_FLEET = 1000  # engines one fleet reply lists (ordered by engine id): a plant has tens


@dataclass(frozen=True)
class Writer:
    """Who writes: the host, the process and a token of this start (two stores in one process are two writers)."""

    host: str
    pid: int
    token: str

    @property
    def name(self) -> str:
        return f"{self.host}:{self.pid}:{self.token}"

    @classmethod
    def this_process(cls) -> Writer:
        return cls(socket.gethostname(), os.getpid(), uuid.uuid4().hex[:8])


def running_here(pid: int) -> bool:
    """Whether a process with this id runs on this host (one we may not signal runs too)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class FleetStore:
    """Leases and the fleet view, mixed into SqlStore (its ``_transaction``, ``_x``, ``_query``, ``dialect``)."""

    dialect: Any

    def claim_engine(self, engine_id: str, me: Writer, timeout_s: float = LEASE_TIMEOUT_S) -> str | None:
        """Make ``me`` the engine's writer. Returns None, or the writer whose stale lease was taken over; raises
        StoreError (one line) while another live writer holds it."""
        now = self.dialect.now
        with self._transaction() as cur:
            self._x(cur, f"INSERT INTO engines (engine_id, created_at) VALUES (?, {now}) "
                         "ON CONFLICT (engine_id) DO NOTHING", (engine_id,))
            if self._x(cur, f"INSERT INTO writers (engine_id, writer, host, pid, claimed_at, heartbeat_at) VALUES "
                            f"(?, ?, ?, ?, {now}, {now}) ON CONFLICT (engine_id) DO NOTHING",
                       (engine_id, me.name, me.host, me.pid)).rowcount == 1:
                return None
            writer, host, pid, age = self._x(cur, f"SELECT writer, host, pid, {now} - heartbeat_at FROM writers "
                                                  "WHERE engine_id = ?" + self.dialect.lock_rows,
                                             (engine_id,)).fetchone()
            gone = host == me.host and int(pid) != me.pid and not running_here(int(pid))
            if writer != me.name and age < timeout_s and not gone:
                raise StoreError(f"engine {engine_id} is written by {writer} (heartbeat {max(age, 0.0):.0f} s ago): "
                                 f"one engine id, one writer; give this one another #ID or stop the other (a lease "
                                 f"with no heartbeat for {timeout_s:g} s is taken over)")
            self._x(cur, f"UPDATE writers SET writer = ?, host = ?, pid = ?, claimed_at = {now}, heartbeat_at = {now} "
                         "WHERE engine_id = ?", (me.name, me.host, me.pid, engine_id))
        if writer == me.name:
            return None
        why = "its process no longer runs" if gone else f"no heartbeat for {age:.0f} s"
        log.warning("engine %s: took over the lease of %s (%s)", engine_id, writer, why)
        return writer

    def heartbeat(self, engine_ids: Sequence[str], me: Writer) -> list[str]:
        """Renew ``me``'s leases; returns the engines of ``engine_ids`` whose lease ``me`` no longer holds."""
        if not engine_ids:
            return []
        marks = ", ".join("?" * len(engine_ids))
        with self._transaction() as cur:
            self._x(cur, f"UPDATE writers SET heartbeat_at = {self.dialect.now} WHERE writer = ? AND engine_id IN "
                         f"({marks})", (me.name, *engine_ids))
            held = {r[0] for r in self._x(cur, f"SELECT engine_id FROM writers WHERE writer = ? AND engine_id IN "
                                               f"({marks})", (me.name, *engine_ids)).fetchall()}
        return [e for e in engine_ids if e not in held]

    def release(self, engine_ids: Sequence[str], me: Writer) -> None:
        if engine_ids:
            with self._transaction() as cur:
                self._x(cur, f"DELETE FROM writers WHERE writer = ? AND engine_id IN ({', '.join('?' * len(engine_ids))})",
                        (me.name, *engine_ids))

    def _latest(self, cur: Any, engine_id: str, run_id: int, newest: dict, figure: dict | None) -> None:
        """The engine's row in engine_latest: its newest committed cycle (never moved back by an older batch)."""
        figure = figure or {}
        self._x(cur, "INSERT INTO engine_latest (engine_id, run_id, cycle_index, t_start_s, written_at, fmep_bar, "
                     "fmep_sigma_bar, status, reason) VALUES (?, ?, ?, ?, " + self.dialect.now + ", ?, ?, ?, ?) "
                     "ON CONFLICT (engine_id) DO UPDATE SET run_id = excluded.run_id, cycle_index = "
                     "excluded.cycle_index, t_start_s = excluded.t_start_s, written_at = excluded.written_at, "
                     "fmep_bar = excluded.fmep_bar, fmep_sigma_bar = excluded.fmep_sigma_bar, status = "
                     "excluded.status, reason = excluded.reason WHERE engine_latest.cycle_index <= excluded.cycle_index",
                (engine_id, run_id, int(newest["cycle_index"]), _number(newest.get("t_start_s")),
                 _number(figure.get("fmep_bar")), _number(figure.get("fmep_sigma_bar")), figure.get("status"),
                 figure.get("reason")))

    def fleet(self, timeout_s: float = LEASE_TIMEOUT_S, limit: int = MAX_FLEET) -> list[dict]:
        """Every engine of the store (by id, at most ``limit``): its writer and whether that one is live, its newest
        committed cycle and how long ago it was written, the engine's friction figure there, and its open alerts."""
        rows = self._query(self._fleet_sql(), (int(limit),))
        out = []
        for eid, writer, beat_age, run, cycle, t_start, age, fmep, sigma, status, reason, active, acked in rows:
            out.append({"engine_id": eid, "writer": writer,
                        "writer_live": writer is not None and beat_age is not None and float(beat_age) < timeout_s,
                        "heartbeat_age_s": _number(beat_age), "run_id": None if run is None else int(run),
                        "last_cycle": None if cycle is None else int(cycle), "t_start_s": _number(t_start),
                        "last_cycle_age_s": _number(age),
                        "engine": {"fmep_bar": _number(fmep), "fmep_sigma_bar": _number(sigma), "status": status,
                                   "reason": reason},
                        "active_alerts": int(active), "acknowledged_alerts": int(acked)})
        return out


    def _fleet_sql(self) -> str:
        """The fleet view's one query (its parameter: the limit)."""
        now = self.dialect.now
        return (f"SELECT e.engine_id, w.writer, {now} - w.heartbeat_at, l.run_id, l.cycle_index, l.t_start_s, "
                f"{now} - l.written_at, l.fmep_bar, l.fmep_sigma_bar, l.status, l.reason, "
                "(SELECT COUNT(*) FROM alerts a WHERE a.engine_id = e.engine_id AND a.state = 'active'), "
                "(SELECT COUNT(*) FROM alerts a WHERE a.engine_id = e.engine_id AND a.state = 'acknowledged') "
                "FROM engines e LEFT JOIN writers w ON w.engine_id = e.engine_id "
                "LEFT JOIN engine_latest l ON l.engine_id = e.engine_id ORDER BY e.engine_id LIMIT ?")


def _number(x: Any) -> float | None:
    if x is None:
        return None
    v = float(x)
    return v if v == v and abs(v) != float("inf") else None
