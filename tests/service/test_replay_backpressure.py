"""A log read as fast as it can be (not real time) waits for its listeners; a stop ends that wait at its deadline
and says what it left; a real-time source never waits (issue 28 items 1 and 3, design note 57).

The store here is the real one (SQLite; PostgreSQL where FW_TEST_POSTGRES_URL is set), joined by DataDir as serve
joins it, each cycle its own commit slowed by ~20 ms (tests/service/slow_store.py): ~45 cycles a second, several
times slower than the monitor on the demo log read as fast as possible. The log is the demo played several times
over and then ended, so the run has a last cycle to compare with."""

from __future__ import annotations

import logging
import threading
import time

import pytest
from frictionwatch.drivers.logs.mcap_replay import McapSource
from frictionwatch.service.listeners import Listener, ServiceEvent

from tests.service.serve_helpers import DEMO, FakeAlerts, demo_service, wait_until
from tests.service.slow_store import ENGINE, DemoPasses, slow_store_engine, stored
from tests.service.test_store_backends import store_url  # noqa: F401 - the fixture, on both backends

WRITE_S = 0.02  # what each slowed commit takes on top of its own time
pytestmark = [pytest.mark.timeout(300)]


def test_a_fast_replay_keeps_every_cycle_in_a_slow_store(store_url):  # noqa: F811
    # a queue of 8 events: the store falls behind within a pass (the default 256 would hide it on a short log)
    data, svc = slow_store_engine(store_url, DemoPasses(5), WRITE_S, queue_size=8)
    assert not svc.session.realtime
    try:
        svc.start()
        assert wait_until(lambda: svc.sources_ended, timeout=240), "the replay did not end"
        svc.stop()
        analysed = [int(r.index) for r in svc.session.results]
        assert len(analysed) == svc.cycles_ok > 150  # five passes of ~40 cycles less the seams'
        assert svc.fanout.drops["store"] == 0 and svc.fanout.left["store"] == 0
        assert stored(data) == analysed  # every analysed cycle, once, in order
    finally:
        svc.stop()
        data.close()


def test_a_stop_during_a_fast_replay_keeps_its_deadline_and_says_what_it_left(tmp_path, caplog):
    data, svc = slow_store_engine(tmp_path / "data", McapSource(DEMO, loop=True), WRITE_S)
    try:
        svc.start()
        # the store's queue full: the replay waits for room, its reader for the ingest thread
        assert wait_until(lambda: svc.fanout.queued["store"] >= svc.fanout.queue_size - 1, timeout=240)
        caplog.set_level(logging.WARNING, logger="frictionwatch.service.engine_service")
        drain_s = 1.0
        t0 = time.monotonic()
        svc.stop(drain_s)
        took = time.monotonic() - t0
        kept = len(stored(data))
    finally:
        svc.stop()
        data.close()
    # the drain, the cycle in progress and the pipeline's flush (LiveSession.stop's 2 s), the listeners' drain_s
    assert took < drain_s + 2.0 + drain_s + 1.0, took
    left = svc.fanout.left["store"]
    assert left > 0  # ~250 queued at ~20 ms each cannot all be written in the listeners' 1 s
    # every analysed cycle is either stored or counted as left (no alerts here: every event is a cycle's)
    assert kept + left + svc.fanout.drops["store"] == svc.cycles_ok
    lines = [r.getMessage() for r in caplog.records if r.name == "frictionwatch.service.engine_service"]
    # one line: the events, and the read-ahead the drain did not reach if any (the replay waited for the store
    # meanwhile; how far its reader had got ahead by the stop varies from run to run)
    records = (svc.session.left_at_stop or (0, 0.0))[0]
    assert len(lines) == 1 and f"listeners: store {left}" in lines[0], lines
    assert ("not analysed" in lines[0]) == (records > 0) and (f"{records} records" in lines[0]) == (records > 0)


class Stuck(Listener):
    """Takes one event and never another until released: a listener that has stopped consuming."""

    name = "stuck"

    def __init__(self) -> None:
        self.release = threading.Event()
        self.got: list[ServiceEvent] = []

    def on_message_received(self, ev: ServiceEvent) -> None:
        self.got.append(ev)
        self.release.wait(30)


