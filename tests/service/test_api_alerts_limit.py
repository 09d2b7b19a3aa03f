"""GET .../alerts is bounded (issue 28 follow-up): ``limit`` (default 100, at most 1000) of the newest alerts, oldest
first, X-Total-Count saying how many there are; a limit out of range is a 422 that does not echo it."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from frictionwatch.service.api import DEFAULT_ALERTS, MAX_ALERTS, create_app

from tests.service.serve_helpers import FakeAlert, FakeAlerts, demo_service

HELD = 1500  # more than MAX_ALERTS: the cap is reached
URL = "/api/v1/engines/demo/alerts"


@pytest.fixture(scope="module")
def client():
    made = {}

    def alerts(engine_id, spec):
        made["alerts"] = FakeAlerts(spec)
        return made["alerts"]

    svc = demo_service("demo", alerts=alerts)
    held = made["alerts"].alerts
    for i in range(1, HELD + 1):  # every 10th still open, the others cleared
        held[i] = FakeAlert(i, 1 + i % 20, "ring_wear", i, float(i), state="active" if i % 10 == 0 else "cleared")
    try:
        with TestClient(create_app([svc], manage=False)) as c:
            yield c
    finally:
        svc.session.stop()


@pytest.mark.parametrize(("params", "ids", "total"), [
    ({"state": "all"}, range(HELD - DEFAULT_ALERTS + 1, HELD + 1), HELD),
    ({"state": "all", "limit": 3}, range(HELD - 2, HELD + 1), HELD),
    ({"state": "all", "limit": MAX_ALERTS}, range(HELD - MAX_ALERTS + 1, HELD + 1), HELD),
    ({"limit": 5}, range(HELD - 40, HELD + 1, 10), HELD // 10),
])
def test_the_newest_alerts_up_to_the_limit(client, params, ids, total: int) -> None:
    r = client.get(URL, params=params)
    assert r.status_code == 200
    assert [a["alert_id"] for a in r.json()] == list(ids)
    assert int(r.headers["X-Total-Count"]) == total


@pytest.mark.parametrize("limit", ["0", str(MAX_ALERTS + 1), "all", "9" * 40])
def test_a_limit_out_of_range_is_refused(client, limit: str) -> None:
    r = client.get(URL, params={"state": "all", "limit": limit})
    assert r.status_code == 422 and limit not in r.text


def test_the_openapi_says_the_bound(client) -> None:
    spec = client.get("/openapi.json").json()
    params = {p["name"]: p for p in spec["paths"]["/api/v1/engines/{engine_id}/alerts"]["get"]["parameters"]}
    assert params["limit"]["schema"]["maximum"] == MAX_ALERTS and params["limit"]["schema"]["default"] == DEFAULT_ALERTS
