"""Pieces of the cycle assembler against their definitions: wheel positions and windows (integers: exact), the load
mean over a cycle with its zero-order hold, the cam votes of a cycle, and the pressure phase verdict."""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from operator import itemgetter

import numpy as np
import pytest
from frictionwatch.core.types import LoadSample
from frictionwatch.drivers.assembly.cycle_parts import Segment, Wheel, load_mean
from frictionwatch.drivers.assembly.cycle_phase import PHASE_RATIO, cycle_votes, firing_verdict, phase_windows
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


def load_mean_reference(rows: list[tuple[int, float, float]], t_lo: float, t_hi: float, hold: float):
    """Mean (torque, power) of the rows with t_lo <= t <= t_hi; else the last row before t_lo if it is at most
    ``hold`` older; else NaN."""
    inside = [(q, p) for t, q, p in rows if t_lo <= t <= t_hi]
    if inside:
        return float(np.mean([q for q, _ in inside])), float(np.mean([p for _, p in inside]))
    before = [(t, q, p) for t, q, p in rows if t < t_lo]
    if before and t_lo - before[-1][0] <= hold:
        return before[-1][1], before[-1][2]
    return math.nan, math.nan


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
        # a mean of up to ~200 values summed in another order: agrees to a few ulp of the magnitudes (1e3, 2e5)
        assert_allclose(load_mean(ring, lo, hi, 500.0), load_mean_reference(rows, lo, hi, 500.0), rtol=1e-12)


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
