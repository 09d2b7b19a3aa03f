"""Numba helpers shared by the plant's kernels (core/model/jit.py)."""

import math

import numba
import numpy as np
from frictionwatch.core.model.jit import BORROWING, sincos
from numpy.testing import assert_array_equal


@numba.njit(**BORROWING)
def _sincos_all(x, s, c):
    for i in range(x.shape[0]):
        s[i], c[i] = sincos(x[i])


def test_sincos_is_the_library_sin_and_cos_to_the_bit():
    # the plant's unwrapped angles reach ~1e6 rad in a long run; small ones near TDC
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.uniform(-10, 10, 20000), rng.uniform(-2e6, 2e6, 20000), rng.uniform(-1e-6, 1e-6, 2000),
                        [0.0, np.pi, 4 * np.pi * 45000]])
    s, c = np.empty_like(x), np.empty_like(x)
    _sincos_all(x, s, c)
    assert_array_equal(s, [math.sin(v) for v in x])  # the C library's sin and cos, as numba's np.sin and np.cos
    assert_array_equal(c, [math.cos(v) for v in x])
