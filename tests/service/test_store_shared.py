"""Several processes on one store (issue 28 item 7), on SQLite and on PostgreSQL where FW_TEST_POSTGRES_URL is set:
a connection killed mid-run (pg_terminate_backend) reopened and the batches written while it was down written late;
a store down for longer than the backlog holds losing the oldest batches, counted, never raising; one engine id, one
writer (a live writer refused, a killed one's lease taken over, a silent one's after the timeout); retention of a
shared store sweeping only this process's engines; the fleet view's rows and its query plan (no scan of the
cycles, estimates or alerts)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time

import pytest
from frictionwatch.service.data_dir import DataDir
from frictionwatch.service.store import StoreError, StoreListener, open_store
from frictionwatch.service.store.fleet import Writer
from frictionwatch.service.store.sql_store import StoreUnavailable

from tests.service.serve_helpers import wait_until
from tests.service.store_samples import TOML, alert, losses, summary
from tests.service.test_store_backends import store_url  # noqa: F401 - the fixture, on both backends

ENG = "eng-1"


@pytest.fixture
def store(store_url):  # noqa: F811
    s = open_store(store_url)
    s.register_engine(ENG, TOML)
    yield s
    s.close()


def _terminate(store) -> None:
    """End the store's PostgreSQL session from another connection, as a server restart or a DBA would."""
    psycopg = pytest.importorskip("psycopg")
    (pid,) = store._query("SELECT pg_backend_pid()")[0]
    with psycopg.connect(os.environ["FW_TEST_POSTGRES_URL"], autocommit=True) as admin:
        assert admin.execute("SELECT pg_terminate_backend(%s)", (pid,)).fetchone()[0]


def test_a_killed_postgresql_connection_is_reopened_and_nothing_is_lost(store_url):  # noqa: F811
    if not store_url.startswith("postgresql"):
        pytest.skip("SQLite has no connection to lose")
    s = open_store(store_url)
    s.register_engine(ENG, TOML)
    listener = StoreListener(s, ENG, batch_cycles=5, max_delay_s=0.2)
    try:
        for i in range(10):
            listener.on_cycle(summary(i), losses(i))
        _terminate(s)
        for i in range(10, 30):  # the first batch after the kill finds the connection gone: kept, written late
            listener.on_cycle(summary(i), losses(i))
        assert wait_until(lambda: listener.backlog == 0 and s.latest_cycle(ENG) == 29, timeout=10.0)
        listener.stop()
        assert [r["cycle_index"] for r in s.cycles(ENG, 0, 100)] == list(range(30))
        assert listener.stats["lost_cycles"] == 0 and listener.stats["cycles_written"] == 30
        assert listener.stats["cycles_written_late"] >= 5 and listener.stats["write_errors"] >= 1
        assert s.connection["lost"] == 1 and s.connection["reconnects"] == 1
    finally:
        s.close()


def test_a_store_down_too_long_loses_the_oldest_batches_counted(store, caplog):
    """The store unavailable (its reconnect failing) while 50 cycles come: the newest 20 (backlog_cycles) are kept
    and written when it is back, the oldest 30 counted lost and logged; the caller never sees an exception."""
    listener = StoreListener(Unavailable(store), ENG, batch_cycles=5, max_delay_s=60.0, backlog_cycles=20)
    for i in range(50):
        listener.on_cycle(summary(i))
    assert listener.backlog == 20 and store.latest_cycle(ENG) is None
    assert listener.stats["lost_cycles"] == 30 and listener.stats["lost_batches"] == 6
    assert any("backlog is full" in r.getMessage() for r in caplog.records)
    listener.store.down = False
    listener.on_cycle(summary(50))
    listener.stop()
    assert [r["cycle_index"] for r in store.cycles(ENG, 0, 100)] == list(range(30, 51))
    assert listener.stats["cycles_written_late"] == 20 and listener.stats["cycles_written"] == 21


def test_what_waits_at_stop_while_the_store_is_down_is_counted_lost(store, caplog):
    listener = StoreListener(Unavailable(store), ENG, batch_cycles=5, max_delay_s=60.0)
    for i in range(7):
        listener.on_cycle(summary(i))
    listener.save_baseline({"bands": []})
    listener.stop()
    assert listener.stats["lost_cycles"] == 7 and listener.stats["lost_baselines"] == 1
    assert any("not written at stop" in r.getMessage() for r in caplog.records)


