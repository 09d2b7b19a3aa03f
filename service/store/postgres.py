"""PostgreSQL (psycopg 3) for many engines on one server: the same tables and SQL as SQLite (service.store.schema).

What differs is in ``POSTGRES``: ``%s`` placeholders, and the migrating transaction locks the schema_version row so
two services starting together migrate once. The connection runs in autocommit mode and ``SqlStore`` issues
BEGIN/COMMIT itself, as it does for SQLite. A lost connection fails the write (the listener counts it and retries
the batch once); the store does not reconnect by itself.
"""

from __future__ import annotations

import re

from frictionwatch.service.store.sql_store import Dialect, SqlStore, StoreError

POSTGRES = Dialect(name="postgresql", begin="BEGIN", placeholder="%s", lock_rows=" FOR UPDATE")


def redact(url: str) -> str:
    """The URL without its password (for messages and logs)."""
    return re.sub(r"(://[^:/@]+:)[^@]*@", r"\1***@", url)


def open_postgres(url: str) -> SqlStore:
    """Connect to ``postgresql://user[:password]@host[:port]/db[?options]`` and migrate its schema."""
    try:
        import psycopg
    except ImportError:
        raise StoreError("a postgresql:// store needs psycopg 3: pip install 'frictionwatch[postgres]'") from None
    where = f"postgresql store {redact(url)}"
    try:
        conn = psycopg.connect(url, autocommit=True, connect_timeout=10)
    except psycopg.Error as e:
        raise StoreError(f"{where}: cannot connect: {str(e).strip().splitlines()[0]}") from None
    try:
        return SqlStore(conn, POSTGRES, where)
    except psycopg.Error as e:
        conn.close()
        raise StoreError(f"{where}: {str(e).strip().splitlines()[0]}") from None
