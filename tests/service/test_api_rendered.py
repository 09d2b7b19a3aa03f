"""The read routes render their reply on their own worker thread (service/api.py ``rendered``, note 139): the reply
must be what FastAPI makes of the same view dict with the same response_model (validation, then its dump). Checked
route by route against a reference app whose route returns the view's dict and lets FastAPI render it, on one engine
stopped after the demo log (nothing changes between the two replies). The numbers compared with a stated tolerance."""

from __future__ import annotations

import dataclasses
import json
import math
import time

import numpy as np
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from frictionwatch.core.monitor.report.figure_status import friction_status
from frictionwatch.core.monitor.report.run_summary import active_flags
from frictionwatch.service import api_views as views
from frictionwatch.service.api import create_app
from frictionwatch.service.api_models import CycleSummary, FrictionTorque, Losses, Speed
from frictionwatch.service.listeners import ServiceEvent
from numpy.testing import assert_allclose

from tests.service.serve_helpers import demo_service, wait_until

BASE = "/api/v1/engines/demo"


@pytest.fixture(scope="module")
def served():
    svc = demo_service("demo").start()
    try:
        assert wait_until(lambda: svc.sources_ended and svc.session.cycles_ok > 0 and
                          svc.state.snapshot(1)[0] is svc.session.results[-1], timeout=900, every=0.5)
    finally:
        svc.stop()
    with TestClient(create_app([svc], manage=False)) as client:
        yield client, svc


def same(a, b, where: str = "") -> None:
    """Equal JSON documents: the same keys, lists and strings; numbers equal to 1e-12 relative."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            same(x, y, f"{where}[{i}]")
    elif isinstance(a, (int, float)) and not isinstance(a, bool):
        assert isinstance(b, (int, float)) and not isinstance(b, bool), where
        assert_allclose(b, a, rtol=1e-12, atol=0, err_msg=where)
    else:
        assert a == b, where


def reference(model, doc: dict) -> dict:
    """FastAPI's own rendering of ``doc`` under ``model``: a route that returns the dict."""
    ref = FastAPI()

    @ref.get("/x", response_model=model)
    def x() -> dict:
        return doc

    r = TestClient(ref).get("/x")
    assert r.status_code == 200
    return r.json()


def test_each_read_route_replies_what_fastapi_renders(served) -> None:
    client, svc = served
    whole, ring = svc.state.snapshot()
    last, figures = svc.state.window(50)
    holes = svc.state.holes_in(figures.first_cycle, figures.last_cycle)
    cases = {
        "/cycles/latest": (CycleSummary, views.cycle_summary("demo", whole)),
        "/friction-torque": (FrictionTorque, views.friction_torque(whole)),
        "/speed?cycles=30": (Speed, views.speed(whole, ring[-30:])),
        "/losses": (Losses, views.losses_now("demo", ring, svc.term_names)),
        "/losses?window_cycles=50": (Losses, views.losses_window("demo", last, figures, svc.term_names, holes)),
    }
    for path, (model, doc) in cases.items():
        r = client.get(BASE + path)
        assert r.status_code == 200 and r.headers["content-type"] == "application/json", path
        assert int(r.headers["content-length"]) == len(r.content), path
        same(reference(model, doc), r.json(), path)
    assert client.get(BASE + "/losses?window_cycles=0").status_code == 422  # the query still checked
    assert client.get("/api/v1/engines/nope/losses").status_code == 404  # the engine dependency (now a coroutine)


def test_health_and_engine_list_keep_their_shape(served) -> None:
    client, svc = served
    health = client.get("/api/v1/health").json()
    assert health["engines"][0]["engine_id"] == "demo" and health["fleet"] is False
    rows = client.get("/api/v1/engines").json()
    assert rows[0]["cycles_ok"] == svc.cycles_ok and rows[0]["n_cylinders"] == 20


def test_finite_list_is_none_where_not_finite() -> None:
    a = np.array([1.5, np.nan, -np.inf, 2.0, np.inf, -0.0])
    got = views._finite_list(a)
    assert got[1] is None and got[2] is None and got[4] is None
    assert_allclose([got[i] for i in (0, 3, 5)], [1.5, 2.0, -0.0], rtol=0, atol=0)
    assert all(type(v) is float for v in views._finite_list(np.arange(4.0)))
    assert not any(isinstance(v, float) and not math.isfinite(v) for v in got)


def test_window_documents_are_made_once_a_cycle_and_anew_for_a_new_one(served) -> None:
    """OwnEstimateDocuments: the newest result's document under a set of flags, made once and then shared; another
    result or other flags make another (never the one held)."""
    _, svc = served
    older, newer = svc.session.results[-2], svc.session.results[-1]
    docs = views.OwnEstimateDocuments()
    active = frozenset(older.flags)
    first = docs.get(older, active)
    assert docs.get(older, active) is first and docs.made == 1
    same(older.to_json(smoothed=False, status=friction_status(older.cycle, active)), first)
    other = docs.get(newer, active)
    assert docs.made == 2 and other["cycle"] == newer.index != first["cycle"]
    same(newer.to_json(smoothed=False, status=friction_status(newer.cycle, active)), other)
    flagged = active | {"misfire_cyl3"}
    assert docs.get(newer, flagged) is not other and docs.made == 3


