"""Issue 28 item 6 and the large-query limit: the token before the body, a body-size limit, errors that do not echo
the input, 429 with Retry-After. The engines are not started (manage=False): these are about the HTTP edge."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from frictionwatch.service.api import LARGE_BURST, MAX_WINDOW_CYCLES, create_app
from frictionwatch.service.request_guard import MAX_BODY_BYTES

from tests.service.serve_helpers import demo_service

TOKEN = "t0ken-for-the-tests-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
ACK = "/api/v1/engines/demo/alerts/1/acknowledge"


@pytest.fixture(scope="module")
def client():
    svc = demo_service("demo")
    with TestClient(create_app([svc], token=TOKEN, manage=False)) as c:
        yield c
    svc.session.stop()


def test_the_token_is_checked_before_the_body(client) -> None:
    broken = b'{"by": "x"'  # malformed JSON: parsed first, it would be a 422
    r = client.post(ACK, content=broken, headers={"Content-Type": "application/json"})
    assert r.status_code == 401 and r.headers["WWW-Authenticate"] == "Bearer"
    r = client.post(ACK, content=broken, headers={"Content-Type": "application/json",
                                                  "Authorization": "Bearer wrong-token-0123456789"})
    assert r.status_code == 401
    r = client.post(ACK, content=broken, headers={"Content-Type": "application/json", **AUTH})
    assert r.status_code == 422 and isinstance(r.json()["detail"], str)  # with the token: parsed, one line
    r = client.post(ACK, json={"by": "ann"}, headers=AUTH)
    assert r.status_code == 404  # through to the route: this engine runs without alerts


def test_a_body_past_the_limit_is_refused(client) -> None:
    big = b'{"by": "' + b"x" * MAX_BODY_BYTES + b'"}'
    r = client.post(ACK, content=big, headers={"Content-Type": "application/json", **AUTH})
    assert r.status_code == 413 and str(MAX_BODY_BYTES) in r.json()["detail"]

    def chunks():  # no Content-Length: counted as it comes
        for _ in range(8):
            yield b"x" * (MAX_BODY_BYTES // 4)

    r = client.post(ACK, content=chunks(), headers={"Content-Type": "application/json", **AUTH})
    assert r.status_code == 413
    small = client.post(ACK, content=b'{"by": "' + b"x" * 60 + b'"}',
                        headers={"Content-Type": "application/json", **AUTH})
    assert small.status_code == 404  # a body within the limit reaches the route


@pytest.mark.parametrize("path", [  # 60 kB: httpx refuses a URL past 64 kB
    "/api/v1/engines/" + "a" * 60_000 + "/losses",
    "/api/v1/engines/demo/losses?window_cycles=" + "9" * 60_000,
    "/api/v1/engines/demo/alerts?state=" + "z" * 60_000,
    "/api/v1/stream?engine_id=" + "B" * 60_000,
])
def test_errors_do_not_echo_the_input(client, path: str) -> None:
    r = client.get(path)
    assert r.status_code == 422
    assert len(r.content) < 400, r.text[:400]
    assert "aaaa" not in r.text and "9999" not in r.text and "zzzz" not in r.text and "BBBB" not in r.text
    assert isinstance(r.json()["detail"], str) and "\n" not in r.json()["detail"]


def test_a_body_that_is_too_long_is_not_echoed(client) -> None:
    r = client.post(ACK, json={"by": "n" * 10_000}, headers=AUTH)
    assert r.status_code in (404, 422) and len(r.content) < 400


def test_window_lengths_are_bounded(client) -> None:
    r = client.get("/api/v1/engines/demo/losses", params={"window_cycles": MAX_WINDOW_CYCLES + 1})
    assert r.status_code == 422 and str(MAX_WINDOW_CYCLES) in r.json()["detail"]
    assert client.get("/api/v1/engines/demo/losses", params={"window_cycles": MAX_WINDOW_CYCLES}).status_code == 503


def test_large_queries_are_rate_limited(client) -> None:
    codes = [client.get("/api/v1/engines/demo/speed", params={"cycles": MAX_WINDOW_CYCLES}) for _ in
             range(int(LARGE_BURST) + 5)]
    limited = [r for r in codes if r.status_code == 429]
    assert limited, [r.status_code for r in codes]
    assert all(int(r.headers["Retry-After"]) >= 1 and "retry after" in r.json()["detail"] for r in limited)
    assert all(r.status_code in (429, 503) for r in codes)  # no result yet: 503 where let through
    small = client.get("/api/v1/engines/demo/speed", params={"cycles": 200})
    assert small.status_code == 503  # a small history is never limited
    text = client.get("/metrics").text
    assert "frictionwatch_rate_limited_total" in text
    assert 'frictionwatch_http_request_seconds_count{route="speed"}' in text  # the server's side of a client's p99
