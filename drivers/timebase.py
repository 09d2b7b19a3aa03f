"""Unwrapping the acquisition board's free-running 32-bit timer into one int64 tick stream.

The tooth board (serial) and the pressure DAQ (CAN) stamp their data with the same free-running timer
(docs/protocols.md §1). Each raw value is unwrapped to the int64 tick nearest to the last unwrapped value, so all
sources of one session that share a ``TimerUnwrapper`` (``Clocks.get("daq")``; ``shared_unwrapper("daq")`` outside a
session) agree on the epoch, whichever of them saw the timer first. This is exact while consecutive values of the timer seen by the process are less than
2**31 ticks apart (214 s at 10 MHz); the serial board's heartbeat frame keeps that true while the engine stands.

A value that maps further back than ``restart_threshold`` ticks (2**28) is a timer restart (board reset): the
stream is re-based so that value lands ``REBASE_GAP`` ticks after the last one. The gap is deliberately long (2**32
ticks), so nothing downstream bridges the old and the new timer with a made-up interval. When the sender flags a
restart (serial BOOT, CAN FD Restart) the stream is re-based whatever the step, unless it was re-based within
``hint_threshold`` ticks (2**24) of this value already: both sources of one board flag the same restart, and the
second flag must not re-base again.
"""

from __future__ import annotations

import threading

import numpy as np

REBASE_GAP = 1 << 32


class TimerUnwrapper:
    """Nearest-value unwrapping of a ``bits``-bit counter into int64 ticks (thread-safe).

    Parameters
    ----------
    bits : int
        Width of the raw counter (32 for the frictionwatch board).
    restart_threshold : int
        A raw value that maps more than this many ticks *before* the last value is taken as a timer restart.
    """

    def __init__(self, bits: int = 32, restart_threshold: int = 1 << 28, hint_threshold: int = 1 << 24) -> None:
        if not 8 <= bits <= 62:
            raise ValueError(f"bits must be in 8..62, got {bits}")
        self.modulus = 1 << bits
        self.half = 1 << (bits - 1)
        if not 0 < restart_threshold < self.half:
            raise ValueError("restart_threshold must be in (0, 2**(bits-1))")
        self.restart_threshold = restart_threshold
        self.hint_threshold = min(hint_threshold, restart_threshold)
        self.last: int | None = None  # last unwrapped value
        self._last_raw = 0  # its raw value (differs from last mod 2**bits after a re-base)
        self._rebase_raw: int | None = None  # raw value of the last re-base
        self.restarts = 0
        self._lock = threading.Lock()

    def _signed_step(self, raw: int) -> int:
        return ((raw - self._last_raw + self.half) % self.modulus) - self.half

    def unwrap(self, raw: int, restart_hint: bool = False) -> int:
        """Unwrapped tick of one raw timer value; updates the reference. ``restart_hint``: the sender flagged a
        restart with this value."""
        raw = int(raw) % self.modulus
        with self._lock:
            if self.last is None:
                self.last = self._last_raw = raw
                self._rebase_raw = raw if restart_hint else None
                return raw
            step = self._signed_step(raw)
            if step < -self.restart_threshold or (restart_hint and not self._same_restart(raw)):
                self.restarts += 1
                self._rebase_raw = raw
                step = REBASE_GAP
            self.last += step
            self._last_raw = raw
            return self.last

    def _same_restart(self, raw: int) -> bool:
        if self._rebase_raw is None:
            return False
        d = ((raw - self._rebase_raw + self.half) % self.modulus) - self.half
        return abs(d) < self.hint_threshold

    def peek(self, raw: int) -> int:
        """Unwrapped tick of ``raw`` without moving the reference (no restart detection)."""
        raw = int(raw) % self.modulus
        with self._lock:
            return raw if self.last is None else self.last + self._signed_step(raw)

    def rebase(self, raw: int) -> int:
        """Declare a timer restart at ``raw`` (e.g. the board's BOOT flag): it maps to last + REBASE_GAP."""
        raw = int(raw) % self.modulus
        with self._lock:
            self.restarts += 1
            self.last = raw if self.last is None else self.last + REBASE_GAP
            self._last_raw = self._rebase_raw = raw
            return self.last

    def unwrap_many(self, raw: np.ndarray, restart_hint: np.ndarray | None = None) -> np.ndarray:
        """Unwrap a sequence of raw values in arrival order (vectorised); each is nearest to its predecessor.
        ``restart_hint`` (bool per value): the sender flagged a restart there (handled one by one, they are rare)."""
        raw = np.asarray(raw, dtype=np.int64) % self.modulus
        if raw.size == 0:
            return np.empty(0, np.int64)
        hints = [] if restart_hint is None else np.flatnonzero(restart_hint).tolist()
        out = np.empty(raw.size, np.int64)
        start = 0
        for h in hints + [raw.size]:
            out[start:h] = self._unwrap_run(raw[start:h])
            if h < raw.size:
                out[h] = self.unwrap(int(raw[h]), restart_hint=True)
            start = h + 1
        return out

    def _unwrap_run(self, raw: np.ndarray) -> np.ndarray:
        if raw.size == 0:
            return np.empty(0, np.int64)
        with self._lock:
            if self.last is None:
                self.last = self._last_raw = int(raw[0])
            prev = np.concatenate(([self._last_raw], raw[:-1]))
            step = (raw - prev + self.half) % self.modulus - self.half
            restart = step < -self.restart_threshold
            if restart.any():
                self.restarts += int(restart.sum())
                self._rebase_raw = int(raw[np.flatnonzero(restart)[-1]])
                step[restart] = REBASE_GAP
            out = self.last + np.cumsum(step)
            self.last = int(out[-1])
            self._last_raw = int(raw[-1])
            return out


class Clocks:
    """The timers of one acquisition (one board, one session): name -> ``TimerUnwrapper``, created on first use.

    Sources of one session that read the same board name the same clock (``clock=daq`` in their URL, the default)
    and so agree on its epoch. Two sessions in one process (two engines, two boards) each hold their own ``Clocks``:
    one board's timer must never re-base another's (drivers.source.open_source takes the session's ``clocks``)."""

    def __init__(self) -> None:
        self._timers: dict[str, TimerUnwrapper] = {}
        self._lock = threading.Lock()

    def get(self, clock: str = "daq") -> TimerUnwrapper:
        with self._lock:
            if clock not in self._timers:
                self._timers[clock] = TimerUnwrapper()
            return self._timers[clock]

    def forget(self, clock: str | None = None) -> None:
        with self._lock:
            if clock is None:
                self._timers.clear()
            else:
                self._timers.pop(clock, None)


# the clocks of sources opened without a session's own (a single command-line session, tests): one per process
_PROCESS_CLOCKS = Clocks()


def shared_unwrapper(clock: str = "daq", clocks: Clocks | None = None) -> TimerUnwrapper:
    """The unwrapper of the timer named ``clock`` in ``clocks`` (default: the process-wide set, for a process that
    runs one session; a service running several engines passes each session's own)."""
    return (clocks or _PROCESS_CLOCKS).get(clock)


def forget_shared(clock: str | None = None) -> None:
    """Drop the process-wide unwrapper(s) (tests, or a deliberate new session)."""
    _PROCESS_CLOCKS.forget(clock)
