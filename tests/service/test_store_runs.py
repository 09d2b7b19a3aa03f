"""Runs in the store (issue 28) on both backends: a restart (a new store object on the same database) numbers its
cycles on from the last stored one and never replaces an earlier run's rows; a stale write under another run's key
is refused and counted; the numbering survives retention; a database of schema version 2 is migrated in place with
every row kept. Numbers are compared exactly (rtol 1e-15: float64 in, float64 out)."""

from __future__ import annotations

import sqlite3

from frictionwatch.service.store import StoreListener, open_store
from frictionwatch.service.store.schema import MIGRATIONS, SCHEMA_VERSION

from tests.json_close import assert_json_close
from tests.service.store_samples import TOML, alert, losses, summary
from tests.service.test_store_backends import store_url  # noqa: F401 - the fixture, on both backends

EXACT = 1e-15
ENG = "eng-1"


def _started(url: str):
    s = open_store(url)
    s.register_engine(ENG, TOML)
    return s, s.begin_run(ENG)


def test_a_restart_appends_after_the_last_cycle_and_keeps_the_first_run(store_url):  # noqa: F811
    s, run = _started(store_url)
    assert (run.run_id, run.first_cycle) == (1, 0)
    s.write_batch(ENG, cycles=[summary(i) for i in range(10)], estimates=[(5, losses(5))],
                  alerts=[dict(alert(1), raised_cycle=7)])
    s.close()

    s, run = _started(store_url)  # the restart
    try:
        assert (run.run_id, run.first_cycle) == (2, 10)
        assert s.write_batch(ENG, cycles=[summary(i) for i in range(10, 15)]) == 0
        rows = s.cycles(ENG, 0, 100)
        assert [r["cycle_index"] for r in rows] == list(range(15))
        assert [r["run_id"] for r in rows] == [1] * 10 + [2] * 5
        assert_json_close(rows[3]["rpm_mean"], summary(3)["rpm_mean"], rtol=EXACT)
        assert [(r["run_id"], r["first_cycle"], r["last_cycle"]) for r in s.runs(ENG)] == [(1, 0, 9), (2, 10, 14)]
    finally:
        s.close()


def test_a_write_under_an_earlier_runs_key_is_refused_and_counted(store_url):  # noqa: F811
    s, _ = _started(store_url)
    s.write_batch(ENG, cycles=[summary(i) for i in range(4)], estimates=[(2, losses(2))], alerts=[alert(1)])
    s.close()
    s, _ = _started(store_url)
    try:
        stale = dict(summary(2), rpm_mean=999.0)  # a writer that restarted its numbering at 0
        other = dict(alert(1), kind="misfire", raised_cycle=3)  # an alert engine that restarted its ids at 1
        refused = s.write_batch(ENG, cycles=[stale, summary(4)], estimates=[(2, losses(2, status="share"))],
                                alerts=[other])
        assert refused == 1 + 4 + 1  # the cycle, four cylinders, the alert; cycle 4 is new and written
        (kept,) = s.cycles(ENG, 2, 2)
        assert_json_close(kept["rpm_mean"], summary(2)["rpm_mean"], rtol=EXACT)
        assert kept["run_id"] == 1 and {r["status"] for r in s.estimates(ENG, 2, 2)} == {"measured"}
        assert [(a["kind"], a["raised_cycle"]) for a in s.load_alerts(ENG)] == [("ring_wear", 101)]
        # a later state of the same alert is another run's to write: an alert lives across restarts
        assert s.upsert_alert(ENG, dict(alert(1), state="acknowledged", acknowledged_by="op")) == 0
        assert s.load_alerts(ENG)[0]["state"] == "acknowledged"
    finally:
        s.close()


def test_the_numbering_continues_after_retention_deleted_every_cycle(store_url):  # noqa: F811
    s, _ = _started(store_url)
    s.write_batch(ENG, cycles=[summary(i) for i in range(20)])
    assert s.apply_retention(keep_days=1.0, now=2e10)["cycles"] == 20
    s.close()
    s, run = _started(store_url)
    try:
        assert s.latest_cycle(ENG) is None and run.first_cycle == 20
    finally:
        s.close()


def test_a_schema_2_database_is_migrated_with_its_rows_kept(tmp_path):
    path = tmp_path / "old.db"
    conn = sqlite3.connect(path, isolation_level=None)  # what frictionwatch before runs made
    conn.execute("CREATE TABLE schema_version (version BIGINT NOT NULL)")
    conn.execute("INSERT INTO schema_version VALUES (2)")
    for statement in (*MIGRATIONS[0], *MIGRATIONS[1]):
        conn.execute(statement)
    conn.execute("INSERT INTO engines VALUES (?, 0.0)", (ENG,))
    conn.execute("INSERT INTO model_versions VALUES (?, 1, 'x', ?, 0.0)", (ENG, TOML))
    conn.execute("INSERT INTO cycles (engine_id, cycle_index, model_version, rpm_mean, imep_bar, pmax_bar, flags, "
                 "written_at) VALUES (?, 41, 1, 1500.25, '[]', '[]', '[]', 0.0)", (ENG,))
    conn.close()

    s, run = _started(f"sqlite:{path}")
    try:
        assert s.schema_version == SCHEMA_VERSION == 5
        (old,) = s.cycles(ENG, 0, 100)
        assert old["run_id"] is None and old["rpm_mean"] == 1500.25  # exact: written and read as float64
        assert (run.run_id, run.first_cycle) == (1, 42)
    finally:
        s.close()


def test_the_listener_counts_and_logs_rows_an_earlier_run_holds(store_url, caplog):  # noqa: F811
    s, _ = _started(store_url)
    s.write_cycles(ENG, [summary(i) for i in range(3)])
    s.close()
    s, _ = _started(store_url)
    try:
        listener = StoreListener(s, ENG, batch_cycles=100)
        for i in range(2, 5):  # cycle 2 is run 1's
            listener.on_cycle(summary(i))
        listener.stop()
        assert listener.stats["rows_refused"] == 1 and listener.stats["cycles_written"] == 3
        assert any("earlier run holds" in r.getMessage() for r in caplog.records)
        assert [r["run_id"] for r in s.cycles(ENG, 0, 10)] == [1, 1, 1, 2, 2]
    finally:
        s.close()


def test_a_run_that_wrote_nothing_is_forgotten_and_one_that_wrote_is_kept(store_url):  # noqa: F811
    s, run = _started(store_url)
    s.write_batch(ENG, cycles=[summary(i) for i in range(3)])
    assert not s.forget_run(ENG, run.run_id)  # it wrote: kept
    s.close()
    s, failed = _started(store_url)  # a start that failed before its first cycle
    assert failed.run_id == 2 and s.forget_run(ENG, failed.run_id)
    s.close()
    s, run = _started(store_url)
    try:
        assert (run.run_id, run.first_cycle) == (2, 3)  # the failed start left no trace in the numbering
        assert [r["run_id"] for r in s.runs(ENG)] == [1, 2]
    finally:
        s.close()
