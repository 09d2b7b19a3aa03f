"""Bounded work per request (issue 28 item 2): a window mean costs the same for any window, and equals the mean
computed from every cycle of the window (service/window_figures.figures_from_cycles, the reference)."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.service import api_views as views
from frictionwatch.service.api import create_app
from frictionwatch.service.window_figures import figures_from_cycles

from tests.json_close import assert_json_close
from tests.service.serve_helpers import DEMO, demo_service, wait_until

HISTORY = 16  # fewer than the demo's cycles: the running sums wrap around


@pytest.fixture(scope="module")
def served():
    svc = demo_service("demo", history_cycles=HISTORY)
    with TestClient(create_app([svc])) as client:
        assert wait_until(lambda: svc.sources_ended and svc.cycles_ok > HISTORY and
                          svc.state.snapshot(1)[0] is svc.session.results[-1], timeout=900, every=0.5)
        yield client, svc


@pytest.mark.parametrize("window", [1, 2, 7, HISTORY])
def test_a_window_mean_equals_the_mean_over_every_cycle(served, window: int) -> None:
    client, svc = served
    doc = client.get("/api/v1/engines/demo/losses", params={"window_cycles": window}).json()
    last, ring = svc.state.snapshot(window)
    expected = views.losses_window("demo", last, figures_from_cycles(ring), svc.term_names)
    # sums about a shift against numpy's mean and std: equal to ~1e-12; 1e-9 leaves room, not for a wrong mean
    assert_json_close(doc, json.loads(json.dumps(expected)), rtol=1e-9, atol=1e-12)
    assert doc["window"]["cycles"] == window
    assert svc.state.sums.appends == svc.cycles_ok  # one row per cycle, made once whatever the requests


def test_a_window_request_costs_the_same_for_any_window(served, monkeypatch) -> None:
    """The cost counted in the operation that made a window expensive: reading a cycle's document (to_json)."""
    client, svc = served
    calls = {"n": 0}
    original = CycleResult.to_json

    def counted(self, *args, **kwargs):
        calls["n"] += 1
        return original(self, *args, **kwargs)

    monkeypatch.setattr(CycleResult, "to_json", counted)
    costs = {}
    for window in (1, HISTORY):
        calls["n"] = 0
        assert client.get("/api/v1/engines/demo/losses", params={"window_cycles": window}).status_code == 200
        costs[window] = calls["n"]
    assert costs[1] == costs[HISTORY] <= 2, costs  # the newest cycle's status, nothing per cycle of the window
    calls["n"] = 0
    reference = figures_from_cycles(svc.state.snapshot(HISTORY)[1])
    assert calls["n"] == HISTORY and reference.cycles == HISTORY  # the count can see per-cycle work


def test_a_fast_replay_loses_no_cycle_to_the_bounded_queue(served) -> None:
    _, svc = served
    lag = svc.backlog()
    assert lag["realtime"] is False and lag["dropped_records"] == 0 and lag["queued_batches"] == 0


def test_the_monitor_never_waits_for_the_api() -> None:
    """A request holding the API-state lock (the longest any route holds it) does not hold the ingest thread: cycles
    go on being analysed while it is held; the API catches up after."""
    svc = demo_service("held", "mcap:" + str(DEMO) + "?loop=1", history_cycles=64)
    svc.start()
    try:
        assert wait_until(lambda: svc.cycles_ok > 5, timeout=900)
        with svc.state._lock:
            before = svc.session.cycles_ok
            assert wait_until(lambda: svc.session.cycles_ok >= before + 20, timeout=60)
        assert wait_until(lambda: svc.state.newest is not None and svc.state.newest.index >= before + 19, timeout=60)
    finally:
        svc.stop()
