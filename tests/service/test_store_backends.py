"""The store's interface on both backends (SQLite; PostgreSQL where FW_TEST_POSTGRES_URL is set, else skipped):
round trips of every kind of row, model versions, alert upserts, baselines, retention, atomic batches, reopening,
and a schema newer than the code refused.

Numbers go in and out as float64 (SQLite REAL, PostgreSQL DOUBLE PRECISION): compared with rtol 1e-15.
"""

from __future__ import annotations

import math
import os
import threading
import time
import uuid
from urllib.parse import quote

import pytest
from frictionwatch.service.store import StoreError, open_store
from frictionwatch.service.store.schema import SCHEMA_VERSION

from tests.json_close import assert_json_close
from tests.service.store_samples import TOML, alert, losses, summary

EXACT = 1e-15
ENG = "eng-1"


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request, tmp_path):
    """A URL to a new, empty store on each backend (a fresh schema in the test PostgreSQL)."""
    if request.param == "sqlite":
        yield f"sqlite:{tmp_path / 'fw.db'}"
        return
    url = os.environ.get("FW_TEST_POSTGRES_URL")
    if not url:
        pytest.skip("FW_TEST_POSTGRES_URL is not set: no PostgreSQL to test against (.ci/run starts one)")
    psycopg = pytest.importorskip("psycopg")
    schema = f"fw_test_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute(f"CREATE SCHEMA {schema}")
    sep = "&" if "?" in url else "?"
    yield f"{url}{sep}options={quote(f'-csearch_path={schema}')}"
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute(f"DROP SCHEMA {schema} CASCADE")


@pytest.fixture
def store(store_url):
    s = open_store(store_url)
    s.register_engine(ENG, TOML)
    yield s
    s.close()


def test_a_new_store_is_at_the_current_schema_version(store):
    assert store.schema_version == SCHEMA_VERSION
    assert store.latest_cycle(ENG) is None and store.cycles(ENG, 0, 10) == []
    assert store.load_alerts(ENG) == [] and store.load_baseline(ENG) is None


def test_model_version_changes_with_the_engine_toml(store):
    assert store.register_engine(ENG, TOML) == 1  # the same text again: the same version
    assert store.register_engine(ENG, TOML + "# retuned\n") == 2
    store.write_cycles(ENG, [summary(0)])
    assert store.register_engine(ENG, TOML) == 3  # back to the first text: a new version, the history kept
    store.write_cycles(ENG, [summary(1)])
    assert [v["version"] for v in store.model_versions(ENG)] == [1, 2, 3]
    assert store.model_versions(ENG)[1]["engine_toml"] == TOML + "# retuned\n"
    assert [r["model_version"] for r in store.cycles(ENG, 0, 1)] == [2, 3]
    assert store.register_engine("eng-2", TOML) == 1  # versions count per engine


def test_cycles_round_trip_with_missing_values_and_added_fields(store):
    rows = [summary(i) for i in range(30)]
    rows[3]["load_torque_nm"] = math.nan  # not a number: stored as NULL, read as None
    rows[4]["imep_bar"][2] = math.inf
    rows[5]["speed_rpm_p2p"] = 12.5  # a field a helper added to CycleSummary later
    store.write_cycles(ENG, rows[:10])
    store.write_cycles(ENG, rows[10:])
    got = store.cycles(ENG, 2, 27)
    assert [r["cycle_index"] for r in got] == list(range(2, 28))
    expected = [dict(r, model_version=1, run_id=1) for r in rows[2:28]]
    expected[1]["load_torque_nm"] = None
    expected[2]["imep_bar"][2] = None
    for g, e in zip(got, expected):
        assert_json_close(g, e, rtol=EXACT, where=f"cycle {e['cycle_index']}")
    assert got[0]["friction_balance_nm"] is None or got[0]["friction_balance_nm"] > 0
    assert store.latest_cycle(ENG) == 29
    assert store.cycles("eng-other", 0, 100) == []


