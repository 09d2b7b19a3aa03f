"""A token bucket for the API's large queries (issue 28 item 2): what a client may ask for costs the server at most
``rate`` large replies a second, with bursts of ``burst``; past that, 429 and the seconds after which one more is
allowed (``Retry-After``).

One bucket per app, not per client: what it protects is the box's CPU, which the monitor shares with the API, and
a client address is easy to change. Cheap routes (the newest cycle, a window mean from running sums, /health) are
never limited.

    bucket = TokenBucket(rate=10, burst=20)
    wait_s = bucket.take()      # 0.0: go ahead; > 0: refuse, retry after wait_s
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class TokenBucket:
    def __init__(self, rate: float, burst: float, clock: Callable[[], float] = time.monotonic) -> None:
        if not (rate > 0 and burst >= 1):
            raise ValueError(f"need rate > 0 and burst >= 1, got {rate}, {burst}")
        self.rate, self.burst, self.clock = float(rate), float(burst), clock
        self._tokens, self._at = float(burst), clock()
        self._lock = threading.Lock()
        self.refused = 0  # counted for /metrics

    def take(self, cost: float = 1.0) -> float:
        """Take ``cost`` tokens: 0.0 when they were there, else the seconds until they will be (nothing taken)."""
        with self._lock:
            now = self.clock()
            self._tokens = min(self.burst, self._tokens + (now - self._at) * self.rate)
            self._at = now
            if self._tokens >= cost:
                self._tokens -= cost
                return 0.0
            self.refused += 1
            return (cost - self._tokens) / self.rate
