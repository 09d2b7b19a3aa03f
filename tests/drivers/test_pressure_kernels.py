"""frictionwatch.drivers.assembly.pressure_kernels (via cycle_parts.pressure_on_grid) against its reference: RingBuffer searches,
views and resample.interp_checked (cycle_parts._pressure_on_grid_general). Same rows bit for bit, same reasons."""

import numpy as np
import pytest

from frictionwatch.drivers.assembly.cycle_parts import _pressure_on_grid_general, pressure_on_grid
from frictionwatch.drivers.assembly.ringbuffer import RingBuffer


def _ring(rng, cap, n_blocks, hole=False, nan=False):
    ring = RingBuffer(cap, {"t": np.float64, "p": np.float64})
    t = 1000.0
    for k in range(n_blocks):
        m = int(rng.integers(5, 40))
        times = t + np.arange(m) * 10.0
        vals = rng.normal(5e5, 1e5, m)
        if nan and k == n_blocks // 2:
            vals[m // 2] = np.nan
        ring.extend(times, vals)
        t = times[-1] + (80.0 if hole and k == n_blocks // 2 else 10.0)
        ring.discard_before(ring.end - cap // 2)  # keep the ring wrapping, as the assembler's discard does
    return ring


@pytest.mark.parametrize("seed", range(6))
def test_kernel_matches_reference(seed):
    rng = np.random.default_rng(seed)
    ring = _ring(rng, 257, 60, hole=seed % 3 == 1, nan=seed % 3 == 2)
    t_all = ring.view("t")
    for _ in range(200):
        lo = rng.uniform(t_all[0] - 50.0, t_all[-1])
        hi = lo + rng.uniform(1.0, 1200.0)
        grid = np.sort(rng.uniform(lo, hi, 64))
        grid[0], grid[-1] = lo, hi
        if rng.random() < 0.1:  # grid ends exactly on samples
            grid[0] = t_all[rng.integers(0, t_all.size)]
            grid[-1] = grid[0] + 100.0
            grid = np.sort(grid)
        got, why = pressure_on_grid(ring, grid)
        ref, why_ref = _pressure_on_grid_general(ring, grid)
        assert why == why_ref
        if ref is None:
            assert got is None
        else:
            assert got.tobytes() == ref.tobytes()


def test_short_ring_and_exact_values():
    ring = RingBuffer(16, {"t": np.float64, "p": np.float64})
    assert pressure_on_grid(ring, np.array([1.0, 2.0])) == (None, "pressure_missing")
    ring.extend(np.arange(10.0), np.arange(10.0))
    row, why = pressure_on_grid(ring, np.array([0.5, 8.25]))
    np.testing.assert_array_equal(row, [0.5, 8.25])


@pytest.mark.parametrize("dtype", [np.int64, np.float64])
def test_ring_searchsorted_matches_numpy(dtype):
    rng = np.random.default_rng(7)
    ring = RingBuffer(100, {"t": dtype})
    for _ in range(13):  # wrap several times
        ring.extend(np.sort(rng.integers(0, 50, 17)).astype(dtype) + 50 * ring.end)
        ring.discard_before(ring.end - 60)
        view = ring.view("t")
        keys = [int(view[0]) - 1, float(view[3]), int(view[5]), float(view[-1]) + 0.5, float(view[7]) - 0.25,
                np.float64(view[9]), np.nan, -np.inf, np.inf]
        for key in keys:
            for side in ("left", "right"):
                assert ring.searchsorted("t", key, side=side) == ring.start + int(np.searchsorted(view, key, side))
    with pytest.raises(ValueError):
        ring.searchsorted("t", 1.0, side="middle")
