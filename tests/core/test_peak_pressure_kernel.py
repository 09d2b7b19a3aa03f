"""frictionwatch.core.model.indicated.peak_pressure (numba kernel) against its plain-numpy reference (the pre-kernel implementation)."""

import numpy as np
import pytest
from frictionwatch.core.model.indicated import peak_pressure


def peak_pressure_reference(theta, pressure, phases):
    p = np.atleast_2d(pressure)
    i = np.argmax(p, axis=1)
    n = p.shape[1]
    rows = np.arange(p.shape[0])
    y0, y1, y2 = p[rows, (i - 1) % n], p[rows, i], p[rows, (i + 1) % n]
    denom = y0 - 2 * y1 + y2
    frac = np.where(denom < 0, 0.5 * (y0 - y2) / np.where(denom < 0, denom, 1.0), 0.0)
    step = theta[1] - theta[0]
    ang = theta[i] + frac * step - np.atleast_1d(phases)
    ang = (ang + 2 * np.pi) % (4 * np.pi) - 2 * np.pi
    return y1 - 0.25 * (y0 - y2) * frac, ang


@pytest.mark.parametrize("seed", range(4))
def test_matches_reference_bitwise(seed):
    rng = np.random.default_rng(seed)
    z, n = 1 + seed * 5, 720
    theta = np.arange(n) * (4 * np.pi / n)
    phases = rng.uniform(0, 4 * np.pi, z)
    peak_at = rng.uniform(0, 4 * np.pi, z)
    p = 1e5 + 60e5 * np.exp(-((theta[None] - peak_at[:, None]) / 0.3) ** 2) + rng.normal(0, 1e3, (z, n))
    p[0, 0] = p[0].max() + 1.0  # a peak on the first sample: the periodic neighbour is the last one
    p[-1, 100:103] = p[-1].max() + 5.0  # a plateau: the first maximum counts (np.argmax)
    got = peak_pressure(theta, p, phases)
    ref = peak_pressure_reference(theta, p, phases)
    np.testing.assert_array_equal(got[0], ref[0])
    np.testing.assert_array_equal(got[1], ref[1])


def test_flat_row_and_nan_rows_as_reference():
    theta = np.arange(8) * (np.pi / 2)
    p = np.ones((4, 8))
    p[1, 3] = np.nan  # np.argmax picks the first NaN
    p[2, 0] = np.nan
    p[3, [2, 6]] = [5.0, np.nan]
    phases = np.array([0.0, 1.0, 2.0, 3.0])
    got = peak_pressure(theta, p, phases)
    ref = peak_pressure_reference(theta, p, phases)
    np.testing.assert_array_equal(got[0], ref[0])
    np.testing.assert_array_equal(got[1], ref[1])
    np.testing.assert_array_equal(got[0][0], 1.0)
    with pytest.raises(ValueError):
        peak_pressure(theta, p, np.zeros(3))
