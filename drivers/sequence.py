"""Putting frames back in order by their modular sequence counter, and counting what went wrong on the way.

Used by the serial codec (one counter per link) and the CAN decoder (one counter per cylinder). For each frame:

- the expected one is released at once, with any held frames that follow it;
- one from ahead is held (a reordered frame may still come) until more than ``window`` are held, then the missing
  ones are given up as lost (``frames_lost``) and the held frames are released; ``window=0`` never holds;
- one from behind is a duplicate (``duplicate_frame``) or a frame given up earlier (``late_frame``): both dropped,
  since a stream of increasing time cannot take it any more;
- ``restart_after`` consecutive frames from behind mean the sender restarted its counter without saying so
  (``sequence_restart``): the tracker follows the new counter and flags the first released frame.

``flush()`` releases everything held (call it when the link is idle), ``reset()`` forgets the counter.
"""

from __future__ import annotations

from collections import Counter, deque
from typing import Generic, TypeVar

T = TypeVar("T")


class SequenceTracker(Generic[T]):
    """Release items in counter order; ``counts`` holds the reasons (lost, duplicate, late, reordered, restart)."""

    def __init__(self, modulus: int = 1 << 16, window: int = 4, restart_after: int = 32) -> None:
        if modulus < 4 or window < 0 or restart_after < 2:
            raise ValueError("need modulus >= 4, window >= 0, restart_after >= 2")
        self.modulus = modulus
        self.window = window
        self.restart_after = restart_after
        self.expected: int | None = None
        self.pending: dict[int, T] = {}
        self.counts: Counter[str] = Counter()
        self._lost: deque[tuple[int, int]] = deque(maxlen=32)  # (first seq, how many) given up
        self._stray: list[tuple[int, T]] = []

    # --- public -------------------------------------------------------------------------------------------------
    def push(self, seq: int, item: T) -> list[tuple[T, bool]]:
        """Offer one frame; returns ``(item, starts_new_counter)`` pairs now releasable, in order."""
        m = self.modulus
        seq %= m
        if self.expected is None:  # start: hold a few, a reordered first pair must not lose its first frame
            if seq in self.pending:
                self.counts["duplicate_frame"] += 1
                return []
            self.pending[seq] = item
            return self._start() if len(self.pending) > self.window else []
        d = (seq - self.expected) % m
        if d >= m // 2:
            return self._behind(seq, item)
        self._discard_stray()
        if d == 0:
            if self.pending:
                self.counts["reordered_frame"] += 1
            self.expected = (seq + 1) % m
            return [(item, False), *self._drain()]
        if seq in self.pending:
            self.counts["duplicate_frame"] += 1
            return []
        self.pending[seq] = item
        out: list[tuple[T, bool]] = []
        while len(self.pending) > self.window:
            out += self._skip_gap()
        return out

    def flush(self) -> list[tuple[T, bool]]:
        """Give up on every gap and release all held frames (link idle, or end of input)."""
        self._discard_stray()
        out: list[tuple[T, bool]] = []
        if self.expected is None and self.pending:
            out += self._start()
        while self.pending:
            out += self._skip_gap()
        return out

    def reset(self, start: int | None = None) -> list[tuple[T, bool]]:
        """Release what is held, then forget the counter (the sender announced a restart; ``start``: its new
        first counter value, if known)."""
        out = self.flush()
        self.expected = None if start is None else start % self.modulus
        self._lost.clear()
        return out

    def advance(self, first: int, count: int) -> bool:
        """Fast path: accept ``count`` consecutive frames starting at ``first`` if nothing is held and ``first`` is
        the expected counter; returns False (and changes nothing) otherwise."""
        if self.pending or self._stray or (self.expected is not None and first % self.modulus != self.expected):
            return False
        self.expected = (first + count) % self.modulus
        return True

    # --- internals ----------------------------------------------------------------------------------------------
    def _start(self) -> list[tuple[T, bool]]:
        m = self.modulus
        keys = list(self.pending)
        self.expected = next((c for c in sorted(keys) if all((k - c) % m < m // 2 for k in keys)), keys[0])
        dist = [(k - self.expected) % m for k in keys]
        if dist != sorted(dist):
            self.counts["reordered_frame"] += 1
        out = self._drain()
        while len(self.pending) > self.window:
            out += self._skip_gap()
        return out

    def _drain(self) -> list[tuple[T, bool]]:
        out = []
        while self.expected in self.pending:
            out.append((self.pending.pop(self.expected), False))
            self.expected = (self.expected + 1) % self.modulus  # type: ignore[operator]
        return out

    def _skip_gap(self) -> list[tuple[T, bool]]:
        assert self.expected is not None
        m, e = self.modulus, self.expected
        nxt = min(self.pending, key=lambda s: (s - e) % m)
        missing = (nxt - e) % m
        self.counts["frames_lost"] += missing
        self._lost.append((e, missing))
        self.expected = nxt
        return self._drain()

    def _was_lost(self, seq: int) -> bool:
        return any((seq - first) % self.modulus < n for first, n in self._lost)

    def _discard_stray(self) -> None:
        for seq, _ in self._stray:
            self.counts["late_frame" if self._was_lost(seq) else "duplicate_frame"] += 1
        self._stray.clear()

    def _behind(self, seq: int, item: T) -> list[tuple[T, bool]]:
        if not (self._stray and seq == (self._stray[-1][0] + 1) % self.modulus):
            self._discard_stray()
        self._stray.append((seq, item))
        if len(self._stray) < self.restart_after:
            return []
        stray, self._stray = self._stray, []
        out = self.flush() if self.pending else []
        self.counts["sequence_restart"] += 1
        self._lost.clear()
        self.expected = (stray[-1][0] + 1) % self.modulus
        return out + [(it, i == 0) for i, (_, it) in enumerate(stray)]
