"""The embedded default: one SQLite file in WAL mode.

Durability. ``synchronous=FULL`` (the default here) fsyncs the write-ahead log at every commit: a transaction that
returned has survived a process kill *and* a power cut. ``synchronous=NORMAL`` in WAL mode survives a kill of the
process (the log is written before the commit returns, only its fsync waits for the next checkpoint) but may lose the
last transactions on a power cut, never the file's integrity. The store commits in batches (service.store.listener:
about one a second), so one fsync a batch is cheap next to what it guards; choose ``?synchronous=normal`` in the URL
only for a disk whose fsync is slow and a site whose power is backed.

WAL lets other processes (a report, a backup with ``sqlite3 .backup``) read while the service writes; a reader sees
the last committed transaction. The file must be on a local disk (WAL needs shared memory between its users).
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

from frictionwatch.service.store.sql_store import Dialect, SqlStore, StoreError

SQLITE = Dialect(name="sqlite", begin="BEGIN IMMEDIATE", placeholder="?", lock_rows="",
                 now="((julianday('now') - 2440587.5) * 86400.0)")
SYNCHRONOUS = ("full", "normal")


def open_sqlite(path: str, synchronous: str = "full") -> SqlStore:
    """Open (create) the SQLite store at ``path`` (``:memory:`` for a throw-away one), migrated to this schema."""
    if synchronous not in SYNCHRONOUS:
        raise StoreError(f"sqlite synchronous={synchronous!r}: choose one of {', '.join(SYNCHRONOUS)}")
    memory = path == ":memory:"
    if not memory and not Path(path).parent.is_dir():
        raise StoreError(f"sqlite store {path}: folder {Path(path).parent} does not exist")
    try:
        conn = sqlite3.connect(path, isolation_level=None, check_same_thread=False, timeout=30.0)
        mode = conn.execute("PRAGMA journal_mode=WAL").fetchone()[0]
        if mode != "wal" and not memory:
            conn.close()
            raise StoreError(f"sqlite store {path}: cannot switch to WAL mode (journal_mode is {mode}); "
                             "is it on a network file system?")
        conn.execute(f"PRAGMA synchronous={synchronous.upper()}")
        conn.execute("PRAGMA foreign_keys=ON")
    except sqlite3.DatabaseError as e:
        raise StoreError(f"sqlite store {path}: {e}") from None
    try:
        return SqlStore(conn, SQLITE, f"sqlite store {path}", errors=(sqlite3.Error,))
    except sqlite3.DatabaseError as e:
        conn.close()
        raise StoreError(f"sqlite store {path}: {e}") from None
    except StoreError:
        conn.close()
        raise
