"""The accumulated equations' persistent residual (core.monitor.identify.accumulate.Accumulator.persistent_residual)
and the speed rows' repeatable-error budget made from it (core.monitor.identify.identification.speed_budget; design
note 35): the weighted mean of each cycle's raw residual at one estimate, kept through forgetting and a discount."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from frictionwatch.core.monitor.identify.accumulate import Accumulator, raw_rows, speed_budget
from frictionwatch.core.monitor.identify.noise_model import ResidualStats
from numpy.testing import assert_allclose


def _cycles(n: int, r: int, p: int, bias: np.ndarray, seed: int = 4):
    """(the true parameters, n cycles' raw rows, targets with ``bias`` and 0.01 noise, and row weights)."""
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0.5, 1.5, p)
    cycles = []
    for _ in range(n):
        d = rng.standard_normal((r, p))
        t = d @ truth + bias + 0.01 * rng.standard_normal(r)
        cycles.append((d, t, rng.uniform(0.5, 2.0, r)))
    return truth, cycles


def test_persistent_residual_is_the_weighted_mean_residual():
    r, p, lam = 7, 3, 0.97
    bias = np.linspace(-0.2, 0.3, r)
    acc = Accumulator.empty(p, r)
    ds, ts, weights = [], [], []
    truth, cycles = _cycles(40, r, p, bias)
    for d, t, inv in cycles:
        a, y = d * inv[:, None], t * inv
        got_d, got_t = raw_rows(a, y, inv)
        assert_allclose(got_d, d, rtol=1e-12)
        assert_allclose(got_t, t, rtol=1e-12)
        acc = acc.fold(acc.cycle_terms(a, y, inv, 1), lam, (got_d, got_t))
        weights = [w * lam for w in weights] + [1.0]
        ds.append(d)
        ts.append(t)
    w = np.array(weights)
    want = sum(wi * (ti - di @ truth) for wi, di, ti in zip(w, ds, ts)) / w.sum()
    assert_allclose(acc.raw_weight, w.sum(), rtol=1e-12)
    assert_allclose(acc.persistent_residual(truth), want, rtol=1e-10)
    assert_allclose(acc.persistent_residual(truth), bias, atol=0.01)  # 40 cycles of 0.01 noise
    # a discount keeps the mean (every cycle's weight alike), and a fold without raw rows drops them
    assert_allclose(acc.discounted(0.1).persistent_residual(truth), want, rtol=1e-10)
    assert acc.fold(acc.cycle_terms(ds[0], ts[0], np.ones(r), 1), lam).persistent_residual(truth) is None


def test_speed_budget_takes_the_persistent_residual_or_the_model_floor():
    m, p = 3, 2
    r = 2 * m + 1
    acc = Accumulator.empty(p, r)
    bias = np.array([0.3, 0.0, 0.0, 0.4, 0.0, 0.0, 0.0])  # harmonic 1: |mean| 0.5; harmonics 2, 3: none
    truth, cycles = _cycles(200, r, p, bias, seed=5)
    for d, t, inv in cycles:
        acc = acc.fold(acc.cycle_terms(d * inv[:, None], t * inv, inv, 1), 1.0, (d, t))
    stats = ResidualStats(np.zeros(m, complex), np.full(m, 1e-4), 0.0, 0.0, 200)
    white = SimpleNamespace(sys_var=np.full(r, 7.0), freq=np.array([1.0, 2.0, 3.0]), stats=stats)
    harmonics = np.array([1.0, 1.0, 2.0])
    got = speed_budget(acc, truth, white, 0.003, harmonics)
    assert_allclose(got[0], 0.5 ** 2 / 2, rtol=0.05)  # the persistent residual, per real component
    assert_allclose(got[[1, 2]], (0.003 * np.array([2.0, 6.0])) ** 2 / 2, rtol=0.05)  # below it: the model floor
    assert_allclose(got[m:2 * m], got[:m])
    assert got[-1] == 7.0  # the balance row as the noise model states it
    # without raw rows (a state saved before them): this cycle's statistics
    assert_allclose(speed_budget(Accumulator.empty(p, r), truth, white, 0.003, harmonics), white.sys_var)
