"""PostgreSQL (psycopg 3) for many engines on one server: the same tables and SQL as SQLite (service.store.schema).

What differs is in ``POSTGRES``: ``%s`` placeholders, and the migrating transaction locks the schema_version row so
two services starting together migrate once. The connection runs in autocommit mode and ``SqlStore`` issues
BEGIN/COMMIT itself, as it does for SQLite. A lost connection (``conn.broken``: the server went away, or ended the
session) is reopened by SqlStore with the same URL (service/store/sql_store.py: reconnecting, with backoff).
"""

from __future__ import annotations

import re

from frictionwatch.service.store.sql_store import Dialect, SqlStore, StoreError

POSTGRES = Dialect(name="postgresql", begin="BEGIN", placeholder="%s", lock_rows=" FOR UPDATE",
                   now="(EXTRACT(EPOCH FROM clock_timestamp())::float8)")
CONNECT_TIMEOUT_S, RECONNECT_TIMEOUT_S = 10, 3  # at start; when reopening, shorter: the writer waits for it


def redact(url: str) -> str:
    """The URL without its password, in the authority or as a ``password=`` option (for messages and logs)."""
    url = re.sub(r"(://[^:/@]+:)[^@]*@", r"\1***@", url)
    return re.sub(r"([?&]password=)[^&]*", r"\1***", url)


def open_postgres(url: str) -> SqlStore:
    """Connect to ``postgresql://user[:password]@host[:port]/db[?options]`` and migrate its schema."""
    try:
        import psycopg
    except ImportError:
        raise StoreError("a postgresql:// store needs psycopg 3: pip install 'frictionwatch[postgres]'") from None
    where = f"postgresql store {redact(url)}"
    try:
        conn = psycopg.connect(url, autocommit=True, connect_timeout=CONNECT_TIMEOUT_S)
    except psycopg.Error as e:
        raise StoreError(f"{where}: cannot connect: {str(e).strip().splitlines()[0]}") from None

    def reopen():
        return psycopg.connect(url, autocommit=True, connect_timeout=RECONNECT_TIMEOUT_S)

    try:
        return SqlStore(conn, POSTGRES, where, reopen=reopen, is_lost=lambda c: bool(c.broken or c.closed),
                        errors=(psycopg.Error,))
    except psycopg.Error as e:
        conn.close()
        raise StoreError(f"{where}: {str(e).strip().splitlines()[0]}") from None