def test_a_cycle_written_again_replaces_the_first(store):
    store.write_cycles(ENG, [summary(7)])
    again = dict(summary(7), rpm_mean=1234.5)
    store.write_cycles(ENG, [again])
    (got,) = store.cycles(ENG, 7, 7)
    assert_json_close(got["rpm_mean"], 1234.5, rtol=EXACT)


def test_estimates_round_trip(store):
    store.write_estimate(ENG, 25, losses(25))
    store.write_estimate(ENG, 50, losses(50, status="unresolved"))
    got = store.estimates(ENG, 0, 100)
    assert [(r["cycle_index"], r["cylinder"]) for r in got] == [(c, k) for c in (25, 50) for k in range(1, 5)]
    for g, e in zip(got, [dict(r, cycle_index=25, run_id=1) for r in losses(25)] +
                    [dict(r, cycle_index=50, run_id=1) for r in losses(50, status="unresolved")]):
        assert_json_close(g, e, rtol=EXACT, where=f"cycle {e['cycle_index']} cylinder {e['cylinder']}")
    assert all(r["fmep_bar"] is None and r["status"] == "unresolved" for r in got[4:])


def test_alerts_upsert_by_id_and_filter_by_state(store):
    store.upsert_alert(ENG, alert(1))
    store.upsert_alert(ENG, alert(2, cylinder=None, kind="sensor_fault"))
    store.upsert_alert(ENG, dict(alert(1), state="acknowledged", acknowledged_by="operator"))
    store.upsert_alert(ENG, dict(alert(2, cylinder=None, kind="sensor_fault"), state="cleared", cleared_cycle=400))
    store.upsert_alert(ENG, alert(3, cylinder=7, kind="blow_by"))
    everything = store.load_alerts(ENG)
    assert [(a["alert_id"], a["state"]) for a in everything] == [(1, "acknowledged"), (2, "cleared"), (3, "active")]
    assert everything[0]["acknowledged_by"] == "operator" and everything[1]["cleared_cycle"] == 400
    assert_json_close(everything[2], dict(alert(3, cylinder=7, kind="blow_by"), engine_id=ENG), rtol=EXACT)
    assert [a["alert_id"] for a in store.load_alerts(ENG, state="active")] == [3]
    with pytest.raises(StoreError, match="unknown alert state"):
        store.load_alerts(ENG, state="open")


def test_the_newest_baseline_is_the_one_in_force(store):
    first = {"fmep_bar": [1.1, 1.2, 1.0, 1.15], "cycles": [0, 2000]}
    store.save_baseline(ENG, first)
    assert store.load_baseline(ENG) == first
    second = {"fmep_bar": [1.2, 1.2, 1.1, 1.15], "cycles": [5000, 7000], "note": None}
    store.save_baseline(ENG, second)
    assert store.load_baseline(ENG) == second
    assert store.load_baseline("eng-other") is None


def test_a_batch_is_written_whole_or_not_at_all(store):
    with pytest.raises(StoreError, match="alert lacks severity"):
        bad = {k: v for k, v in alert(9).items() if k != "severity"}
        store.write_batch(ENG, cycles=[summary(0), summary(1)], alerts=[bad])
    assert store.latest_cycle(ENG) is None
    with pytest.raises(StoreError, match="lacks rpm_mean"):
        store.write_cycles(ENG, [summary(0), {k: v for k, v in summary(1).items() if k != "rpm_mean"}])
    with pytest.raises(StoreError, match="not registered"):
        store.write_cycles("eng-unknown", [summary(0)])
    assert store.latest_cycle(ENG) is None


