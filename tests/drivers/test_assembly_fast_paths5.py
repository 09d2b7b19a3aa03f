"""The assembler's session-5 fast paths against the code they replace (kept here as references):
``discard_older`` of RingBuffer / PressureGroup / FrameGroup vs ``discard_before(searchsorted(...) - keep)``;
``WheelTracker.advance_from`` + ``good_if_synced`` vs ``advance`` + ``synced`` / ``good_through``; ``window_verdict``
vs ``firing_verdict``; ``cycle_votes`` vs the bisection over the cam votes. Every comparison is exact (integers,
events, tracker state bytes, verdicts)."""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from operator import itemgetter

import numpy as np
import pytest

from frictionwatch.drivers.assembly.cycle_phase import cycle_votes, firing_verdict, phase_windows, window_verdict
from frictionwatch.drivers.assembly.frame_store import FrameGroup
from frictionwatch.drivers.assembly.pressure_ring import PressureGroup, write_frame
from frictionwatch.drivers.assembly.ringbuffer import RingBuffer
from frictionwatch.drivers.assembly.wheel_sync import WheelTracker


# ---- references -------------------------------------------------------------------------------------------------
def discard_older_reference(ring, value, keep, upto=None, name="t"):
    """What ``EngineBuffers.release_before`` did before ``discard_older``."""
    if isinstance(ring, RingBuffer):
        seq = ring.searchsorted(name, value) - keep
    else:
        seq = ring.searchsorted(value, side="left") - keep
    if upto is not None:
        seq = min(upto, seq)
    ring.discard_before(seq)


def cycle_votes_reference(cv, t_first, t_last, phase):
    """``CycleAssembler._build`` before ``cycle_votes``: the votes by bisection, then all equal to the phase."""
    tick = itemgetter(0)
    votes = [b for _, b in cv[bisect_left(cv, t_first, key=tick):bisect_right(cv, t_last, key=tick)]]
    return len(votes) if votes.count(phase) == len(votes) else -1


def keys_for(rng, times):
    lo, hi = (float(times[0]), float(times[-1])) if len(times) else (0.0, 1.0)
    picks = list(times[rng.integers(0, len(times), 6)]) if len(times) else []
    return [float(x) for x in rng.uniform(lo - 50, hi + 50, 12)] + [float(x) for x in picks] + \
        [float(x) + 0.5 for x in picks] + [math.nan, math.inf, -math.inf, lo - 1e6]


# ---- discard_older ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(6))
def test_ring_discard_older_matches_search_and_discard(seed):
    rng = np.random.default_rng(seed)
    cap = int(rng.integers(5, 60))
    a, b = RingBuffer(cap, {"t": np.int64}), RingBuffer(cap, {"t": np.int64})
    t = 0
    for _ in range(120):
        n = int(rng.integers(0, cap + 8))  # some batches overflow the ring
        batch = t + np.cumsum(rng.integers(1, 40, n)).astype(np.int64)
        t = int(batch[-1]) if n else t
        a.extend(batch)
        b.extend(batch)
        times = a.view("t")
        for key in rng.permutation(np.array(keys_for(rng, times), dtype=object))[:5]:
            keep = int(rng.integers(0, 3))
            upto = None if rng.random() < 0.5 else int(rng.integers(a.start - 2, a.end + 3))
            discard_older_reference(a, key, keep, upto)
            b.discard_older("t", key, keep, upto)
            assert (a.start, a.end, a.dropped) == (b.start, b.end, b.dropped)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("kind", ["ring", "frames"])
def test_group_discard_older_matches_search_and_discard(seed, kind):
    rng = np.random.default_rng(seed)
    cap, k = int(rng.integers(30, 300)), (1 if kind == "ring" else 3)
    make = (lambda: PressureGroup(tuple(range(1, k + 1)), cap)) if kind == "ring" else \
        (lambda: FrameGroup(tuple(range(1, k + 1)), cap))
    a, b = make(), make()
    t0, period = float(rng.uniform(0, 1e6)), float(rng.choice([10.0, 333.25]))
    for _ in range(60):
        n = int(rng.integers(1, 80))
        vals = rng.normal(5e5, 1e5, (k, n))
        for g in (a, b):
            if kind == "ring":
                i, skip = g._advance(n)
                write_frame(g.t, g.p, i, t0 + skip * period, period, vals, skip)
            else:
                g.add(t0, period, vals, 0)
        t0 += n * period
        times = a.t[a.start % cap: a.start % cap + len(a)] if kind == "ring" else a.times(a.start, a.end)
        for key in keys_for(rng, times)[:6]:
            keep = int(rng.integers(0, 3))
            discard_older_reference(a, key, keep)
            b.discard_older(key, keep)
            assert (a.start, a.end, a.dropped) == (b.start, b.end, b.dropped)


