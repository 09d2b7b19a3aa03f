"""The chain's free response taken out of a cycle's speed rows (core.monitor.identify.free_response, design note 105):
its columns are the speed harmonics of a free vibration in the monitor's convention, the kernel equals its numpy
reference, what it leaves is orthogonal to them, and genset-v20 at 1500 rpm carries its 2.4 and 19.6 Hz modes."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.core.model.dynamics import free_modes, shaft_model
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.identify.free_response import (
    carried_modes,
    free_response_columns,
    free_response_kernel,
    free_response_reference,
)
from numpy.testing import assert_allclose

GENSET_MODES = np.array([-3.79 + 14.8j, -14.6 + 122.0j])  # ~2.4 Hz (zeta 0.25) and ~19.6 Hz (zeta 0.12)


def test_columns_are_the_speed_harmonics_of_a_free_vibration():
    """Column 2j (2j + 1) is the speed harmonic S_k of w(t) = Re(c e^(lambda t)), c = 1 (c = i), in the
    monitor's convention w(t) = sum Re(S_k e^(+i k 2 pi t / T)): S_k = (2 / T) int_0^T w(t) e^(-i k 2 pi t / T) dt
    (trapezoid on 200,001 points, rtol 1e-7)."""
    period, m = 0.08, 24
    cols = free_response_columns(GENSET_MODES, period, m)
    t = np.linspace(0.0, period, 200_001)
    k = np.arange(1, m + 1)[:, None]
    basis = np.exp(-2j * np.pi * k * t[None, :] / period)
    for j, lam in enumerate(GENSET_MODES):
        for col, c in ((2 * j, 1.0), (2 * j + 1, 1j)):
            w = (c * np.exp(lam * t)).real
            s = 2.0 / period * np.trapezoid(w[None, :] * basis, t, axis=1)
            assert_allclose(cols[:, col], s, rtol=1e-7, atol=1e-9 * np.abs(s).max())


@pytest.mark.parametrize("seed", range(20))
def test_kernel_equals_reference_and_leaves_rows_orthogonal_to_the_columns(seed):
    """Random rows (2M + 1 + 6 extra, P), weights and modes; every fourth case a duplicated mode (a rank-deficient
    set of columns, the kernel drops what is left of it). Kernel against the numpy reference within 1e-10 of the
    largest row; the projected flywheel rows orthogonal to the whitened columns (1e-10 relative); the rows after
    the flywheel's untouched."""
    rng = np.random.default_rng(seed)
    m, p = int(rng.integers(3, 25)), int(rng.integers(2, 48))
    r = 2 * m + 7
    a, y = rng.normal(size=(r, p)), rng.normal(size=r)
    w = rng.uniform(0.2, 5.0, r)
    lams = -rng.uniform(1.0, 20.0, 2) + 1j * rng.uniform(5.0, 200.0, 2)
    if seed % 4 == 0:
        lams = np.array([lams[0], lams[0]])
    cols = free_response_columns(lams, 0.08, m)
    ka, ky = free_response_kernel(a, y, w, cols)
    ra, ry = free_response_reference(a, y, w, cols)
    assert_allclose(ka, ra, rtol=0, atol=1e-10 * np.abs(a).max())
    assert_allclose(ky, ry, rtol=0, atol=1e-10 * np.abs(y).max())
    fw = np.concatenate([cols.real, cols.imag]) * w[:2 * m, None]
    fw = fw / np.linalg.norm(fw, axis=0)
    assert_allclose(fw.T @ ka[:2 * m], 0.0, atol=1e-10 * np.abs(a).max())
    assert_allclose(fw.T @ ky[:2 * m], 0.0, atol=1e-10 * np.abs(y).max())
    assert_allclose(ka[2 * m:], a[2 * m:], rtol=0, atol=0)
    assert_allclose(ky[2 * m:], y[2 * m:], rtol=0, atol=0)


def test_genset_carries_its_two_slow_modes_and_nothing_else():
    """genset-v20 at 1500 rpm (T 0.08 s, M 24): the modes kept over a cycle at carry 0.1 are the electromechanical
    one (2.4 Hz, 0.74 of its amplitude kept) and the chain's first flexible one (19.6 Hz, 0.32), within 0.1 Hz; the
    next in-band one (87 Hz) keeps 0.002; carry 0 takes none."""
    spec = load_engine("genset-v20")
    omega = 1500.0 * np.pi / 30.0
    modes = free_modes(shaft_model(spec, 0.0, omega))
    period = 4.0 * np.pi / omega
    kept = carried_modes(modes, period, 24, 0.1)
    assert_allclose(np.abs(kept) / (2.0 * np.pi), [2.43, 19.55], atol=0.1)
    assert_allclose(np.exp(kept.real * period), [0.739, 0.315], atol=0.005)
    assert carried_modes(modes, period, 24, 0.0).shape == (0,)
