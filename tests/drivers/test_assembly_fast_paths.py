"""The assembler's fast paths (session 4 speed work) against the code they replace, kept here as references:
``RingBuffer.extend_increasing`` and ``EngineBuffers._add_ticks`` (one compiled check-and-write) vs the numpy check
and ``RingBuffer.extend``; ``EngineBuffers.add_frame``'s steady path vs its general path; ``release_before`` vs the
discards the assembler made inline; ``Segment.seq_of`` / ``pos_of`` with their cached base and the memoized
``Wheel.window`` vs their formulas. Every comparison is exact (integers, row counts, bytes of the stored floats)."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from frictionwatch.core.types import CamBatch, LoadSample, PressureFrame
from frictionwatch.drivers.assembly.cycle_parts import Segment, Wheel, load_mean
from frictionwatch.drivers.assembly.engine_buffers import EngineBuffers
from frictionwatch.drivers.assembly.pressure_kernels import ROW_OK
from frictionwatch.drivers.assembly.ringbuffer import RingBuffer


# ---- references: the code before the fast paths ---------------------------------------------------------------
def add_ticks_reference(ring: RingBuffer, rejected: Counter, ticks, stream: str) -> int:
    """``EngineBuffers._add_ticks`` before ``extend_increasing`` (numpy checks, then ``RingBuffer.extend``)."""
    t = np.asarray(ticks, dtype=np.int64).ravel()
    if t.shape[0] == 0:
        return 0
    last = None if ring.end == ring.start else int(ring._cols["t"][(ring.end - 1) % ring.capacity])
    ok = np.ones(t.size, dtype=bool)
    ok[1:] = t[1:] > t[:-1]
    if last is not None:
        ok[0] = t[0] > last
    if not ok.all():
        keep = np.zeros(t.size, dtype=bool)
        top = np.iinfo(np.int64).min if last is None else last
        for i, x in enumerate(t.tolist()):
            if x > top:
                keep[i] = True
                top = x
        rejected[stream] += int(t.size - keep.sum())
        t = t[keep]
    ring.extend(t)
    return int(t.size)


def ordinal_reference(w: Wheel, pos):
    return (pos // w.n) * w.t + pos % w.n


def window_reference(w: Wheel, h2: int) -> tuple[int, int]:
    lo = w.n * h2 - w.a0_pitch
    return w.tooth_at_or_before(lo), w.tooth_at_or_after(lo + 2 * w.n)


def release_reference(buf: EngineBuffers, t_keep: float, hold: float, cam_next: int) -> None:
    """What ``CycleAssembler._discard`` did inline before ``EngineBuffers.release_before``."""
    for group in buf.groups.values():
        group.discard_before(group.searchsorted(t_keep, side="left") - 2)
    ring = buf.load
    ring.discard_before(ring.searchsorted("t", t_keep - hold) - 1)
    ring = buf.cam
    ring.discard_before(min(cam_next, ring.searchsorted("t", t_keep)))


def ring_state(ring: RingBuffer) -> tuple:
    return ring.start, ring.end, ring.dropped, tuple(c.tobytes() for c in ring._cols.values())


# ---- tests ------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_add_ticks_matches_the_numpy_checks_and_extend(seed):
    rng = np.random.default_rng(seed)
    cap = int(rng.choice([7, 64, 317]))
    new, ref = EngineBuffers(tooth_capacity=cap), RingBuffer(cap, {"t": np.int64})
    rejected: Counter = Counter()
    t = int(rng.integers(-1000, 1000))
    for _ in range(400):
        n = int(rng.integers(0, 2 * cap if rng.random() < 0.1 else 40))  # sometimes longer than the ring
        batch = t + np.cumsum(rng.integers(1, 50, n))
        u = rng.random()
        if u < 0.1 and n > 3:  # an edge out of order
            j = int(rng.integers(0, n - 1))
            batch[j], batch[j + 1] = batch[j + 1], batch[j]
        elif u < 0.15 and n:  # a batch that starts before the last edge
            batch -= int(rng.integers(1, 200))
        elif u < 0.2:  # not an int64 array
            batch = batch.astype(np.float64).tolist()
        if n:
            t = int(np.max(batch))
        if rng.random() < 0.3 and len(ref) > 2:
            s = int(rng.integers(ref.start, ref.end))
            ref.discard_before(s)
            new.teeth.discard_before(s)
        got = new._add_ticks(new.teeth, batch, "teeth")
        want = add_ticks_reference(ref, rejected, batch, "teeth")
        assert got == want
        assert ring_state(new.teeth) == ring_state(ref)
        assert new.rejected == rejected


def test_extend_increasing_refuses_without_writing():
    ring = RingBuffer(8, {"t": np.int64})
    assert ring.extend_increasing(np.array([5, 6, 7], dtype=np.int64))
    before = ring_state(ring)
    assert not ring.extend_increasing(np.array([7, 8], dtype=np.int64))  # not after the last row
    assert not ring.extend_increasing(np.array([8, 10, 9], dtype=np.int64))  # not increasing
    assert ring_state(ring) == before
    assert ring.extend_increasing(np.array([], dtype=np.int64))
    assert ring.extend_increasing(np.arange(100, 120, dtype=np.int64))  # longer than the ring: its newest rows
    assert_array_equal(ring.view("t"), np.arange(112, 120))
    assert ring.start == 15 and ring.end == 23 and ring.dropped == 3 + 12


def test_segment_positions_and_wheel_windows_match_their_formulas():
    rng = np.random.default_rng(3)
    for n, k in ((60, 2), (36, 1), (80, 2), (24, 3)):
        w = Wheel(n, k, float(rng.uniform(0, n)))
        for _ in range(20):
            first_seq, first_pos = int(rng.integers(0, 10**6)), int(rng.integers(-5 * n, 5 * n))
            first_pos -= first_pos % n if first_pos % n >= w.t else 0  # a tooth
            seg = Segment(w, first_seq, first_pos, 0, first_seq)
            pos = rng.integers(-10 * n, 10 * n, 50)
            pos = pos[pos % n < w.t]
            for p in pos.tolist():
                want = first_seq + ordinal_reference(w, p) - ordinal_reference(w, first_pos)
                assert seg.seq_of(p) == want
            seqs = rng.integers(first_seq - 500, first_seq + 500, 50)
            want = w.pos_of_ordinal(ordinal_reference(w, first_pos) + (seqs - first_seq))
            assert_array_equal(seg.pos_of(seqs), want)
            assert all(seg.pos_of(s) == x for s, x in zip(seqs.tolist(), want.tolist()))
        for h2 in rng.integers(-100, 100, 200).tolist():  # repeats and more than the memo holds
            assert w.window(h2) == window_reference(w, h2)


def frame_stream(rng, cyls, n_frames):
    t, period = float(rng.uniform(0, 1e6)), float(rng.choice([25.0, 333.25]))
    for _ in range(n_frames):
        n = int(rng.integers(1, 120))
        v = rng.normal(5e5, 1e5, (len(cyls), n))
        u = rng.random()
        t0 = t - (int(rng.integers(1, n + 5)) * period if u < 0.1 else 0.0)  # some overlap what came before
        yield PressureFrame(cyls, int(t0) if u < 0.5 else t0, period, v)
        t += n * period


@pytest.mark.parametrize("seed", [0, 1])
def test_add_frame_plain_and_converted_frames_match(seed):
    rng = np.random.default_rng(seed)
    cyls = tuple(range(1, 21))
    fast, slow = EngineBuffers(pressure_capacity=2000), EngineBuffers(pressure_capacity=2000)
    for fr in frame_stream(rng, cyls, 300):
        # a Fortran-ordered copy (not a plain frame) goes through the conversions: the same rows
        other = PressureFrame(fr.cylinders, fr.t0_ticks, fr.period_ticks, np.asfortranarray(fr.values))
        assert fast.add_frame(fr) == slow.add_frame(other)
        g, h = fast.groups[cyls], slow.groups[cyls]
        assert (g.start, g.end, g.dropped, g.newest, g.n_chunks) == (h.start, h.end, h.dropped, h.newest, h.n_chunks)
        assert g.ci[: g.n_chunks].tobytes() == h.ci[: h.n_chunks].tobytes()
        assert g.cf[: g.n_chunks].tobytes() == h.cf[: h.n_chunks].tobytes()
        if rng.random() < 0.2:
            s = int(rng.integers(g.start, g.end + 1))
            g.discard_before(s)
            h.discard_before(s)
    assert fast.rejected == slow.rejected
    times = g.times(max(g.start, g.end - 300), g.end)  # the newest retained samples
    q = np.linspace(times[0], times[-1], 64)
    out_f, out_s = np.empty((20, 64)), np.empty((20, 64))
    codes_f, codes_s = np.zeros(20, np.int64), np.zeros(20, np.int64)
    rows = np.arange(20, dtype=np.int64)
    g.rows_on_grid(q, rows, out_f, codes_f)
    h.rows_on_grid(q, rows, out_s, codes_s)
    assert_array_equal(codes_f, codes_s)
    ok = codes_f == ROW_OK  # (a failed row is left unwritten)
    assert ok.any()
    assert out_f[ok].tobytes() == out_s[ok].tobytes()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_release_before_matches_the_inline_discards(seed):
    rng = np.random.default_rng(seed)
    bufs = EngineBuffers(cam_capacity=16, pressure_capacity=500, load_capacity=32), \
        EngineBuffers(cam_capacity=16, pressure_capacity=500, load_capacity=32)
    frames = list(frame_stream(rng, (1, 2, 3), 200))
    t_cam = t_load = 0
    for fr in frames:
        t_cam += int(rng.integers(1, 3000))
        t_load += int(rng.integers(1, 2000))
        for b in bufs:
            b.add_frame(fr)
            b.add(CamBatch(np.array([t_cam], dtype=np.int64)))
            b.add_load(LoadSample(t_load, 1.0, 2.0))
        t_keep = float(rng.uniform(0.0, max(t_cam, t_load, fr.t0_ticks)))
        hold = float(rng.choice([0.0, 1000.0, math.inf]))
        cam_next = int(rng.integers(bufs[0].cam.start, bufs[0].cam.end + 2))
        bufs[0].release_before(t_keep, hold, cam_next)
        release_reference(bufs[1], t_keep, hold, cam_next)
        a, b = bufs
        assert ring_state(a.cam) == ring_state(b.cam) and ring_state(a.load) == ring_state(b.load)
        ga, gb = a.groups[(1, 2, 3)], b.groups[(1, 2, 3)]
        assert (ga.start, ga.end, ga.dropped) == (gb.start, gb.end, gb.dropped)
    assert bufs[0].dropped() == bufs[1].dropped()


def load_mean_reference(ring: RingBuffer, t_lo: float, t_hi: float, hold_ticks: float) -> tuple[float, float]:
    """``drivers.assembly.cycle_parts.load_mean`` before the one-kernel window sums (np.mean = np.add.reduce / n)."""
    if len(ring) == 0:
        return math.nan, math.nan
    a = ring.searchsorted("t", t_lo, side="left")
    b = ring.searchsorted("t", t_hi, side="right")
    if b > a:
        return float(np.mean(ring.view("torque", a, b))), float(np.mean(ring.view("power", a, b)))
    if a > ring.start and t_lo - ring.get("t", a - 1) <= hold_ticks:
        return float(ring.get("torque", a - 1)), float(ring.get("power", a - 1))
    return math.nan, math.nan


@pytest.mark.parametrize("seed", [0, 1])
def test_load_mean_matches_numpy_means_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    buf = EngineBuffers(load_capacity=300)
    t = 0
    for _ in range(2000):
        t += int(rng.integers(1, 400))
        buf.add_load(LoadSample(t, float(rng.normal(1e3, 300)), float(rng.normal(2e5, 5e4))))
        if rng.random() < 0.05:
            buf.load.discard_before(int(rng.integers(buf.load.start, buf.load.end)))
        lo = float(rng.uniform(t - 60000, t + 100))
        hi = lo + float(rng.choice([0.0, rng.uniform(0, 5000), rng.uniform(0, 80000)]))  # 0 to ~200 rows
        got = load_mean(buf.load, lo, hi, 500.0)
        want = load_mean_reference(buf.load, lo, hi, 500.0)
        assert np.array(got).tobytes() == np.array(want).tobytes()
