"""A fresh install compiles its kernels on the first cycle (35 s on a 2-core machine): a replay paced by the wall
clock waits for the monitor meanwhile instead of having its oldest data dropped, and its clock starts again at the
monitor is warm (issue 28: a new user's `make run` dropped ~37 s of the demo, ~458 cycles, on its first start). A
serial or CAN board never waits (test_api_backlog). The first cycle's compile is a stand-in: the pipeline's feed
sleeps on its first call, then hands back a result for every record."""

from __future__ import annotations

import time
from types import SimpleNamespace

import pytest
from frictionwatch.drivers.source import open_source
from frictionwatch.drivers.timebase import Clocks
from frictionwatch.service.live import WARM_RESULTS, LiveSession
from frictionwatch.service.pipeline import resolve_model

from tests.service.serve_helpers import DEMO, wait_until

COMPILE_S = 6.0  # the stand-in first cycle: three times the queue's bound
# The demo log's records carry about a second of acquisition each, so a bound of 1 s was one record: a loaded CI box that held
# the ingest thread for a moment after the warm-up dropped one (stop 31). Two seconds leave a batch of slack.
MAX_QUEUE_S = 2.0


def session(warmup_s: float) -> tuple[LiveSession, object]:
    src = open_source(f"mcap:{DEMO}?speed=1&loop=1", Clocks())
    model = resolve_model(src.engine_toml, None, "demo", src.info)
    live = LiveSession(model, src.info, {"log": src}, start=False, max_queue_s=MAX_QUEUE_S, warmup_s=warmup_s)
    calls = 0

    def feed(record) -> list:
        nonlocal calls
        calls += 1
        if calls == 1:
            time.sleep(COMPILE_S)
        return [SimpleNamespace(slim=lambda: None)]

    live.pipeline.feed = feed
    return live, src


@pytest.mark.parametrize("warmup_s, drops", [(60.0, False), (0.0, True)])
def test_a_paced_replay_waits_for_the_first_result_instead_of_dropping(warmup_s, drops):
    live, src = session(warmup_s)
    live.start()
    try:
        assert wait_until(lambda: live.cycles_ok >= WARM_RESULTS, 30.0)
        time.sleep(1.0)  # the replay at its pace again: nothing more to drop
        lag = live.lag()
    finally:
        live.stop()
    assert (lag.dropped_records > 0) == drops, lag
    if not drops:
        assert src._anchor is None or src._anchor[0] >= live._start_s + COMPILE_S - 0.5  # its clock started again
