"""Shared pieces of the wire drivers: timer unwrapping (drivers/timebase.py) and counter order (drivers/sequence.py)."""

from __future__ import annotations

import numpy as np
from frictionwatch.drivers.backoff import Backoff
from frictionwatch.drivers.sequence import SequenceTracker
from frictionwatch.drivers.timebase import REBASE_GAP, TimerUnwrapper, forget_shared, shared_unwrapper
from hypothesis import given, settings
from hypothesis import strategies as st

WRAP = 1 << 32


def test_vectorised_unwrap_equals_scalar_reference() -> None:
    rng = np.random.default_rng(5)
    true = 3 * WRAP - 10**9 + np.cumsum(rng.integers(0, 2**30, 2000))  # crosses several wraps
    raw = true % WRAP
    scalar = TimerUnwrapper()
    ref = np.array([scalar.unwrap(int(r)) for r in raw])
    vec = TimerUnwrapper()
    got = np.concatenate([vec.unwrap_many(raw[:700]), vec.unwrap_many(raw[700:])])
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(got - got[0], true - true[0])


def test_restart_detection_and_one_rebase_per_flagged_restart() -> None:
    u = TimerUnwrapper()
    u.unwrap(1_000_000_000)
    assert u.unwrap(5) == 1_000_000_000 + REBASE_GAP  # 1e9 ticks back: a restart, not a wrap
    v = TimerUnwrapper()
    v.unwrap(WRAP - 1000)
    first = v.unwrap(500, restart_hint=True)  # the board said so: even a small step forward is a restart
    assert first == WRAP - 1000 + REBASE_GAP
    assert v.unwrap(300, restart_hint=True) == first - 200  # the same restart flagged by the other source
    np.testing.assert_array_equal(v.unwrap_many(np.array([400, 600]), np.array([True, False])), [first - 100,
                                                                                               first + 100])


def test_shared_unwrapper_registry() -> None:
    forget_shared()
    a = shared_unwrapper("daq")
    assert shared_unwrapper("daq") is a and shared_unwrapper("other") is not a
    a.unwrap(WRAP - 10)
    assert shared_unwrapper("daq").unwrap(5) == WRAP + 5  # a second source sees the same epoch
    forget_shared()


def test_sequence_tracker_basics() -> None:
    tr: SequenceTracker[int] = SequenceTracker(256, window=2)
    out = []
    for s in [250, 252, 251, 253, 253, 254, 255, 0, 1, 5, 6, 7, 2]:
        out += [x for x, _ in tr.push(s, s)]
    out += [x for x, _ in tr.flush()]
    assert out == [250, 251, 252, 253, 254, 255, 0, 1, 5, 6, 7]
    assert tr.counts == {"reordered_frame": 1, "duplicate_frame": 1, "frames_lost": 3, "late_frame": 1}


@settings(max_examples=100, deadline=None, derandomize=True)
@given(st.lists(st.integers(0, 65535), max_size=200), st.integers(0, 6))
def test_fuzz_tracker_never_releases_twice(seqs: list[int], window: int) -> None:
    tr: SequenceTracker[int] = SequenceTracker(1 << 16, window=window, restart_after=8)
    released = []
    for i, s in enumerate(seqs):
        released += [x for x, _ in tr.push(s, i)]
    released += [x for x, _ in tr.flush()]
    assert len(released) == len(set(released)) <= len(seqs)


def test_backoff_doubles_to_cap() -> None:
    b = Backoff(first=0.1, factor=2, cap=0.5)
    assert [b.failed(now=0.0) for _ in range(5)] == [0.1, 0.2, 0.4, 0.5, 0.5]
    assert not b.due(now=0.3) and b.due(now=0.6)
    b.reset()
    assert b.due(now=0.0) and b.attempts == 0