class Unavailable:
    """A store whose connection is down (``down``) and being reopened: every write says so, as SqlStore does."""

    def __init__(self, store) -> None:
        self.store, self.down = store, True

    def write_batch(self, *args, **kwargs):
        if self.down:
            raise StoreUnavailable("test store: connection lost; next attempt in 0.5 s")
        return self.store.write_batch(*args, **kwargs)

    def save_baseline(self, *args):
        if self.down:
            raise StoreUnavailable("test store: connection lost; next attempt in 0.5 s")
        return self.store.save_baseline(*args)


# ---- one engine id, one writer ------------------------------------------------------------------------------------
def test_a_second_writer_of_a_live_engine_is_refused(store_url):  # noqa: F811
    a, b = open_store(store_url), open_store(store_url)
    me, other = Writer.this_process(), Writer.this_process()
    try:
        assert a.claim_engine("genset-1", me) is None
        with pytest.raises(StoreError, match=r"engine genset-1 is written by .*:\d+:\w+ \(heartbeat 0 s ago\)") as e:
            b.claim_engine("genset-1", other)
        assert "\n" not in str(e.value)
        assert b.claim_engine("genset-2", other) is None  # another engine id: no conflict
        assert a.claim_engine("genset-1", me) is None  # the holder claiming again: its own lease
        assert a.heartbeat(["genset-1"], me) == [] and b.heartbeat(["genset-1", "genset-2"], other) == ["genset-1"]
        a.release(["genset-1"], me)  # a clean stop: the next one may start at once
        assert b.claim_engine("genset-1", other) is None
    finally:
        a.close()
        b.close()


def test_a_silent_writer_on_another_host_is_taken_over_after_the_timeout(store):
    far = Writer("other-box", os.getpid(), "a1b2c3d4")  # its pid cannot be checked from here: only the heartbeat
    me = Writer.this_process()
    assert store.claim_engine(ENG, far, timeout_s=1.0) is None
    with pytest.raises(StoreError, match="is written by other-box"):
        store.claim_engine(ENG, me, timeout_s=1.0)
    time.sleep(1.2)  # no heartbeat for longer than the timeout
    assert store.claim_engine(ENG, me, timeout_s=1.0) == far.name
    assert [row["writer"] for row in store.fleet()] == [me.name]