def test_a_new_cycle_changes_the_window_reply(served) -> None:
    """An engine's API state fed the demo's results by hand: a window reply after each new cycle is that cycle's
    (the reference made without the shared documents), not the one held from the cycle before."""
    _, done = served
    svc = demo_service("fed")  # not started: nothing but this test feeds its API state
    results = done.session.results[-4:]
    with TestClient(create_app([svc], manage=False)) as client:
        replies: dict[int, list[dict]] = {1: [], 3: []}
        for r in results:
            svc.state.on_message_received(ServiceEvent("fed", r, time.monotonic()))
            for window in (1, 3):  # one cycle: its sigma is the newest cycle's own (from the document)
                got = client.get("/api/v1/engines/fed/losses", params={"window_cycles": window}).json()
                last, figures = svc.state.window(window)
                assert last is r
                same(reference(Losses, views.losses_window("fed", last, figures, svc.term_names)), got, str(window))
                replies[window].append(got)
    for window, got in replies.items():  # each cycle's its own
        assert len({json.dumps(x, sort_keys=True) for x in got}) == len(results), window


def test_the_smoothed_losses_read_from_the_held_arrays_are_the_rings_after_it_wraps(served) -> None:
    """LatestState.smoothed keeps each held result's index and smoothed weight in arrays beside its ring (the plain
    /losses route reads them instead of walking the ring): fed more results than it holds, every reply is
    views.losses_now over the ring's results (rtol 1e-12), and the arrays are the ring's, oldest first."""
    _, done = served
    svc = demo_service("held", history_cycles=3)  # not started: this test feeds its API state
    results = done.session.results[-7:]
    with TestClient(create_app([svc], manage=False)) as client:
        for i, r in enumerate(results):
            svc.state.on_message_received(ServiceEvent("held", r, time.monotonic()))
            ring = results[max(0, i - 2): i + 1]
            whole, index, weight, active = svc.state.smoothed()
            assert whole is r and index.tolist() == [x.index for x in ring]
            assert_allclose(weight, [x.smoothed.weight for x in ring], rtol=0, atol=0)
            assert active == active_flags([x.flags for x in ring], weight[-1])
            got = client.get("/api/v1/engines/held/losses").json()
            same(reference(Losses, views.losses_now("held", ring, svc.term_names)), got, f"cycle {r.index}")


def flagged_results(results, n: int) -> list:
    """``n`` results made from the demo's (cycled, numbered on): every third raises 'often', every 13th 'rare' (under
    run_summary.ACTIVE_SHARE of a window of HELD unless it is the newest), besides their own flags."""
    out = []
    for i in range(n):
        r = results[i % len(results)]
        extra = ("often",) * (i % 3 == 0) + ("rare",) * (i % 13 == 0)
        out.append(dataclasses.replace(r, index=1000 + i, flags=tuple(r.flags) + extra))
    return out


HELD = 12  # results the fed API state holds: the demo's smoothed weights reach past it and fall back (its seam)


def test_the_smoothed_reply_takes_its_active_flags_from_the_running_counts(served, monkeypatch) -> None:
    """LatestState.smoothed's active flags come from the window sums' flag counts (O(flags)), not from the held
    results: each cycle, with the ring wrapping and the reach (round(newest weight)) below and at the ring's length,
    they are run_summary.active_flags over the held results, and the plain /losses reply is views.losses_now's (the
    reference: every result read) - also where the sums do not cover the reach (started again: read from the ring)."""
    _, done = served
    svc = demo_service("flags", history_cycles=HELD)  # not started: this test feeds its API state
    results = flagged_results(done.session.results, 70)
    reaches, seen_often = set(), set()
    with TestClient(create_app([svc], manage=False)) as client:
        for i, r in enumerate(results):
            svc.state.on_message_received(ServiceEvent("flags", r, time.monotonic()))
            if i in (40, 41):  # the sums not covering the reach: the ring's flags are read instead
                monkeypatch.setattr(svc.state.sums, "flag_counts", lambda cycles: None)
            else:
                monkeypatch.undo()
            ring = results[max(0, i - HELD + 1): i + 1]
            _, _, weight, active = svc.state.smoothed()
            reaches.add(max(1, min(len(ring), round(weight[-1]))))
            assert active == active_flags([x.flags for x in ring], weight[-1]), f"cycle {r.index}"
            seen_often.add("often" in active)
            got = client.get("/api/v1/engines/flags/losses").json()
            same(reference(Losses, views.losses_now("flags", ring, svc.term_names)), got, f"cycle {r.index}")
    assert seen_often == {True, False} and min(reaches) < HELD and HELD in reaches, reaches  # the cases were met


def test_window_replies_are_made_once_a_cycle_and_window_length(served) -> None:
    """NewestReplies.window: within one cycle a window reply is made once per length of the window it covers (1000
    and 5000 cycles asked while fewer are held are one reply) and each is the reply made without the cache; a new
    cycle makes them anew."""
    _, done = served
    svc = demo_service("win")
    app = create_app([svc], manage=False)
    results = done.session.results[-6:]
    with TestClient(app) as client:
        for r in results:
            svc.state.on_message_received(ServiceEvent("win", r, time.monotonic()))
        got = {w: client.get("/api/v1/engines/win/losses", params={"window_cycles": w}) for w in (1000, 5000, 3, 1000)}
        assert got[1000].content == got[5000].content != got[3].content
        for w in (3, 5000):
            last, figures = svc.state.window(w)
            same(reference(Losses, views.losses_window("win", last, figures, svc.term_names)), got[w].json(), str(w))
        made = [c.windows_made for c in app.state.newest_replies.values()]
        assert made == [2]
        svc.state.on_message_received(ServiceEvent("win", dataclasses.replace(results[0], index=9999),
                                                   time.monotonic()))
        for w in (3, 5000):  # a window of the same length as before (3) is made again too
            again = client.get("/api/v1/engines/win/losses", params={"window_cycles": w})
            assert again.content != got[w].content
            last, figures = svc.state.window(w)
            same(reference(Losses, views.losses_window("win", last, figures, svc.term_names)), again.json(), str(w))
        assert [c.windows_made for c in app.state.newest_replies.values()] == [4]
