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


class ReconnectingLink:
    """The read loop of a source on a link that can vanish (a serial port, a CAN bus), written once.

    A subclass provides ``backoff``, ``idle_flush_s``, ``LINK_ERRORS`` (what a lost link raises) and:
    ``_link_open()`` (is the link up), ``_open()`` (try to open it; True on success), ``_read_chunk(wait)`` (raw
    data waited for up to ``wait`` s; empty when none), ``_lose_link(exc)`` (count, log, close, back off),
    ``_decode(chunk)`` and ``_decode_flush()`` (records from raw data / released from the decoder's hold).
    While the link is down, reopening is tried whenever the back-off allows; a lost link releases what the decoder
    held, and so does a link idle for ``idle_flush_s``. Returns as soon as there are records, or at the timeout."""

    backoff: Backoff
    idle_flush_s: float
    LINK_ERRORS: tuple[type[BaseException], ...] = (OSError,)
    _last_data: float = 0.0

    def _link_open(self) -> bool:
        raise NotImplementedError

    def _open(self) -> bool:
        raise NotImplementedError

    def _read_chunk(self, wait: float):
        raise NotImplementedError

    def _lose_link(self, exc: BaseException) -> None:
        raise NotImplementedError

    def _decode(self, chunk) -> list:
        raise NotImplementedError

    def _decode_flush(self) -> list:
        raise NotImplementedError

    def _read_internal(self, timeout: float | None) -> list:
        deadline = None if timeout is None else time.monotonic() + timeout
        records: list = []
        while True:
            now = time.monotonic()
            remaining = 0.1 if deadline is None else max(0.0, deadline - now)
            if not self._link_open():
                if self.backoff.due(now) and self._open():
                    continue  # read at once from the reopened link
                time.sleep(min(self.backoff.wait_time(now), remaining, 0.1))
            else:
                try:
                    chunk = self._read_chunk(min(remaining, self.idle_flush_s))
                except self.LINK_ERRORS as exc:
                    self._lose_link(exc)
                    records += self._decode_flush()
                    continue
                if chunk:
                    self._last_data = time.monotonic()
                    records += self._decode(chunk)
                elif time.monotonic() - self._last_data >= self.idle_flush_s:
                    records += self._decode_flush()
            if records or (deadline is not None and time.monotonic() >= deadline):
                return records