def test_the_lease_of_a_killed_process_is_taken_over_at_once(store_url, tmp_path):  # noqa: F811
    """A process of this host that claimed an engine and was killed with SIGKILL: its lease is taken over at the
    next start without waiting for the timeout (its process no longer runs)."""
    code = textwrap.dedent(f"""
        import sys, time
        from frictionwatch.service.store import open_store
        from frictionwatch.service.store.fleet import Writer
        s = open_store({store_url!r})
        s.claim_engine("genset-1", Writer.this_process())
        print("claimed", flush=True)
        time.sleep(600)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "claimed"
        s = open_store(store_url)
        with pytest.raises(StoreError, match="is written by"):  # alive: refused
            s.claim_engine("genset-1", Writer.this_process())
        proc.kill()
        proc.wait(timeout=30)
        taken = s.claim_engine("genset-1", Writer.this_process())
        assert taken is not None and taken.split(":")[1] == str(proc.pid)
        s.close()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_lost_lease_is_logged_counted_and_taken_back(store_url, caplog):  # noqa: F811
    """DataDir's heartbeat finding its lease gone (the store out of reach past the timeout, another start took it
    and went away): logged as an error, counted, and claimed back."""
    data = DataDir(store_url, heartbeat_s=0.5, lease_timeout_s=5.0)
    try:
        data.store.claim_engine(ENG, data.writer)
        data.engines.append(ENG)
        assert data.renew() == [] and data.leases["heartbeats"] == 1
        data.store.release([ENG], data.writer)  # as if taken over and released by another process
        assert data.renew() == [ENG]
        assert data.leases["lost"] == 1 and data.leases["taken_back"] == 1
        assert any("taken back" in r.getMessage() for r in caplog.records)
        assert data.store.fleet()[0]["writer"] == data.writer.name
    finally:
        data.close()


# ---- retention of a shared store ----------------------------------------------------------------------------------
def test_retention_of_a_shared_store_sweeps_only_this_process_engines(store_url):  # noqa: F811
    other = open_store(store_url)  # another process's engine in the same database
    other.register_engine("theirs", TOML)
    other.write_cycles("theirs", [summary(i, engine_id="theirs") for i in range(5)])
    data = DataDir(store_url, keep_days=2.0)
    try:
        data.store.claim_engine("ours", data.writer)
        data.engines.append("ours")
        data.store.register_engine("ours", TOML)
        data.store.write_cycles("ours", [summary(i, engine_id="ours") for i in range(5)])
        with data.store._transaction() as cur:  # everything written three days ago
            cur.execute("UPDATE cycles SET written_at = written_at - 3 * 86400")
        assert data.sweep() == {"cycles": 5, "estimates": 0}
        assert data.store.cycles("ours", 0, 10) == [] and len(data.store.cycles("theirs", 0, 10)) == 5
    finally:
        data.close()
        other.close()


# ---- the fleet view -----------------------------------------------------------------------------------------------
def test_the_fleet_lists_every_engine_with_its_writer_figure_and_alerts(store_url):  # noqa: F811
    a, b = open_store(store_url), open_store(store_url)  # two processes' stores
    wa, wb = Writer.this_process(), Writer.this_process()
    try:
        for s, w, eid in ((a, wa, "genset-1"), (b, wb, "genset-2")):
            s.claim_engine(eid, w)
            s.register_engine(eid, TOML)
        figure = {"fmep_bar": 1.85, "fmep_sigma_bar": 0.025, "status": "measured", "reason": None}
        a.write_batch("genset-1", cycles=[summary(i) for i in range(10)], engine_figure=figure,
                      alerts=[alert(1), alert(2, state="acknowledged"), alert(3, state="cleared")])
        a.write_batch("genset-1", cycles=[summary(4)])  # an older cycle again: the newest stays the fleet's row
        b.write_batch("genset-2", cycles=[summary(0)], engine_figure={"fmep_bar": None, "fmep_sigma_bar": None,
                                                                       "status": "unresolved", "reason": "warm-up"})
        b.register_engine("genset-3", TOML)  # known, never written, no writer
        rows = {r["engine_id"]: r for r in b.fleet()}
        assert list(rows) == ["genset-1", "genset-2", "genset-3"]
        one, two, three = rows["genset-1"], rows["genset-2"], rows["genset-3"]
        assert one["writer"] == wa.name and one["writer_live"] and two["writer"] == wb.name
        assert one["last_cycle"] == 9 and one["run_id"] == 1 and 0 <= one["last_cycle_age_s"] < 60
        assert one["engine"] == figure
        assert (one["active_alerts"], one["acknowledged_alerts"]) == (1, 1)
        assert two["engine"]["status"] == "unresolved" and two["engine"]["fmep_bar"] is None
        assert three["writer"] is None and not three["writer_live"] and three["last_cycle"] is None
        assert len(b.fleet(limit=2)) == 2
    finally:
        a.close()
        b.close()


def test_the_fleet_query_reads_no_cycles_estimates_or_whole_alert_table(store):
    """Bounded work per request: the plan touches the per-engine rows and the alerts' (engine_id, state) index,
    never the tables that grow with the cycles."""
    sql = store._fleet_sql()
    if store.dialect.name == "sqlite":
        plan = " ".join(str(r[-1]) for r in store._query("EXPLAIN QUERY PLAN " + sql, (1000,)))
        assert "alerts_state" in plan and "SCAN a " not in plan and "SCAN alerts" not in plan, plan
    else:
        with store._cursor() as cur:
            cur.execute("SET enable_seqscan = off")  # an empty table is scanned by choice; show what can be used
            plan = " ".join(r[0] for r in store._x(cur, "EXPLAIN " + sql, (1000,)).fetchall())
            cur.execute("RESET enable_seqscan")
        assert "alerts_state" in plan and "Seq Scan on alerts" not in plan, plan
    assert "cycles" not in sql.replace("engine_latest", "") and "estimates" not in sql


def test_get_fleet_serves_the_store_rows_and_says_when_there_is_no_store(store):
    from fastapi.testclient import TestClient
    from frictionwatch.service.api import create_app

    me = Writer.this_process()
    store.claim_engine(ENG, me)
    store.write_batch(ENG, cycles=[summary(i) for i in range(3)], alerts=[alert(1)],
                      engine_figure={"fmep_bar": 1.85, "fmep_sigma_bar": 0.025, "status": "measured", "reason": None})

    def down() -> list[dict]:
        raise StoreUnavailable(f"{store.where}: connection lost; next attempt in 0.5 s")

    with TestClient(create_app([], token="t", fleet=store.fleet)) as client:
        (row,) = client.get("/api/v1/fleet").json()
        assert row["engine_id"] == ENG and row["writer"] == me.name and row["last_cycle"] == 2
        assert row["engine"]["fmep_bar"] == 1.85 and row["active_alerts"] == 1
    with TestClient(create_app([], token="t")) as client:
        reply = client.get("/api/v1/fleet")
        assert reply.status_code == 404 and "--store" in reply.json()["detail"]
    with TestClient(create_app([], token="t", fleet=down)) as client:
        reply = client.get("/api/v1/fleet")
        assert reply.status_code == 503 and reply.headers["retry-after"] == "5"
        assert "connection" not in reply.json()["detail"]  # the store's URL and words stay in the log


# ---- serve --store ------------------------------------------------------------------------------------------------
def _serve(capsys, *argv: str) -> tuple[int, str]:
    from frictionwatch.service.cli import main

    rc = main(["serve", "--port", "0", *argv])
    return rc, capsys.readouterr().err


def test_serve_store_refuses_an_engine_another_live_process_writes(store_url, capsys):  # noqa: F811
    if not store_url.startswith("postgresql"):
        pytest.skip("--store takes a PostgreSQL URL (SQLite: --data-dir)")
    from tests.service.serve_helpers import DEMO

    holder = open_store(store_url)
    try:
        holder.claim_engine("genset-a", Writer("plant-b", 4242, "0badc0de"))
        rc, err = _serve(capsys, "--store", store_url, "--source", f"mcap:{DEMO}#genset-a")
        assert rc == 2 and err.count("\n") == 1, err
        assert "engine genset-a is written by plant-b:4242:0badc0de" in err and "one engine id, one writer" in err
        assert [r["writer"] for r in holder.fleet()] == ["plant-b:4242:0badc0de"]  # its lease untouched
    finally:
        holder.close()


def test_serve_store_says_in_one_line_what_is_wrong(capsys, monkeypatch, tmp_path):
    rc, err = _serve(capsys, "--store", "postgresql://fw:s3cret@127.0.0.1:1/fw")  # nothing listens on port 1
    assert rc == 2 and err.count("\n") == 1 and "cannot connect" in err and "s3cret" not in err and "fw:***@" in err
    rc, err = _serve(capsys, "--store", f"sqlite:{tmp_path / 'x.db'}")
    assert rc == 2 and "--store takes a postgresql://" in err
    rc, err = _serve(capsys, "--store", "postgresql://fw@127.0.0.1:1/fw", "--data-dir", str(tmp_path))
    assert rc == 2 and "not both" in err
    monkeypatch.setitem(sys.modules, "psycopg", None)  # psycopg not installed
    rc, err = _serve(capsys, "--store", "postgresql://fw@127.0.0.1:1/fw")
    assert rc == 2 and err.count("\n") == 1 and "needs psycopg 3" in err


def test_data_dir_attach_holds_the_lease_until_close(store_url):  # noqa: F811
    """What serve does: DataDir.attach claims the engine before anything is written (a second process's attach of
    the same engine id refused, its store untouched), the heartbeat thread renews it, close releases it."""
    from tests.service.serve_helpers import demo_service

    first, second = DataDir(store_url, heartbeat_s=0.2), DataDir(store_url)
    a, b = demo_service("genset-a"), demo_service("genset-a")
    try:
        first.attach(a)
        with pytest.raises(StoreError, match="engine genset-a is written by"):
            second.attach(b)
        assert second.engines == [] and second.store.runs("genset-a") == [{**first.store.runs("genset-a")[0]}]
        assert wait_until(lambda: first.leases["heartbeats"] >= 2, timeout=10.0)
        first.close()
        assert "run 2" in second.attach(b)  # the lease released at close: taken at once
        assert second.store.fleet()[0]["writer"] == second.writer.name
    finally:
        a.session.stop()
        b.session.stop()
        first.close()
        second.close()


def test_health_says_what_waits_for_a_store_that_is_down(store):
    """/health's engine row (service/api.py store_waiting): the cycles kept for the store while it is down make the
    service 'degraded'; what was lost stays counted."""
    from types import SimpleNamespace

    from frictionwatch.service.api import store_waiting

    listener = StoreListener(Unavailable(store), ENG, batch_cycles=5, max_delay_s=60.0)
    svc = SimpleNamespace(fanout=SimpleNamespace(listener=lambda name: listener if name == "store" else None))
    for i in range(7):  # one batch of 5 handed over and kept, 2 cycles still pending
        listener.on_cycle(summary(i))
    assert store_waiting(svc) == {"store_waiting_cycles": 5, "store_lost_cycles": 0}
    listener.stop()  # still down at stop: lost, counted
    assert store_waiting(svc) == {"store_waiting_cycles": 0, "store_lost_cycles": 7}
    no_store = SimpleNamespace(fanout=SimpleNamespace(listener=lambda name: None))
    assert store_waiting(no_store) == {"store_waiting_cycles": 0, "store_lost_cycles": 0}
