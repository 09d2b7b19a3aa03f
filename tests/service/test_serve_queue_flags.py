"""serve --max-queue-s, --drain-s and --hold-mb (issue 28 follow-up): the ingest queue's cap, the stop's drain and
the warm-up's hold reach each engine; a value out of range is refused in one line, exit 2, before any engine
starts."""

from __future__ import annotations

import argparse

import pytest
from frictionwatch.service.cli import build_parser
from frictionwatch.service.serve import DRAIN_S, MAX_QUEUE_S, build_engines
from frictionwatch.service.warmup import HOLD_BYTES

from tests.service.serve_helpers import DEMO
from tests.service.test_serve_security import one_line_error


@pytest.mark.parametrize("argv, words", [
    (["--max-queue-s", "0.5"], "--max-queue-s must be 1 to 600 seconds, got 0.5"),
    (["--max-queue-s", "601"], "--max-queue-s must be 1 to 600 seconds, got 601"),
    (["--max-queue-s", "nan"], "--max-queue-s must be 1 to 600 seconds, got nan"),
    (["--max-queue-s", "inf"], "--max-queue-s must be 1 to 600 seconds, got inf"),
    (["--drain-s", "-1"], "--drain-s must be 0 to 600 seconds, got -1"),
    (["--drain-s", "1e9"], "--drain-s must be 0 to 600 seconds, got 1e+09"),
    (["--hold-mb", "-1"], "--hold-mb must be 0 to 16384, got -1"),
    (["--hold-mb", "16385"], "--hold-mb must be 0 to 16384, got 16385"),
])
def test_out_of_range_is_one_line(capsys, argv: list[str], words: str) -> None:
    line = one_line_error(capsys, ["serve", "--port", "0", *argv])
    assert line.startswith("frictionwatch serve: error:") and words in line, line


def _args(*argv: str) -> argparse.Namespace:
    return build_parser().parse_args(["serve", "--source", f"mcap:{DEMO}", *argv])


@pytest.mark.parametrize(("argv", "queue_s", "drain_s"), [((), MAX_QUEUE_S, DRAIN_S),
                                                          (("--max-queue-s", "2.5", "--drain-s", "0"), 2.5, 0.0)])
def test_the_values_reach_the_session(argv, queue_s: float, drain_s: float) -> None:
    (svc,) = build_engines(_args(*argv), None)
    try:
        session = svc.session
        assert session.max_queue_s == queue_s and session.drain_s == drain_s
        # the queue's bound in ticks of the engine's clock: what the policy is enforced on (service/ingest_queue.py)
        assert session._queue.max_span == pytest.approx(queue_s * svc.info.tick_hz, rel=1e-12)
        assert svc.backlog()["max_queue_s"] == queue_s
    finally:
        svc.stop()
    assert svc.session.drain_s == drain_s  # the stop (as the app's lifespan calls it) drained for --drain-s


@pytest.mark.parametrize(("argv", "hold_bytes"), [((), HOLD_BYTES), (("--hold-mb", "3"), 3 * 2**20),
                                                  (("--hold-mb", "0"), 0)])
def test_the_hold_reaches_the_warm_start(argv, hold_bytes: int) -> None:
    """--hold-mb: what a board's queue holds while the warm-up runs (service/warmup.py WarmStart; 0: no hold)."""
    (svc,) = build_engines(_args(*argv), None)
    try:
        assert svc.warm_start is not None and svc.warm_start.hold_bytes == hold_bytes
    finally:
        svc.stop()
