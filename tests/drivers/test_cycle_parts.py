"""Pieces of the cycle assembler against their definitions: wheel positions and windows (integers: exact), the load
mean over a cycle with its zero-order hold, the cam votes of a cycle, and the pressure phase verdict."""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from operator import itemgetter

import numpy as np
import pytest
from frictionwatch.core.types import LoadSample
from frictionwatch.drivers.assembly.cycle_parts import Segment, Wheel, load_mean, load_means
from frictionwatch.drivers.assembly.cycle_phase import (
    PHASE_RATIO,
    cycle_votes,
    firing_ratio,
    firing_verdict,
    phase_windows,
    window_ratio,
)
from frictionwatch.drivers.assembly.engine_buffers import EngineBuffers
from numpy.testing import assert_allclose, assert_array_equal


def ordinal_reference(w: Wheel, pos):
    return (pos // w.n) * w.t + pos % w.n


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
                assert seg.seq_of(p) == first_seq + ordinal_reference(w, p) - ordinal_reference(w, first_pos)
            seqs = rng.integers(first_seq - 500, first_seq + 500, 50)
            assert_array_equal(seg.pos_of(seqs), w.pos_of_ordinal(ordinal_reference(w, first_pos) + (seqs - first_seq)))
        for h2 in rng.integers(-100, 100, 50).tolist():
            lo = w.n * h2 - w.a0_pitch
            assert w.window(h2) == (w.tooth_at_or_before(lo), w.tooth_at_or_after(lo + 2 * w.n))


def load_mean_reference(rows: list[tuple[int, float, float]], ticks, angles, hold: float):
    """(torque, power, torque early, torque late) over the cycle [0, 4 pi] of the edges (ticks, angles) of the rows,
    each standing for the span from the row before it (at most ``hold`` back; the first row: from the cycle's first
    edge) to its own tick, weighted by that span's part of the cycle's time u from theta = 0 to 4 pi (the edges'
    times linear between them) under 1, 2 (1 - u) and 2 u; no part inside: the last row at or before the first edge if
    it is at most ``hold`` older; else NaN."""
    t0, t4 = np.interp(0.0, angles, ticks), np.interp(4.0 * math.pi, angles, ticks)

    def u(t):
        return min(max((t - t0) / (t4 - t0), 0.0), 1.0)

    sums = np.zeros((3, 3))  # (weight, weight x torque, weight x power) x (mean, early, late)
    for k, (t, q, p) in enumerate(rows):
        u0, u1 = u(max(rows[k - 1][0] if k else ticks[0], t - hold)), u(t)
        if u1 > u0:
            for j, w in enumerate((u1 - u0, 2.0 * (u1 - u0) - (u1 * u1 - u0 * u0), u1 * u1 - u0 * u0)):
                sums[j] += (w, w * q, w * p)
    if sums[0, 0] > 0:
        return sums[0, 1] / sums[0, 0], sums[0, 2] / sums[0, 0], sums[1, 1] / sums[1, 0], sums[2, 1] / sums[2, 0]
    before = [(t, q, p) for t, q, p in rows if t <= ticks[0]]
    if before and ticks[0] - before[-1][0] <= hold:
        return before[-1][1], before[-1][2], before[-1][1], before[-1][1]
    return (math.nan,) * 4


@pytest.mark.parametrize("seed", [0, 1])
def test_load_mean_and_its_hold(seed):
    rng = np.random.default_rng(seed)
    buf = EngineBuffers(load_capacity=300)
    t = 0
    for _ in range(600):
        t += int(rng.integers(1, 400))
        buf.add_load(LoadSample(t, float(rng.normal(1e3, 300)), float(rng.normal(2e5, 5e4))))
        if rng.random() < 0.05:
            buf.load.discard_before(int(rng.integers(buf.load.start, buf.load.end)))
        ring = buf.load
        rows = list(zip(ring.view("t").tolist(), ring.view("torque").tolist(), ring.view("power").tolist()))
        lo = float(rng.uniform(t - 60000, t + 100))
        hi = lo + float(rng.choice([0.0, rng.uniform(0, 5000), rng.uniform(0, 80000)]))  # 0 to ~200 rows
        m = int(rng.integers(2, 12))  # the cycle's edges: uneven steps in time and angle, bracketing [0, 4 pi]
        ticks = np.sort(np.round(rng.uniform(lo, hi, m))).astype(np.int64)
        ticks[0], ticks[-1] = int(np.floor(lo)), int(np.ceil(hi)) + 1
        angles = np.sort(rng.uniform(0.0, 4.0 * np.pi, m))
        angles[0], angles[-1] = -rng.uniform(0.0, 0.2), 4.0 * np.pi + rng.uniform(0.0, 0.2)
        # sums of up to ~200 values in another order: agree to a few ulp of the magnitudes (1e3, 2e5)
        got = load_mean(ring, ticks, angles, 500.0)
        assert_allclose(got, load_mean_reference(rows, ticks, angles, 500.0), rtol=1e-10)
        # the one compiled call (load_means) against the Python composition it replaced, to the bit
        assert_array_equal(got, load_mean_composed(ring, ticks, angles, 500.0))


def load_mean_composed(ring, ticks, angles, hold):
    """What ``load_mean`` was before ``load_means`` (two searches, three views, the sums' kernel, the hold), step
    by step in Python: the compiled call must give the same floats."""
    from frictionwatch.drivers.assembly.cycle_parts import span_weighted_load

    if len(ring) == 0:
        return (math.nan,) * 4
    t_lo, t_hi = float(ticks[0]), float(ticks[-1])
    a = ring.searchsorted("t", t_lo, side="right")
    b = min(ring.searchsorted("t", t_hi, side="left") + 1, ring.end)
    if b > a:
        first = max(a - 1, ring.start)
        w, wq, wp, e, eq, late, lq = span_weighted_load(ring.view("t", first, b), ring.view("torque", a, b),
                                                         ring.view("power", a, b), first < a, t_lo, angles, ticks,
                                                         float(hold))
        if w > 0.0:
            return wq / w, wp / w, eq / e, lq / late
    if a > ring.start and t_lo - ring.get("t", a - 1) <= hold:
        q = float(ring.get("torque", a - 1))
        return q, float(ring.get("power", a - 1)), q, q
    return (math.nan,) * 4


def test_load_means_of_an_empty_ring_and_beyond_the_hold_are_nan():
    buf = EngineBuffers(load_capacity=8)
    ticks, angles = np.array([1000, 2000]), np.array([0.0, 4.0 * np.pi])
    cols = (buf.load.cols["t"], buf.load.cols["torque"], buf.load.cols["power"])
    assert np.isnan(load_means(cols, 0, 0, ticks, angles, 500.0)).all()
    buf.add_load(LoadSample(400, 10.0, 20.0))  # 600 ticks before the cycle: beyond a hold of 500, within 700
    assert np.isnan(load_mean(buf.load, ticks, angles, 500.0)).all()
    assert_array_equal(load_mean(buf.load, ticks, angles, 700.0), (10.0, 20.0, 10.0, 10.0))


def test_a_load_step_late_in_a_cycle_is_in_its_mean_and_late_half():
    """Readings every 10 ms, each the mean since the one before (the simulator's): the load steps 30 -> 550 N m
    8.7 ms before the end of a 40.3 ms cycle, in the reading 1.3 ms after its end (10 MHz ticks; deutz two-point
    s9 cycle 145, design note 76). The readings stamped inside read 30 throughout; the cycle's mean, early and late halves are
    the step's own figures to the last reading's part (within 1e-9)."""
    buf = EngineBuffers(load_capacity=64)
    tick_hz, t_step, t0, t1 = 1e7, 77_000_000, 76_683_655, 77_086_647  # that cycle's first and last edges
    for t in range(76_400_000, 77_300_001, 100_000):
        buf.add_load(LoadSample(t, 30.0 if t <= t_step else 550.0, 0.0))
    ticks, angles = np.array([t0, t1]), np.array([0.0, 4.0 * np.pi])
    got = load_mean(buf.load, ticks, angles, tick_hz)
    f = (t1 - t_step) / (t1 - t0)  # the cycle's part the reading after its end stands for
    assert_allclose(got.torque, 30.0 + 520.0 * f, rtol=1e-9)
    assert_allclose(got.torque_early, 30.0 + 520.0 * f * f, rtol=1e-9)  # int of 2 (1 - u) over [1 - f, 1]
    assert_allclose(got.torque_late, 30.0 + 520.0 * (2.0 * f - f * f), rtol=1e-9)
    assert got.torque > 130.0  # the plain mean of the readings stamped inside: 30


def test_cycle_votes_count_the_votes_inside_or_refuse_a_contrary_one():
    rng = np.random.default_rng(3)
    tick = itemgetter(0)
    for _ in range(400):
        cv = [(int(t), int(rng.integers(0, 2)) if rng.random() < 0.2 else 1)
              for t in np.cumsum(rng.integers(1, 50, int(rng.integers(0, 12))))]
        lo = int(rng.integers(-10, 300))
        hi = lo + int(rng.integers(0, 200))
        votes = [b for _, b in cv[bisect_left(cv, lo, key=tick):bisect_right(cv, hi, key=tick)]]
        for phase in (0, 1):
            assert cycle_votes(cv, lo, hi, phase) == (len(votes) if votes.count(phase) == len(votes) else -1)


@pytest.mark.parametrize("points", [256, 720])
def test_firing_verdict_thresholds(points):
    grid = np.arange(points) * (4 * np.pi / points)
    for tdc in (0.0, 1.3, 4 * np.pi - 0.2):
        win = phase_windows(grid, tdc)
        assert win[0].size and win[1].size
        row = np.full(points, 1e6)
        assert firing_verdict(row, grid, tdc, win) == 0  # equal means: undecided
        row[win[0]] *= 1.01 * PHASE_RATIO
        assert firing_verdict(row, grid, tdc, win) == firing_verdict(row, grid, tdc) == 1
        row = np.full(points, 1e6)
        row[win[1]] *= 1.01 * PHASE_RATIO
        assert firing_verdict(row, grid, tdc, win) == -1
        row[win[1]] = 0.0  # no denominator
        assert firing_verdict(row, grid, tdc, win) == 0
        assert firing_verdict(None, grid, tdc, win) == 0


def firing_ratio_reference(row, fire, exch):
    """The numpy reference of ``window_ratio``: mean of the firing window over the mean of the exchange window."""
    if fire.size == 0 or exch.size == 0:
        return math.nan
    den = float(np.add.reduce(row[exch])) / exch.size
    return float(np.add.reduce(row[fire])) / fire.size / den if den > 0 else math.nan


@pytest.mark.parametrize("points", [16, 256, 720, 1440, 4096])
def test_window_ratio_against_its_numpy_reference(points):
    """The compiled ratio against the numpy reference: windows of 1 to ~650 points, one wrapping round the grid's
    end, pressures over six decades (rtol 1e-13: index-order sums against numpy's pairwise ones), a NaN, a zero
    denominator, an empty window."""
    rng = np.random.default_rng(points)
    grid = np.arange(points) * (4 * np.pi / points)
    for tdc in (0.0, 0.7, 2.0, 4 * np.pi - 0.05):
        for half in (0.02, 0.3, 0.52, 1.0):
            fire, exch, _ = phase_windows(grid, tdc, half)
            for _ in range(5):
                row = rng.uniform(0.5, 1.5, points) * 10.0 ** rng.uniform(3, 9, points)
                assert_allclose(window_ratio(row, fire, exch), firing_ratio_reference(row, fire, exch), rtol=1e-13)
            if fire.size and exch.size:
                row[exch] = 0.0
                assert math.isnan(window_ratio(row, fire, exch))
                row[exch[0]], row[fire[0]] = 1e5, math.nan
                assert math.isnan(window_ratio(row, fire, exch))
    empty = np.zeros(0, dtype=np.int64)
    assert math.isnan(window_ratio(np.ones(points), empty, np.arange(3)))
    assert math.isnan(firing_ratio(np.ones(points), grid, 1.0, half_width=1e-9))  # no grid point that close