# ---- the tracker ------------------------------------------------------------------------------------------------
def tooth_stream(rng, n_rev=40, n=60, k=2, faults=True):
    """Edge ticks of an n-k wheel at a slowly varying speed, with dropped / spurious edges and silences."""
    pitch = np.ones(n)
    pitch[n - k - 1] = k + 1  # the interval into tooth 0 spans the gap
    per_tooth = np.delete(pitch, range(n - k, n))
    dt = np.tile(per_tooth, n_rev) * 1000.0 * (1 + 0.1 * np.sin(np.arange(n_rev * (n - k)) / 300.0))
    dt *= 1 + 0.002 * rng.standard_normal(dt.size)
    ticks = np.cumsum(np.round(dt)).astype(np.int64) + 10_000
    if faults:
        for _ in range(8):
            i = int(rng.integers(5, ticks.size - 5))
            u = rng.random()
            if u < 0.35:
                ticks = np.delete(ticks, i)
            elif u < 0.7:
                ticks = np.insert(ticks, i + 1, (ticks[i] + ticks[i + 1]) // 2)
            else:
                ticks = np.r_[ticks[:i], ticks[i + 15:] + 0]
    return ticks


@pytest.mark.parametrize("seed", range(5))
def test_advance_from_matches_advance(seed):
    rng = np.random.default_rng(seed)
    ticks = tooth_stream(rng, faults=seed > 0)
    a, b = WheelTracker(60, 2), WheelTracker(60, 2)
    end = 0
    while end < ticks.size:
        end = min(ticks.size, end + int(rng.integers(1, 150)))
        need = a.oldest_needed()
        assert need == b.oldest_needed()
        if need >= end:
            continue
        ev_a = a.advance(ticks[need:end], need)
        ev_b = b.advance_from(ticks[need:end], need)
        assert list(ev_a) == list(ev_b)
        assert a.ist.tobytes() == b.ist.tobytes() and a.fst.tobytes() == b.fst.tobytes()
        assert b.good_if_synced() == (a.good_through if a.synced else -1)


def test_advance_from_returns_every_event_beyond_one_buffer():
    """More than 64 events in one call (the event buffer's rows): all come back, in order."""
    rng = np.random.default_rng(7)
    ticks = tooth_stream(rng, n_rev=200, faults=False)
    idx = np.arange(300, ticks.size - 10, 150)  # a spurious edge every 2.5 revolutions
    ticks = np.insert(ticks, idx + 1, (ticks[idx] + ticks[idx + 1]) // 2)
    a, b = WheelTracker(60, 2), WheelTracker(60, 2)
    a._ev, b._ev = np.zeros((4, 4), np.int64), np.zeros((4, 4), np.int64)  # a small buffer: many refills
    ev_a, ev_b = a.advance(ticks, 0), b.advance_from(ticks, 0)
    assert len(ev_a) > 8 and list(ev_a) == list(ev_b)
    assert a.ist.tobytes() == b.ist.tobytes()
    assert WheelTracker(60, 2).advance_from(ticks[:3], 0) == ()  # no event: the shared empty answer


# ---- phase helpers ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("points", [256, 720])
def test_window_verdict_matches_firing_verdict(points):
    rng = np.random.default_rng(points)
    grid = np.arange(points) * (4 * np.pi / points)
    for tdc in (0.0, 1.3, 4 * np.pi - 0.2):
        win = phase_windows(grid, tdc)
        for trial in range(40):
            row = rng.uniform(1e5, 5e6, points)
            if trial % 5 == 1:
                row[win[0]] *= 1.3  # clearly firing
            elif trial % 5 == 2:
                row[win[1]] *= 1.3  # clearly exchange
            elif trial % 5 == 3:
                row[rng.integers(0, points)] = np.nan
            elif trial % 5 == 4:
                row[win[1]] = 0.0  # no denominator
            assert window_verdict(row, grid, win) == firing_verdict(row, grid, tdc, win)


def test_cycle_votes_matches_the_bisection():
    rng = np.random.default_rng(3)
    for _ in range(400):
        cv = [(int(t), int(rng.integers(0, 2)) if rng.random() < 0.2 else 1)
              for t in np.cumsum(rng.integers(1, 50, int(rng.integers(0, 12))))]
        lo = int(rng.integers(-10, 300))
        hi = lo + int(rng.integers(0, 200))
        for phase in (0, 1):
            assert cycle_votes(cv, lo, hi, phase) == cycle_votes_reference(cv, lo, hi, phase)
