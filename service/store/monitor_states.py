"""The monitor's carried state kept across a clean restart: one row per engine (service/monitor_snapshot.py makes the
text; service/data_dir.py decides whether a run may go on from it)."""

from __future__ import annotations

import time
from typing import Any


class MonitorStateStore:
    """Mixed into SqlStore (its ``_transaction``, ``_x``, ``_query``, ``run_of``, ``_version_of``)."""

    def save_monitor_state(self, engine_id: str, fingerprint: str, doc: str, last_cycle: int | None) -> None:
        """Replace the engine's saved state with this run's."""
        version, run = self._version_of(engine_id), self.run_of(engine_id).run_id
        with self._transaction() as cur:
            self._x(cur, "DELETE FROM monitor_states WHERE engine_id = ?", (engine_id,))
            self._x(cur, "INSERT INTO monitor_states (engine_id, run_id, model_version, fingerprint, last_cycle, "
                         "saved_at, doc) VALUES (?, ?, ?, ?, ?, ?, ?)",
                    (engine_id, run, version, fingerprint, last_cycle, time.time(), doc))

    def load_monitor_state(self, engine_id: str) -> dict[str, Any] | None:
        rows = self._query("SELECT run_id, model_version, fingerprint, last_cycle, saved_at, doc FROM monitor_states "
                           "WHERE engine_id = ?", (engine_id,))
        if not rows:
            return None
        run, version, fp, last, saved_at, doc = rows[0]
        return {"run_id": int(run), "model_version": int(version), "fingerprint": fp,
                "last_cycle": None if last is None else int(last), "saved_at": float(saved_at), "doc": doc}
