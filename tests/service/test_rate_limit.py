"""The large-query token bucket (service/rate_limit.py), on a fake clock."""

from __future__ import annotations

import pytest
from frictionwatch.service.rate_limit import TokenBucket


def test_burst_then_rate_then_retry_after() -> None:
    now = [0.0]
    bucket = TokenBucket(rate=2.0, burst=3.0, clock=lambda: now[0])
    assert [bucket.take() for _ in range(3)] == [0.0, 0.0, 0.0]
    assert bucket.take() == pytest.approx(0.5)  # one token per 0.5 s
    assert bucket.refused == 1
    now[0] = 0.5
    assert bucket.take() == 0.0 and bucket.take() > 0
    now[0] = 100.0  # an idle bucket refills to the burst, no further
    assert [bucket.take() for _ in range(4)].count(0.0) == 3
