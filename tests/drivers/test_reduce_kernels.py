"""frictionwatch.drivers.assembly.cycle_kernels' sums against np.add.reduce, byte for byte (the assembler's load and phase-window means
must not change by one ulp): every length up to REDUCE_MAX (both code paths: < 8 and 8..128), magnitudes spread over 13 decades,
signed zeros, NaN and inf."""

from __future__ import annotations

import numpy as np

from frictionwatch.drivers.assembly.cycle_kernels import REDUCE_MAX, _add_reduce2, gather_sums


def _vectors(rng, count):
    for trial in range(count):
        n = int(rng.integers(0, REDUCE_MAX + 1)) if trial % 5 else int(rng.integers(0, 20))
        a = rng.standard_normal(n) * 10.0 ** rng.integers(-5, 8, n)
        if n and trial % 7 == 0:
            a[rng.integers(0, n)] = -0.0
        if trial % 11 == 0:
            a[:] = -0.0
        if n and trial % 13 == 0:
            a[rng.integers(0, n)] = (np.nan, np.inf, -np.inf)[trial % 3]
        yield a


def test_add_reduce_is_numpys():
    rng = np.random.default_rng(7)
    for a in _vectors(rng, 3000):
        pad = np.concatenate((rng.standard_normal(3), a, rng.standard_normal(2)))
        ref = np.add.reduce(a)
        s1, s2 = _add_reduce2(pad, pad[::-1].copy(), 3, a.shape[0])
        assert np.float64(s1).tobytes() == ref.tobytes()
        assert np.float64(s2).tobytes() == np.add.reduce(pad[::-1][3 : 3 + a.shape[0]]).tobytes()


def test_gather_sums_is_numpys():
    rng = np.random.default_rng(8)
    for a in _vectors(rng, 1500):
        if a.shape[0] == 0:
            continue
        ia = rng.integers(0, a.shape[0], int(rng.integers(0, REDUCE_MAX + 1)))
        ib = np.sort(rng.integers(0, a.shape[0], int(rng.integers(0, REDUCE_MAX + 1))))
        ok, sa, sb = gather_sums(a, ia, ib)
        assert ok
        assert np.float64(sa).tobytes() == np.add.reduce(a[ia]).tobytes()
        assert np.float64(sb).tobytes() == np.add.reduce(a[ib]).tobytes()


def test_gather_sums_refuses_indices_out_of_range():
    row = np.arange(5.0)
    assert not gather_sums(row, np.array([0, 5]), np.array([1]))[0]
    assert not gather_sums(row, np.array([0]), np.array([-1]))[0]
