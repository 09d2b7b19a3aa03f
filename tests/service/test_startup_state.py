"""What the service says before an engine's first cycle (issue 28 item 5; service/startup.py): 'starting' while
nothing compiles, 'compiling' once numba compiles a kernel in this process (a fresh install), 'running' from the
first result; the route the dashboard reads; the terminal's lines."""

from __future__ import annotations

import io
from types import SimpleNamespace

import numba
import pytest
from fastapi.testclient import TestClient
from frictionwatch.service.api import create_app
from frictionwatch.service.api_models import Startup
from frictionwatch.service.startup import COMPILING_WORDS, StartupState, StartupTicker


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def startup():
    state = StartupState(clock=Clock(), ours="tests.")  # the kernels this test compiles count as ours
    yield state
    state.close()


def _compile_a_new_kernel(offset: float) -> None:
    """A kernel numba has never seen (no cache): one compilation event."""
    kernel = numba.njit(lambda x: x + offset)
    assert kernel(1.0) == 1.0 + offset


def test_starting_then_compiling_then_running(startup):
    engine = SimpleNamespace(engine_id="demo", cycles_ok=0)
    doc = startup.document([engine])
    assert (doc["state"], doc["kernels_compiled"]) == ("starting", 0)  # nothing compiled yet: from the cache
    _compile_a_new_kernel(0.5)
    doc = startup.document([engine])
    assert doc["state"] == "compiling" and doc["message"] == COMPILING_WORDS and doc["kernels_compiled"] >= 1
    startup.clock.t += 42.0
    assert startup.document([engine])["elapsed_s"] == 42.0
    engine.cycles_ok = 1
    doc = startup.document([engine, SimpleNamespace(engine_id="other", cycles_ok=0)])
    # the least advanced engine decides the whole; each engine has its own
    assert doc["state"] == "compiling" and [e["state"] for e in doc["engines"]] == ["running", "compiling"]
    doc = startup.document([engine])
    assert doc["state"] == "running" and doc["message"] is None
    Startup.model_validate(doc)


def test_the_terminal_says_what_it_waits_for(startup):
    engine = SimpleNamespace(engine_id="demo", cycles_ok=0)
    ticker = StartupTicker(lambda: [engine], startup, out=io.StringIO())
    text, done = ticker.line()
    assert not done and text.startswith("frictionwatch serve: waiting for the first cycle")
    _compile_a_new_kernel(1.5)
    text, done = ticker.line()
    assert not done and text.startswith(f"frictionwatch serve: {COMPILING_WORDS}: ")
    assert "service.test_startup_state" in text  # the kernel compiled last, named
    engine.cycles_ok = 3
    text, done = ticker.line()
    assert done and "first cycle analysed after" in text and "cached for the next start" in text


def test_the_app_serves_the_startup_state():
    app = create_app([], manage=False)
    with TestClient(app) as client:
        doc = client.get("/api/v1/startup").json()
    Startup.model_validate(doc)
    assert doc["engines"] == [] and doc["state"] == "running"
    assert "/api/v1/startup" in app.openapi()["paths"]
