"""The container's health check (service/healthcheck.py, Dockerfile HEALTHCHECK): a degraded service is alive and
serving, so healthy; no answer, a reply without a status, or a dead engine is unhealthy. Checked on /health's real
replies (an engine lagging, as tests/service/test_api_backlog.py makes one) and against a closed port."""

from __future__ import annotations

import socket
import time

import pytest
from fastapi.testclient import TestClient
from frictionwatch.service import healthcheck
from frictionwatch.service.api import create_app
from frictionwatch.service.api_models import Health

from tests.service.serve_helpers import DEMO, demo_service, wait_until

ENGINE = {"engine_id": "g1", "running": True, "sources_ended": False, "last_cycle_age_s": 0.2, "behind": False}


@pytest.mark.parametrize(("doc", "healthy", "words"), [
    ({"status": "ok", "engines": [ENGINE]}, True, "healthy: ok"),
    ({"status": "degraded", "engines": [{**ENGINE, "behind": True}]}, True, "behind: g1"),
    ({"status": "degraded", "engines": [{**ENGINE, "last_cycle_age_s": None}]}, True, "healthy: degraded"),
    # a replay that ended: its threads end with it, that is not a failure
    ({"status": "degraded", "engines": [{**ENGINE, "running": False, "sources_ended": True}]}, True, "degraded"),
    ({"status": "degraded", "engines": [{**ENGINE, "running": False}]}, False, "engine g1 stopped"),
    # the warm-up compiling the kernels (service/warmup.py): alive, healthy
    ({"status": "starting", "engines": [{**ENGINE, "last_cycle_age_s": None}]}, True, "healthy: starting"),
    ({"status": "booting"}, False, "did not answer with a status"),
    ({"detail": "Internal Server Error"}, False, "did not answer with a status"),
    ([1, 2], False, "did not answer with a status"),
])
def test_verdict(doc, healthy: bool, words: str) -> None:
    got, why = healthcheck.verdict(doc)
    assert got is healthy and words in why, why


def test_a_lagging_engine_is_degraded_and_healthy() -> None:
    """/health's own reply for an engine held back (the pipeline a slow stand-in, as in test_api_backlog.py): it
    falls behind, /health says 'degraded' and why; the container stays healthy."""
    svc = demo_service("slow", f"mcap:{DEMO}?speed=1&loop=1", max_queue_s=1.0,
                       warmup_s=0.0)  # a stand-in for a live board, which never waits
    svc.session.pipeline.feed = lambda record: (time.sleep(0.05), [])[1]
    with TestClient(create_app([svc])) as client:
        assert wait_until(lambda: client.get("/api/v1/health").json()["engines"][0]["behind"], timeout=10.0)
        doc = client.get("/api/v1/health").json()
    Health.model_validate(doc)
    assert doc["status"] == "degraded"
    healthy, why = healthcheck.verdict(doc)
    assert healthy and "behind: slow" in why, why


def test_no_answer_is_unhealthy(capsys) -> None:
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert healthcheck.main([f"http://127.0.0.1:{port}/api/v1/health"]) == 1
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith("unhealthy:"), out
