"""frictionwatch.drivers.assembly.cycle_kernels.cycle_edges against its numpy reference (``cycle_edges_reference``): the
same ticks, positions and wheel indices (integers: exact), angles and grid times within a stated tolerance."""

from __future__ import annotations

import math

import numpy as np
import pytest
from frictionwatch.drivers.assembly.cycle_kernels import cycle_edges
from frictionwatch.drivers.assembly.cycle_parts import Segment, Wheel
from numpy.testing import assert_allclose, assert_array_equal
from scipy.interpolate import PchipInterpolator

FOUR_PI = 4.0 * math.pi


def cycle_edges_reference(col, cap, seg, s0, s1, c, phase, a0_deg, grid):
    """Ring view, positions, nominal angle in degrees (numpy), grid times by scipy's PCHIP."""
    ticks = col[s0 % cap: s0 % cap + s1 + 1 - s0].copy()
    pos = np.asarray(seg.pos_of(np.arange(s0, s1 + 1)), dtype=np.int64)
    n = seg.wheel.n
    theta = np.radians(a0_deg + (pos - 2 * n * c + n * phase) * (360.0 / n))
    t0 = ticks[0]
    t_grid = PchipInterpolator(theta, (ticks - t0).astype(np.float64))(grid) + float(t0)
    return ticks, pos, (pos % n).astype(np.int64), theta, t_grid


@pytest.mark.parametrize("wheel, first_deg, grid_points", [((60, 2), 84.0, 720), ((160, 2), -30.0, 256),
                                                           ((36, 1), 10.0, 512), ((60, 2), 123.456, 97)])
def test_cycle_edges_match_the_numpy_reference(wheel, first_deg, grid_points):
    n, k = wheel
    rng = np.random.default_rng(n + grid_points)
    a0 = math.radians(first_deg) % (2 * math.pi)
    w = Wheel(n, k, a0 / (2 * math.pi / n))
    a0_deg = first_deg % 360.0
    grid = np.arange(grid_points) * (FOUR_PI / grid_points)
    cap = 4096
    col = np.zeros(2 * cap, dtype=np.int64)
    done = 0
    for trial in range(25):
        first_pos = int(rng.integers(-3 * n, 3 * n))
        first_pos = w.tooth_at_or_after(first_pos)
        first_seq = int(rng.integers(0, 10 * cap))
        seg = Segment(w, first_seq, first_pos, 0, first_seq + 10 ** 6)
        phase = int(rng.integers(0, 2))
        c = int(rng.integers(0, 5))
        ps, pe = w.window(2 * c - phase)
        if ps < first_pos:
            continue
        s0, s1 = seg.seq_of(ps), seg.seq_of(pe)
        pos = np.asarray(seg.pos_of(np.arange(s0, s1 + 1)))
        dt = 1e7 / (1500 / 60 * n) * (1 + 0.05 * np.sin(pos * 0.3 + trial)) * rng.uniform(0.9, 1.1)
        ticks = np.int64(rng.integers(0, 10 ** 12)) + np.cumsum(np.round(dt * np.diff(pos, prepend=pos[0] - 1)))
        for q in range(ticks.size):  # the mirrored ring
            col[(s0 + q) % cap] = col[(s0 + q) % cap + cap] = ticks[q]
        ref = cycle_edges_reference(col, cap, seg, s0, s1, c, phase, a0_deg, grid)
        m = s1 - s0 + 1
        got = (np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m),
               np.empty(grid_points))
        cycle_edges(col, s0 % cap, m, w.ordinal(first_pos) + (s0 - first_seq), n, n - k, -2 * n * c + n * phase,
                     a0_deg, grid, *got)
        for x, y in zip(got[:3], ref[:3], strict=True):
            assert x.dtype == y.dtype == np.int64
            assert_array_equal(x, y)
        # the same formulas in a compiled loop: a few ulp (angles within 4 pi; grid times ~1e12 ticks, where one ulp
        # is 1.2e-4 tick, and the cubic is summed in another order)
        assert_allclose(got[3], ref[3], rtol=0, atol=1e-13)
        assert_allclose(got[4], ref[4], rtol=0, atol=1e-3)
        assert ref[3][0] <= 0.0 < ref[3][1] and ref[3][-2] < FOUR_PI <= ref[3][-1]
        done += 1
    assert done >= 10
