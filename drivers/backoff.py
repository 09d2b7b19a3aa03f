"""Exponential back-off for reconnecting to a port or bus that vanished (USB adapter unplugged, interface down)."""

from __future__ import annotations

import time


class Backoff:
    """Delays ``first, first*factor, ...`` capped at ``cap`` seconds; ``reset()`` after a success.

    ``due()`` says whether the next attempt may run now; ``failed()`` schedules the one after.
    """

    def __init__(self, first: float = 0.05, factor: float = 2.0, cap: float = 5.0) -> None:
        if first <= 0 or factor < 1 or cap < first:
            raise ValueError("need first > 0, factor >= 1, cap >= first")
        self.first, self.factor, self.cap = first, factor, cap
        self.delay = first
        self.attempts = 0
        self._next_at = 0.0

    def due(self, now: float | None = None) -> bool:
        return (time.monotonic() if now is None else now) >= self._next_at

    def wait_time(self, now: float | None = None) -> float:
        """Seconds until the next attempt is due (0 if now)."""
        return max(0.0, self._next_at - (time.monotonic() if now is None else now))

    def failed(self, now: float | None = None) -> float:
        """Record a failed attempt; returns the delay before the next one."""
        self.attempts += 1
        delay = self.delay
        self._next_at = (time.monotonic() if now is None else now) + delay
        self.delay = min(self.cap, self.delay * self.factor)
        return delay

    def reset(self) -> None:
        self.delay = self.first
        self.attempts = 0
        self._next_at = 0.0
