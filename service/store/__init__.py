"""The durable store: per-cycle summaries, per-cylinder estimates, alerts, baselines and engine model versions.

    store = open_store("sqlite:///var/lib/frictionwatch/fw.db")   # or a bare path; or "postgresql://user@host/db"
    version = store.register_engine("genset-v20", engine_toml)    # a new model version when the TOML changes
    run = store.begin_run("genset-v20")                            # this start: run.run_id, run.first_cycle (the
    #                                                                number after every cycle stored: a restart appends)
    store.write_cycles("genset-v20", [summary, ...])               # CycleSummary dicts (the service contract)
    store.write_estimate("genset-v20", cycle_index, [loss, ...])   # CylinderLoss dicts
    store.upsert_alert("genset-v20", alert)                        # Alert dict, replaced by a later state of it
    # each write returns the rows refused: a row of another run under the same key is kept, never overwritten
    store.save_baseline("genset-v20", baseline) ; store.load_baseline("genset-v20") -> dict | None
    store.latest_cycle(id) -> int | None ; store.cycles(id, first, last) ; store.estimates(id, first, last)
    store.runs(id) ; store.next_cycle(id) ; store.load_alerts(id, state=None) ; store.apply_retention(keep_days) ; store.close()
    StoreListener(store, id)                                       # the fan-out's batching writer

URLs: ``sqlite:PATH``, ``sqlite:///ABSOLUTE/PATH`` or a bare path (SQLite in WAL mode, ``?synchronous=normal``
to trade power-cut durability for fewer fsyncs, service/store/sqlite.py); ``postgresql://...`` or
``postgres://...`` (psycopg 3, the ``postgres`` extra). Every failure to open is a one-line ``StoreError``.

Modules: ``schema`` (the migrations), ``sql_store`` (the interface on either backend; ``Dialect`` holds what
differs), ``columns`` (contract dicts to columns and back), ``sqlite``, ``postgres``, ``listener``.
"""

from __future__ import annotations

from urllib.parse import parse_qs

from frictionwatch.service.store.listener import StoreListener
from frictionwatch.service.store.sql_store import SqlStore, StoreError

__all__ = ["SqlStore", "StoreError", "StoreListener", "open_store"]


def open_store(url: str) -> SqlStore:
    """The store at ``url`` (module docstring), its schema migrated to this version of frictionwatch."""
    if url.startswith(("postgresql://", "postgres://")):
        from frictionwatch.service.store.postgres import open_postgres

        return open_postgres(url)
    from frictionwatch.service.store.sqlite import open_sqlite

    if url.startswith("sqlite:"):
        rest = url.removeprefix("sqlite:")
        path, _, query = rest.partition("?")
        path = path.removeprefix("//")  # an empty authority: sqlite:///abs/path -> /abs/path
        options = {k: v[-1] for k, v in parse_qs(query, keep_blank_values=True).items()}
        unknown = sorted(set(options) - {"synchronous"})
        if unknown:
            raise StoreError(f"{url}: unknown option {', '.join(unknown)} (known: synchronous)")
        if not path:
            raise StoreError(f"{url}: no file path")
        return open_sqlite(path, options.get("synchronous", "full").lower())
    if "://" in url:
        raise StoreError(f"{url}: unknown store; use sqlite:PATH, a file path or postgresql://...")
    return open_sqlite(url)
