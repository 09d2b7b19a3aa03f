"""Ring buffers: absolute sequence numbers across wrap, zero-copy views, overflow accounting, record routing."""

import math
from collections import deque

import numpy as np
import pytest
from frictionwatch.core.types import CamBatch, LoadSample, PressureBlock, ToothBatch
from frictionwatch.drivers.assembly.engine_buffers import EngineBuffers
from frictionwatch.drivers.assembly.ringbuffer import RingBuffer
from numpy.testing import assert_array_equal


def test_matches_a_bounded_deque_over_random_batches():
    rng = np.random.default_rng(7)
    cap = 37
    ring = RingBuffer(cap, {"a": np.int64, "b": np.float64})
    ref: deque[int] = deque(maxlen=cap)
    seq = 0
    for _ in range(300):
        n = int(rng.integers(0, 60))  # sometimes longer than the ring
        a = np.arange(seq, seq + n, dtype=np.int64)
        ring.extend(a, a * 0.5)
        ref.extend(a.tolist())
        seq += n
        assert ring.end == seq and len(ring) == len(ref)
        assert_array_equal(ring.view("a"), np.array(ref, dtype=np.int64))
        assert_array_equal(ring.view("b"), np.array(ref) * 0.5)
        if len(ref) > 3:  # any sub-range by absolute sequence number
            lo = int(rng.integers(ring.start, ring.end - 2))
            assert_array_equal(ring.view("a", lo, lo + 2), [lo, lo + 1])
            assert ring.get("a", lo) == lo
    assert ring.dropped == seq - cap  # nothing was released, so every overwritten row counts


def test_views_are_zero_copy_and_searchsorted_is_absolute():
    ring = RingBuffer(8, {"t": np.int64})
    ring.extend(np.arange(0, 60, 10))
    ring.extend(np.arange(60, 110, 10))  # wraps: 11 rows into 8
    v = ring.view("t")
    assert v.base is not None  # a view of the storage, not a copy
    assert_array_equal(v, np.arange(30, 110, 10))
    assert ring.start == 3
    assert ring.searchsorted("t", 55) == 6  # row 6 holds 60
    assert ring.searchsorted("t", 60, side="right") == 7


def test_released_rows_do_not_count_as_dropped():
    ring = RingBuffer(10, {"t": np.int64})
    ring.extend(np.arange(10))
    ring.discard_before(7)
    ring.extend(np.arange(10, 15))  # overwrites rows 0..4: 0..6 were released
    assert ring.dropped == 0 and ring.start == 7
    ring.extend(np.arange(15, 20))  # overwrites 7..9 (unreleased)
    assert ring.dropped == 3 and ring.start == 10


def test_bad_use_raises():
    ring = RingBuffer(4, {"t": np.int64})
    ring.extend(np.arange(6))
    with pytest.raises(IndexError):
        ring.view("t", 0, 3)  # rows 0, 1 are gone
    with pytest.raises(ValueError):
        ring.extend(np.arange(2), np.arange(2))
    with pytest.raises(ValueError):
        RingBuffer(0, {"t": np.int64})


def test_engine_buffers_route_and_refuse_out_of_order():
    buf = EngineBuffers(tooth_capacity=64, pressure_capacity=64)
    assert buf.add(ToothBatch(np.array([10, 20, 30], dtype=np.int64))) == 3
    assert buf.add(ToothBatch(np.array([25, 40, 35, 50], dtype=np.int64))) == 2  # 25 and 35 are out of order
    assert_array_equal(buf.teeth.view("t"), [10, 20, 30, 40, 50])
    assert buf.rejected["teeth"] == 2
    buf.add(CamBatch(np.array([15], dtype=np.int64)))
    # a non-integer period keeps exact sample times: t0 + i * period
    buf.add(PressureBlock(2, 100, 333.25, np.array([1.0, 2.0, 3.0])))
    buf.add(PressureBlock(2, 700, 333.25, np.array([4.0, 5.0])))  # 700 <= 766.5: only the new tail is kept
    assert_array_equal(buf.pressure[2].view("t"), [100.0, 433.25, 766.5, 1033.25])
    assert_array_equal(buf.pressure[2].view("p"), [1.0, 2.0, 3.0, 5.0])
    assert buf.rejected["pressure"] == 1
    buf.add(LoadSample(5, 10.0, 1e3))
    buf.add(LoadSample(5, 11.0, 1e3))  # same time: refused
    assert len(buf.load) == 1 and buf.rejected["load"] == 1
    assert buf.dropped() == {}


def test_extend_increasing_refuses_without_writing():
    ring = RingBuffer(8, {"t": np.int64})
    assert ring.extend_increasing(np.array([5, 6, 7], dtype=np.int64))
    before = (ring.start, ring.end, ring.dropped, ring.view("t").tolist())
    assert not ring.extend_increasing(np.array([7, 8], dtype=np.int64))  # not after the last row
    assert not ring.extend_increasing(np.array([8, 10, 9], dtype=np.int64))  # not increasing
    assert (ring.start, ring.end, ring.dropped, ring.view("t").tolist()) == before
    assert ring.extend_increasing(np.array([], dtype=np.int64))
    assert ring.extend_increasing(np.arange(100, 120, dtype=np.int64))  # longer than the ring: its newest rows
    assert_array_equal(ring.view("t"), np.arange(112, 120))
    assert ring.start == 15 and ring.end == 23 and ring.dropped == 3 + 12


@pytest.mark.parametrize("seed", range(4))
def test_discard_older_is_discard_before_a_search(seed):
    """``discard_older(name, value, keep, upto)`` is ``discard_before(min(upto, searchsorted(value) - keep))``
    (row numbers: exact), over wrapping batches, NaN and infinite keys."""
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
        keys = [float(x) for x in rng.uniform(t - 400, t + 50, 4)] + [math.nan, math.inf, -math.inf]
        if len(times):
            keys.append(float(times[rng.integers(0, len(times))]))
        for key in keys:
            keep = int(rng.integers(0, 3))
            upto = None if rng.random() < 0.5 else int(rng.integers(a.start - 2, a.end + 3))
            seq = a.searchsorted("t", key) - keep
            a.discard_before(seq if upto is None else min(upto, seq))
            b.discard_older("t", key, keep, upto)
            assert (a.start, a.end, a.dropped) == (b.start, b.end, b.dropped)


def test_append_is_extend_of_one_row():
    a = RingBuffer(5, {"t": np.int64, "x": np.float64})
    b = RingBuffer(5, {"t": np.int64, "x": np.float64})
    assert a.last("t") is None
    for k in range(13):  # wraps twice, overflows (with and without released rows: append's two paths)
        a.append(10 * k, 0.5 * k)
        b.extend(np.array([10 * k]), np.array([0.5 * k]))
        assert (a.start, a.end, a.dropped) == (b.start, b.end, b.dropped)
        assert_array_equal(a.view("t"), b.view("t"))
        assert_array_equal(a.view("x"), b.view("x"))
        assert a.last("t") == b.get("t", b.end - 1) == 10 * k and type(a.last("t")) is int
        assert a.last("x") == 0.5 * k
        if k == 6:
            a.discard_before(a.end - 1)
            b.discard_before(b.end - 1)
    a.clear()
    assert a.last("t") is None
    with pytest.raises(ValueError):
        a.append(1)
