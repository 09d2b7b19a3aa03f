"""Backpressure that is seen (issue 28 item 3): an engine whose ingest is held back shows its lag in /health
('degraded') and /metrics, its bounded queue drops the oldest and counts them, and a stop with a backlog says how
much it left. The pipeline is replaced by a slow stand-in: no numba, no results, only the queue at work."""

from __future__ import annotations

import logging
import threading
import time

import pytest
from fastapi.testclient import TestClient
from frictionwatch.service.api import LAG_DEGRADED_S, create_app
from prometheus_client.parser import text_string_to_metric_families

from tests.service.serve_helpers import DEMO, demo_service, wait_until

MAX_QUEUE_S = 1.0


def slow_feed(record) -> list:
    time.sleep(0.05)  # far slower than the demo's records arrive at real time
    return []


@pytest.fixture()
def held_back():
    svc = demo_service("slow", f"mcap:{DEMO}?speed=1&loop=1", max_queue_s=MAX_QUEUE_S,
                       warmup_s=0.0)  # a stand-in for a live board, which never waits
    svc.session.pipeline.feed = slow_feed
    with TestClient(create_app([svc])) as client:
        yield client, svc


def test_lag_shows_in_health_and_metrics(held_back) -> None:
    client, svc = held_back
    row = {}

    def behind() -> bool:
        nonlocal row
        row = client.get("/api/v1/health").json()["engines"][0]
        return row["behind"]

    assert wait_until(behind, timeout=10.0), row  # the check: within 10 s
    assert client.get("/api/v1/health").json()["status"] == "degraded"
    assert client.get("/api/v1/engines").json()[0]["backlog"]["behind"] is True  # what the dashboard shows
    assert row["realtime"] is True
    assert row["dropped_records"] > 0 or row["behind_s"] > LAG_DEGRADED_S
    assert wait_until(lambda: svc.backlog()["dropped_records"] > 0, timeout=10.0)
    lag = svc.backlog()
    assert lag["queued_s"] <= MAX_QUEUE_S + 0.1  # bounded: one batch of the demo's spans well under 0.1 s
    assert lag["dropped_s"] > 0
    fams = {f.name: f for f in text_string_to_metric_families(client.get("/metrics").text)}
    dropped = [s.value for s in fams["frictionwatch_ingest_dropped_records"].samples if s.name.endswith("_total")]
    assert dropped and dropped[0] > 0
    assert [s.labels["engine"] for s in fams["frictionwatch_ingest_queued_seconds"].samples] == ["slow"]


def test_a_stop_with_a_backlog_says_what_it_left(caplog) -> None:
    svc = demo_service("slow", f"mcap:{DEMO}?speed=1&loop=1", max_queue_s=MAX_QUEUE_S,
                       warmup_s=0.0)  # a stand-in for a live board, which never waits
    svc.session.pipeline.feed = slow_feed
    svc.start()
    try:
        assert wait_until(lambda: svc.backlog()["queued_s"] > 0.5, timeout=10.0)
    finally:
        with caplog.at_level(logging.WARNING):
            svc.stop(timeout=0.3)
    records, span_s = svc.session.left_at_stop
    assert records > 0 and 0 < span_s <= MAX_QUEUE_S + 0.1
    assert not any(t.is_alive() for t in svc.session.threads)
    assert any("unanalysed" in r.getMessage() for r in caplog.records)


def test_a_fast_replay_waits_instead_of_dropping() -> None:
    svc = demo_service("fast", max_queue_s=0.2)  # the log read as fast as it can be: the reader waits for room
    svc.session.pipeline.feed = lambda r: (time.sleep(0.002), [])[1]
    svc.start()
    try:
        assert wait_until(lambda: svc.sources_ended, timeout=60.0)
        lag = svc.backlog()
        assert lag["realtime"] is False and lag["dropped_records"] == 0
    finally:
        svc.stop()
    assert svc.session.records_fed > 0 and svc.session.left_at_stop in (None, (0, 0.0))


def test_a_shutdown_drains_every_engine_at_once() -> None:
    """The app's shutdown (SIGTERM) stops all engines together: asyncio's default pool (cores + 4 threads) stopped 20
    engines six at a time, 31 s where each engine's drain is bounded at 5 s. Here each stop waits until all of them
    have begun (a barrier), so a shutdown that runs them in turns never ends its first stop."""
    n = 12  # more than asyncio's default pool holds on a 2-core box (6 threads)
    services = [demo_service(f"g{i}", f"mcap:{DEMO}?speed=1&loop=1", warmup_s=0.0) for i in range(n)]
    for svc in services:
        svc.session.pipeline.feed = lambda r: []  # no numba: only the sessions' threads
    began = threading.Barrier(n, timeout=20.0)
    passed = []

    def stop_after_all_began(stop):
        def stop_all_at_once(timeout=None):
            try:
                began.wait()
                passed.append(True)
            except threading.BrokenBarrierError:
                passed.append(False)
            stop(timeout)
        return stop_all_at_once

    for svc in services:
        svc.stop = stop_after_all_began(svc.stop)
    with TestClient(create_app(services)) as client:
        assert client.get("/api/v1/health").status_code == 200
    assert passed == [True] * n
    assert not any(t.is_alive() for svc in services for t in svc.session.threads)


def health_row(**given) -> dict:
    row = {"running": True, "last_cycle_age_s": 0.1, "behind": False, "store_waiting_cycles": 0, "warming_up": False,
           "holding": False, "dropped_records": 0, "queued_s": 0.0, "behind_s": 0.0, "held_s": 0.0}
    return {**row, **given}


def test_an_engine_catching_up_on_its_warm_ups_hold_is_starting_not_degraded() -> None:
    """After a board's warm-up the monitor is behind by what the hold kept (design note 136): /health says
    'starting' and the row's words say it catches up, while nothing was dropped; a hold that dropped records, an
    engine behind without a hold, or a stale one is 'degraded'; an engine still warming up is 'starting'."""
    from frictionwatch.service.api import catching_up_words, health_status

    fine = health_row()
    catching_up = health_row(behind=True, holding=True, queued_s=41.5, behind_s=43.0, held_s=62.0,
                             last_cycle_age_s=0.2)
    assert health_status([fine]) == "ok"
    assert health_status([fine, catching_up]) == "starting"
    assert health_status([health_row(warming_up=True, holding=True, last_cycle_age_s=None), catching_up]) == "starting"
    assert catching_up_words(catching_up) == ("catching up on the input held while the kernels warmed up: 41.5 s "
                                              "queued, 43.0 s behind (the most held: 62.0 s), nothing dropped")
    for bad in (health_row(behind=True, holding=True, dropped_records=5),  # the hold's bound was reached: lost data
                health_row(behind=True),  # behind with no hold: a plant that does not keep up
                health_row(holding=True, last_cycle_age_s=30.0, dropped_records=1)):
        assert health_status([catching_up, bad]) == "degraded", bad
        assert catching_up_words(bad) is None
    assert catching_up_words(health_row(warming_up=True, holding=True)) is None  # the warm-up's own words say it
    assert catching_up_words(fine) is None
