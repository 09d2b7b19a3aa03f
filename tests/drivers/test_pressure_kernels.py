"""frictionwatch.drivers.assembly.pressure_kernels (via cycle_parts.pressure_on_grid) against a plain numpy reference
(np.searchsorted window, hole / NaN checks, np.interp): the same reasons, rows within a stated tolerance."""

import numpy as np
import pytest
from frictionwatch.drivers.assembly.cycle_parts import pressure_on_grid
from frictionwatch.drivers.assembly.ringbuffer import RingBuffer
from numpy.testing import assert_allclose


def pressure_on_grid_reference(ring: RingBuffer, grid: np.ndarray):
    """The samples that bracket the grid, refused if a spacing exceeds 1.5 times their mean ('pressure_missing') or
    a sample is NaN ('pressure_nan': whichever comes first in time), else np.interp at the grid times."""
    t, p = ring.view("t"), ring.view("p")
    if t.size < 2:
        return None, "pressure_missing"
    a = int(np.searchsorted(t, grid[0], "right")) - 1
    b = int(np.searchsorted(t, grid[-1], "left")) + 1
    if a < 0 or b > t.size:
        return None, "pressure_missing"
    x, y = t[a:b], p[a:b]
    holes = np.flatnonzero(np.diff(x) > 1.5 * (x[-1] - x[0]) / (x.size - 1))
    nans = np.flatnonzero(np.isnan(y))
    hole = holes[0] if holes.size else np.inf
    nan = nans[0] if nans.size else np.inf
    if hole <= nan and hole < np.inf:
        return None, "pressure_missing"
    if nan < np.inf:
        return None, "pressure_nan"
    return np.interp(grid, x, y), ""


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
        ref, why_ref = pressure_on_grid_reference(ring, grid)
        assert why == why_ref
        if ref is None:
            assert got is None
        else:
            # the same linear interpolation written y0 + w (y1 - y0) here and (slope) x + y0 in numpy: a few ulp of
            # the ~5e5 Pa values
            assert_allclose(got, ref, rtol=1e-12)


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


def test_a_grid_that_is_not_increasing_is_refused():
    ring = RingBuffer(16, {"t": np.float64, "p": np.float64})
    ring.extend(np.arange(10.0), np.arange(10.0))
    for bad in (np.array([3.0]), np.array([5.0, 2.0]), np.ones((2, 2))):
        with pytest.raises(ValueError):
            pressure_on_grid(ring, bad)
