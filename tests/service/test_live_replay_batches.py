"""A replay paced by the wall clock is read in batches (LiveSession ``replay_batch_s``, design notes 31): the same
records reach the pipeline, in a few reads a second instead of one read (and one ingest wake-up) per record."""

from __future__ import annotations

import time

import pytest
from frictionwatch.drivers.source import StreamRestart, open_source
from frictionwatch.drivers.timebase import Clocks
from frictionwatch.service.live import LiveSession
from frictionwatch.service.pipeline import resolve_model
from frictionwatch.service.record_merge import record_key

from tests.service.serve_helpers import DEMO

RUN_S = 1.5


def run(batch_s: float) -> tuple[int, list]:
    """(reads that returned records, the records the pipeline got) over RUN_S s of the demo replayed at real time."""
    src = open_source(f"mcap:{DEMO}?speed=1&loop=1", Clocks())
    model = resolve_model(src.engine_toml, None, "demo", src.info)
    live = LiveSession(model, src.info, {"log": src}, start=False, replay_batch_s=batch_s)
    reads, fed = [], []
    read = src.read

    def counted(timeout=None):
        out = read(timeout)
        if out:
            reads.append(len(out))
        return out

    src.read = counted
    live.pipeline.feed = lambda record: fed.append(record) or []
    live.start()
    try:
        time.sleep(RUN_S)
    finally:
        live.stop()
    return len(reads), [r for r in fed if not isinstance(r, StreamRestart)]


@pytest.mark.parametrize("batch_s", [0.02, 0.04])  # 0.04: serve's default (design notes 34)
def test_a_paced_replay_is_read_in_batches_and_loses_nothing(batch_s):
    reads_1, fed_1 = run(0.0)
    reads_b, fed_b = run(batch_s)
    # one or two records a read without batching (the demo: ~300 a second), at most one read per batch with it
    assert reads_1 >= 0.5 * len(fed_1) and len(fed_1) > 200
    assert reads_b <= RUN_S / batch_s + 5 and len(fed_b) >= 3 * reads_b and reads_1 >= 2 * reads_b
    # the same records in the same order (each run's stop drains what was read; the batched one may end a batch
    # earlier: up to a batch of the demo's ~300 records a second)
    n = min(len(fed_1), len(fed_b))
    assert len(fed_b) >= len(fed_1) - 0.05 * 300 - 5 and n > 200
    assert [(type(r).__name__, record_key(r)) for r in fed_b[:n]] == [(type(r).__name__, record_key(r))
                                                                        for r in fed_1[:n]]