def test_a_real_time_replay_never_waits_for_a_listener():
    stuck = Stuck()
    svc = demo_service(ENGINE, f"mcap:{DEMO}?loop=1&speed=4", listeners=[stuck], queue_size=2)
    assert svc.session.realtime
    try:
        svc.start()
        # the monitor goes on past the stuck listener's queue of 2; what does not fit is dropped and counted
        assert wait_until(lambda: svc.cycles_ok >= 30, timeout=240)
        analysed = svc.cycles_ok  # read first: its newest event may not be handed on yet
        assert svc.fanout.drops["stuck"] >= analysed - 3 - 1
    finally:
        stuck.release.set()
        svc.stop()


def test_the_api_never_waits_for_a_waiting_replay_and_its_events_keep_their_order():
    """An acknowledgement made while the replay waits for a stuck listener returns at once; the listener gets the
    alert's raise before its acknowledgement (the order the alert engine made them in)."""
    stuck = Stuck()
    svc = demo_service(ENGINE, f"mcap:{DEMO}?loop=1", listeners=[stuck], queue_size=2,
                       alerts=lambda engine_id, spec: FakeAlerts(spec, at_cycle=3))
    assert not svc.session.realtime
    try:
        svc.start()
        # cycle 3 raises the alert; the stuck listener holds its first event and two queued: the replay waits
        assert wait_until(lambda: svc.alerts.alerts, timeout=240)
        assert wait_until(lambda: svc.fanout.queued["stuck"] == 2, timeout=60)
        held = svc.cycles_ok
        t0 = time.monotonic()
        svc.acknowledge(1, "alice")
        assert time.monotonic() - t0 < 0.5
        time.sleep(0.5)
        assert svc.cycles_ok <= held + 1  # the replay waits (the cycle in hand at most), not dropped on
        stuck.release.set()
        assert wait_until(lambda: any(e.result is None for e in stuck.got), timeout=60)
    finally:
        stuck.release.set()
        svc.stop()
    kinds = [(a["alert_id"], a["state"]) for e in stuck.got for a in e.alerts]
    assert kinds[:2] == [(1, "active"), (1, "acknowledged")], kinds
    assert svc.fanout.drops["stuck"] == 0


def test_a_replay_waiting_for_a_listener_says_so_in_health_and_metrics():
    """While a fast replay waits for a listener's full queue, /health names that listener (the replay runs at its
    pace: 'ok', nothing lost) and /metrics counts the seconds waited; both go when the listener is released."""
    from fastapi.testclient import TestClient
    from frictionwatch.service.api import create_app
    from prometheus_client.parser import text_string_to_metric_families

    stuck = Stuck()
    svc = demo_service(ENGINE, f"mcap:{DEMO}?loop=1", listeners=[stuck], queue_size=2)
    assert not svc.session.realtime

    def waited(client: TestClient) -> float:
        fams = {f.name: f for f in text_string_to_metric_families(client.get("/metrics").text)}
        return next(s.value for s in fams["frictionwatch_listener_waited_seconds"].samples
                    if s.labels == {"engine": svc.engine_id, "listener": "stuck"} and s.name.endswith("_total"))

    try:
        with TestClient(create_app([svc])) as client:
            assert wait_until(lambda: svc.fanout.waiting_for == "stuck", timeout=240)
            first = waited(client)
            time.sleep(0.3)
            assert waited(client) >= first + 0.25  # the wait in progress counts, not only finished ones
            row = client.get("/api/v1/health").json()["engines"][0]
            assert row["paced_by_listener"] == "stuck"
            info = client.get("/api/v1/engines").json()[0]
            assert info["listener_waited_s"]["stuck"] >= 0.3 and info["listener_left"]["stuck"] == 0
            stuck.release.set()
            assert wait_until(lambda: svc.fanout.waiting_for is None, timeout=30)
    finally:
        stuck.release.set()
        svc.stop()
    assert svc.fanout.drops["stuck"] == 0