def test_retention_deletes_old_cycles_and_estimates_in_batches_and_keeps_alerts_and_baselines(store):
    store.write_batch(ENG, cycles=[summary(i) for i in range(40)],
                      estimates=[(i, losses(i)) for i in range(0, 40, 10)], alerts=[alert(1)])
    store.save_baseline(ENG, {"fmep_bar": [1.0]})
    time.sleep(0.05)
    cutoff = time.time()
    time.sleep(0.05)
    store.write_batch(ENG, cycles=[summary(i) for i in range(40, 50)], estimates=[(40, losses(40))])
    deleted = store.apply_retention(keep_days=1.0, now=cutoff + 86400.0, batch_rows=7)  # 6 batches for 40 rows
    assert deleted == {"cycles": 40, "estimates": 16}
    assert [r["cycle_index"] for r in store.cycles(ENG, 0, 100)] == list(range(40, 50))
    assert {r["cycle_index"] for r in store.estimates(ENG, 0, 100)} == {40}
    assert [a["alert_id"] for a in store.load_alerts(ENG)] == [1]
    assert store.load_baseline(ENG) == {"fmep_bar": [1.0]}
    assert store.apply_retention(keep_days=1.0, now=cutoff + 86400.0) == {"cycles": 0, "estimates": 0}
    with pytest.raises(StoreError, match="keep_days > 0"):
        store.apply_retention(keep_days=0)


def test_everything_survives_closing_and_reopening(store_url):
    s = open_store(store_url)
    s.register_engine(ENG, TOML)
    s.write_batch(ENG, cycles=[summary(i) for i in range(12)], estimates=[(10, losses(10))], alerts=[alert(4)])
    s.save_baseline(ENG, {"fmep_bar": [1.0, 2.0]})
    s.close()
    s = open_store(store_url)
    try:
        assert s.register_engine(ENG, TOML) == 1
        assert s.latest_cycle(ENG) == 11 and len(s.cycles(ENG, 0, 11)) == 12
        assert len(s.estimates(ENG, 0, 11)) == 4
        assert [a["alert_id"] for a in s.load_alerts(ENG, state="active")] == [4]
        assert s.load_baseline(ENG) == {"fmep_bar": [1.0, 2.0]}
    finally:
        s.close()


def test_a_schema_newer_than_the_code_is_refused_in_one_line(store_url):
    s = open_store(store_url)
    with s._transaction() as cur:
        cur.execute("UPDATE schema_version SET version = 99")
    s.close()
    with pytest.raises(StoreError) as e:
        open_store(store_url)
    assert "schema version 99 is newer than this frictionwatch knows" in str(e.value)
    assert "\n" not in str(e.value)


def test_an_unreachable_postgresql_is_one_line_without_its_password():
    pytest.importorskip("psycopg")
    with pytest.raises(StoreError, match="cannot connect") as e:
        open_store("postgresql://fw:s3cret@127.0.0.1:1/fw?connect_timeout=2")
    assert "\n" not in str(e.value) and "s3cret" not in str(e.value) and "fw:***@127.0.0.1:1" in str(e.value)


def test_two_writers_on_one_store_each_keep_every_row(store_url):
    """Two services (two connections) writing their own engines at once: PostgreSQL serves both; SQLite serialises
    their transactions (BEGIN IMMEDIATE waits on the other's lock within the busy timeout)."""
    stores = [open_store(store_url) for _ in range(2)]
    for k, s in enumerate(stores):
        s.register_engine(f"eng-{k}", TOML)
    errors: list[BaseException] = []

    def write(k: int) -> None:
        try:
            for b in range(40):
                stores[k].write_batch(f"eng-{k}", cycles=[summary(i, engine_id=f"eng-{k}")
                                                          for i in range(b * 5, b * 5 + 5)],
                                      estimates=[(b * 5, losses(b * 5))])
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=write, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    for k in range(2):
        assert [r["cycle_index"] for r in stores[0].cycles(f"eng-{k}", 0, 1000)] == list(range(200))
        assert len(stores[1].estimates(f"eng-{k}", 0, 1000)) == 40 * 4
    for s in stores:
        s.close()
