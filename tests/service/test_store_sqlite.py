"""The SQLite store: WAL and durability settings, URLs, an old schema's file migrated on opening, a reader in
another connection while a writer commits, and files that are not a store refused in one line."""

from __future__ import annotations

import sqlite3
import threading

import pytest
from frictionwatch.service.store import StoreError, open_store
from frictionwatch.service.store.schema import MIGRATIONS, SCHEMA_VERSION

from tests.service.store_samples import TOML, summary

ENG = "eng-1"


def pragma(store, name: str):
    return store._conn.execute(f"PRAGMA {name}").fetchone()[0]


def test_wal_mode_and_full_synchronous_by_default(tmp_path):
    store = open_store(str(tmp_path / "fw.db"))  # a bare path is SQLite
    assert pragma(store, "journal_mode") == "wal"
    assert pragma(store, "synchronous") == 2  # FULL: the log is fsynced at every commit
    assert pragma(store, "foreign_keys") == 1
    store.close()
    store = open_store(f"sqlite:{tmp_path / 'fw.db'}?synchronous=normal")
    assert pragma(store, "journal_mode") == "wal" and pragma(store, "synchronous") == 1
    store.close()


def test_urls(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    open_store("sqlite:rel.db").close()
    open_store(f"sqlite://{tmp_path}/abs.db").close()  # sqlite:///abs/path: an empty authority
    assert (tmp_path / "rel.db").exists() and (tmp_path / "abs.db").exists()
    for url, message in [("sqlite:fw.db?journal=off", "unknown option journal"),
                         ("sqlite:fw.db?synchronous=off", "synchronous='off'"),
                         ("sqlite:", "no file path"),
                         ("mysql://x/y", "unknown store"),
                         (str(tmp_path / "missing" / "fw.db"), "does not exist")]:
        with pytest.raises(StoreError, match=message) as e:
            open_store(url)
        assert "\n" not in str(e.value)


def test_a_file_that_is_not_a_database_is_refused_in_one_line(tmp_path):
    path = tmp_path / "fw.db"
    path.write_bytes(b"this is not an SQLite file, it is a log of something else\n" * 20)
    with pytest.raises(StoreError, match="file is not a database") as e:
        open_store(str(path))
    assert "\n" not in str(e.value)
    assert path.read_bytes().startswith(b"this is not")  # left as it was


def test_a_file_of_schema_version_1_migrates_and_keeps_its_rows(tmp_path):
    """A database as frictionwatch with only the first migration left it (made here with plain sqlite3)."""
    path = tmp_path / "old.db"
    conn = sqlite3.connect(path, isolation_level=None)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute("BEGIN")
    conn.execute("CREATE TABLE schema_version (version BIGINT NOT NULL)")
    for statement in MIGRATIONS[0]:
        conn.execute(statement)
    conn.execute("INSERT INTO schema_version VALUES (1)")
    conn.execute("INSERT INTO engines VALUES ('eng-1', 1.0)")
    conn.execute("INSERT INTO model_versions VALUES ('eng-1', 1, 'x', ?, 1.0)", (TOML,))
    conn.execute("INSERT INTO cycles VALUES ('eng-1', 41, 1, 3.28, 1500.0, 5000.0, 785.0, '[18.0,18.1]', "
                 "'[150.0,151.0]', 300.0, '[]', NULL, 1.0)")
    conn.execute("COMMIT")
    conn.close()
    assert SCHEMA_VERSION > 1  # else this test shows nothing: there would be no migration to apply
    store = open_store(str(path))
    assert store.schema_version == SCHEMA_VERSION
    indexes = {r[0] for r in store._conn.execute("SELECT name FROM sqlite_master WHERE type = 'index'")}
    assert {"cycles_written_at", "estimates_written_at", "alerts_state"} <= indexes
    assert store.latest_cycle(ENG) == 41
    (row,) = store.cycles(ENG, 41, 41)
    assert row["imep_bar"] == [18.0, 18.1] and row["flags"] == []
    store.register_engine(ENG, TOML + "# new\n")
    store.write_cycles(ENG, [summary(42)])
    assert store.latest_cycle(ENG) == 42
    store.close()


def test_a_migration_that_fails_leaves_the_file_at_the_last_whole_version(tmp_path, monkeypatch):
    from frictionwatch.service.store import sql_store

    path = str(tmp_path / "fw.db")
    broken = (MIGRATIONS[0], ("CREATE INDEX cycles_written_at ON cycles (written_at)", "THIS IS NOT SQL"))
    monkeypatch.setattr(sql_store, "MIGRATIONS", broken)
    with pytest.raises(StoreError, match="syntax error"):
        open_store(path)
    version = sqlite3.connect(path).execute("SELECT version FROM schema_version").fetchone()[0]
    indexes = sqlite3.connect(path).execute("SELECT name FROM sqlite_master WHERE type = 'index' "
                                            "AND name = 'cycles_written_at'").fetchall()
    assert version == 1 and indexes == []  # the second migration rolled back whole
    monkeypatch.undo()
    store = open_store(path)
    assert store.schema_version == SCHEMA_VERSION
    store.close()


def test_a_reader_in_another_connection_sees_whole_batches_while_the_writer_commits(tmp_path):
    path = str(tmp_path / "fw.db")
    writer = open_store(path)
    writer.register_engine(ENG, TOML)
    reader = open_store(path)
    batch, n_batches = 10, 150
    seen: list[int] = []
    errors: list[BaseException] = []
    done = threading.Event()

    def read() -> None:
        try:
            while not done.is_set():
                latest = reader.latest_cycle(ENG)
                if latest is not None:
                    rows = reader.cycles(ENG, 0, latest)
                    assert len(rows) == latest + 1  # every cycle up to the newest is there
                    assert (latest + 1) % batch == 0  # never part of a batch
                    seen.append(latest)
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    thread = threading.Thread(target=read)
    thread.start()
    for b in range(n_batches):
        writer.write_cycles(ENG, [summary(i) for i in range(b * batch, (b + 1) * batch)])
    done.set()
    thread.join()
    assert errors == []
    assert len(seen) > 5 and seen[0] < batch * n_batches - 1  # the reader ran alongside the writer
    assert seen == sorted(seen)  # and never saw the store go back
    assert reader.latest_cycle(ENG) == batch * n_batches - 1
    writer.close()
    reader.close()
