"""frictionwatch.drivers.assembly.frame_store.FrameGroup (frames kept by reference) against the ring storage of the same
samples, a drivers.assembly.pressure_ring.PressureGroup filed with ``write_frame``: the same row counts, overflow and
searches (integers: exact), the same stored samples, and resampled rows and codes that agree (codes exactly, values
within a stated tolerance), including holes, NaN samples, overlapping frames, frames longer than the ring and grid
times that straddle two frames."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.drivers.assembly.frame_store import FrameChannel, FrameGroup
from frictionwatch.drivers.assembly.pressure_kernels import ROW_HOLE, ROW_MISSING, ROW_NAN, ROW_OK, pressure_rows
from frictionwatch.drivers.assembly.pressure_ring import PressureGroup, write_frame
from numpy.testing import assert_allclose, assert_array_equal


def file_both(ring: PressureGroup, group: FrameGroup, t0: float, period: float, values: np.ndarray, first: int):
    """File samples first.. of a frame into the ring (copied) and the frame group (kept)."""
    i, skip = ring.reserve(values.shape[1] - first)
    write_frame(ring.t, ring.p, i, t0 + skip * period, float(period), values, first + skip)
    ring.period = float(period)  # as EngineBuffers files a frame
    group.add(t0, float(period), values, first)


def random_pair(rng, cap, k, n_frames, hole=False, nan=False, keep=None):
    ring = PressureGroup(tuple(range(1, k + 1)), cap)
    group = FrameGroup(tuple(range(1, k + 1)), cap)
    t = float(rng.uniform(0, 1e6))
    period = float(rng.choice([10.0, 333.25, 0.1 + rng.uniform(0, 50)]))
    for f in range(n_frames):
        long = rng.random() < 0.1 and f < n_frames - 12  # some overflow, not over the injected faults
        n = int(rng.integers(cap, cap + 40)) if long else int(rng.integers(1, 60))
        vals = rng.normal(5e5, 1e5, (k, n))
        if nan and f == n_frames - 4:
            vals[int(rng.integers(0, k)), n // 2] = np.nan
        first = int(rng.integers(0, n)) if rng.random() < 0.1 else 0  # an overlapping frame keeps its tail
        file_both(ring, group, t, period, vals, first)
        t += (n - 1) * period + (8.0 * period if hole and f == n_frames - 4 else period)
        if keep is not None:
            g = ring.end - keep(rng)
            ring.discard_before(g)
            group.discard_before(g)
        assert (ring.start, ring.end, ring.dropped) == (group.start, group.end, group.dropped)
    return ring, group


@pytest.mark.parametrize("seed", range(8))
def test_counts_times_values_and_searches_match_the_ring(seed):
    rng = np.random.default_rng(seed)
    k = 3
    ring, group = random_pair(rng, 211, k, 120, keep=lambda r: int(r.integers(20, 150)))
    t_ring = ring.t[ring.start % ring.capacity: ring.start % ring.capacity + len(ring)]
    # sample times t0 + q period, computed by two kernels: exact in practice, a few ulp allowed
    assert_allclose(group.times(group.start, group.end), t_ring, rtol=1e-15, atol=0)
    assert group.newest == t_ring[-1] and group.last_t() == ring.last_t()
    for r in range(k):
        ch = FrameChannel(group, r)
        p_ring = ring.p[r, ring.start % ring.capacity: ring.start % ring.capacity + len(ring)]
        assert_array_equal(ch.view("p"), p_ring)  # the samples themselves: copied, never computed
        assert_allclose(ch.view("t"), t_ring, rtol=1e-15, atol=0)
        s = int(rng.integers(group.start, group.end))
        assert ch.get("p", s) == p_ring[s - group.start]
    keys = np.concatenate([rng.uniform(t_ring[0] - 100, t_ring[-1] + 100, 50), t_ring[rng.integers(0, t_ring.size, 20)],
                           [np.nan, np.inf, -np.inf]])
    for key in keys:
        for side in ("left", "right"):
            assert group.searchsorted(key, side) == ring.searchsorted(key, side)
    assert group.n_chunks <= 2 * (len(group) + 1) + FrameGroup._SLACK  # frames without a retained row are let go


@pytest.mark.parametrize("seed", range(9))
def test_rows_on_grid_match_the_ring_kernel(seed):
    rng = np.random.default_rng(seed)
    k = 5
    ring, group = random_pair(rng, 1031, k, 90, hole=seed % 3 == 1, nan=seed % 3 == 2,
                              keep=lambda r: int(r.integers(400, 900)))
    t_all = ring.t[ring.start % ring.capacity: ring.start % ring.capacity + len(ring)]
    rows = np.array([2, -1, 0, 4, 1], dtype=np.int64)  # row 1 not wanted
    seen = set()
    for trial in range(150):
        lo = rng.uniform(t_all[0] - 5 * (t_all[1] - t_all[0]), t_all[-1])
        hi = lo + rng.uniform(1.0, 0.6 * (t_all[-1] - t_all[0]))
        m = int(rng.choice([16, 64, 700]))
        grid = np.sort(rng.uniform(lo, hi, m))
        grid[0], grid[-1] = lo, hi
        if trial < 2:  # the whole retained window: any injected fault shows
            grid = np.linspace(t_all[0], t_all[-1], m)
        elif trial % 5 == 0:  # grid times on samples: intervals that start on a frame's last sample
            grid = np.sort(t_all[rng.integers(0, t_all.size, m)] + rng.choice([0.0, 1e-9], m))
            grid = np.maximum.accumulate(grid)
        out_ring, out_group = np.full((5, m), -1.0), np.full((5, m), -1.0)
        codes_ring, codes_group = np.zeros(k, dtype=np.int64), np.zeros(k, dtype=np.int64)
        bad_ring = pressure_rows(ring.t, ring.p, ring.start, ring.end, grid, rows, out_ring, codes_ring, ring.period)
        bad_group = group.rows_on_grid(grid, rows, out_group, codes_group)
        assert bad_ring == bad_group and codes_ring.tolist() == codes_group.tolist()
        for r in range(k):
            seen.add(int(codes_ring[r]))
            if rows[r] >= 0 and codes_ring[r] == ROW_OK:
                # the same interpolation y0 + w (y1 - y0) read from frames instead of the ring: a few ulp of ~5e5 Pa
                assert_allclose(out_group[rows[r]], out_ring[rows[r]], rtol=1e-12)
        assert np.all(out_group[3] == -1.0)  # the unwanted row's target is untouched
    assert ROW_OK in seen and ROW_MISSING in seen
    if seed % 3 == 1:
        assert ROW_HOLE in seen
    if seed % 3 == 2:
        assert ROW_NAN in seen


def test_one_row_through_the_channel_and_bad_use():
    rng = np.random.default_rng(3)
    ring, group = random_pair(rng, 300, 2, 10)
    ch = FrameChannel(group, 1)
    t = ch.view("t")
    grid = np.linspace(t[1], t[-2], 33)
    out = np.empty(33)
    assert ch.row_on_grid(grid, out) == ROW_OK
    ref = np.empty((1, 33))
    pressure_rows(ring.t, ring.p[1:2], ring.start, ring.end, grid, np.zeros(1, dtype=np.int64), ref,
                   np.zeros(1, dtype=np.int64))
    assert_allclose(out, ref[0], rtol=1e-12)  # as in test_rows_on_grid_match_the_ring_kernel
    assert ch.searchsorted("t", float(t[4])) == group.start + 4
    with pytest.raises(ValueError):
        ch.extend(np.ones(1), np.ones(1))
    with pytest.raises(IndexError):
        ch.view("p", group.start - 1, group.end)
    with pytest.raises(ValueError):
        FrameGroup((1,), 10)


@pytest.mark.parametrize("runs", [(1,), (3,), (8,), (9, 2), (17, 1, 5)])
def test_the_typed_list_holds_every_filed_frame_once_in_order(runs):
    """``_sync`` pads a short run to its one signature: the padding must not be appended (runs of 1, 3, 8 and
    longer, across several syncs)."""
    group = FrameGroup((1, 2), 10_000)
    filed, t = [], 0.0
    for n_run in runs:
        for _ in range(n_run):
            vals = np.full((2, 5), float(len(filed)))
            group.add(t, 1.0, vals, 0)
            filed.append(vals)
            t += 5.0
        frames = group.frames  # the sync
        assert len(frames) == len(filed)
        assert all(f is g or np.shares_memory(f, g) for f, g in zip(frames, filed, strict=True))
        assert_array_equal([f[0, 0] for f in frames], np.arange(len(filed), dtype=float))


def test_a_grid_inside_a_stretch_of_missing_samples_is_a_hole_not_an_interpolation():
    """A cycle whose grid falls wholly inside a stretch of dropped pressure has a window of two samples, the last
    before the stretch and the first after it: their spacing is the window's mean, so the mean alone saw no hole and
    the cycle was interpolated across the stretch (~170 bar off on the demo log before the period was filed). The
    samples' own period (filed with each frame) sees it, on the frame group and on the ring alike; a grid over whole
    frames is still read."""
    rng = np.random.default_rng(3)
    k, period = 3, 50.0
    ring, group = PressureGroup(tuple(range(1, k + 1)), 4096), FrameGroup(tuple(range(1, k + 1)), 4096)
    for t0 in (0.0, 200 * period, 1400 * period, 1600 * period):  # two frames, 1,000 samples dropped, two frames
        file_both(ring, group, t0, period, rng.normal(5e5, 1e5, (k, 200)), 0)
    rows = np.arange(k, dtype=np.int64)
    for lo, hi, code in ((500 * period, 1300 * period, ROW_HOLE), (10 * period, 390 * period, ROW_OK),
                         (1410 * period, 1790 * period, ROW_OK)):
        grid = np.linspace(lo, hi, 720)
        codes_ring, codes_group, out = np.zeros(k, dtype=np.int64), np.zeros(k, dtype=np.int64), np.empty((k, 720))
        pressure_rows(ring.t, ring.p, ring.start, ring.end, grid, rows, out, codes_ring, ring.period)
        group.rows_on_grid(grid, rows, out, codes_group)
        assert codes_ring.tolist() == codes_group.tolist() == [code] * k, (lo, hi, codes_ring, codes_group)
