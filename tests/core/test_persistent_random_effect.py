"""A repeated row error as a random effect of the accumulated equations
(core.monitor.identify.accumulate.Accumulator.with_persistent_error; design note 38): the normal equations are
the generalised least squares of rows whose error has a part common to every cycle, so the estimate is not drawn
by that part and its covariance carries it."""

from __future__ import annotations

import numpy as np
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from numpy.testing import assert_allclose


def _accumulated(n: int, r: int, p: int, inv: np.ndarray, bias: np.ndarray, seed: int = 3):
    """(truth, the accumulator of n cycles without forgetting, the raw rows (n, r, p) and targets (n, r))."""
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0.5, 1.5, p)
    acc = Accumulator.empty(p, r)
    ds, ts = [], []
    for _ in range(n):
        d = rng.standard_normal((r, p)) + 0.8  # rows with a common mean part, as a steady harmonic's
        t = d @ truth + bias + rng.standard_normal(r) / inv
        a, y = d * inv[:, None], t * inv
        acc = acc.fold(acc.cycle_terms(a, y, inv, 0), 1.0, (d, t), (a, y))
        ds.append(d)
        ts.append(t)
    return truth, acc, np.array(ds), np.array(ts)


def test_the_equations_are_the_random_effect_generalised_least_squares():
    n, r, p = 30, 5, 3
    inv = np.array([1.0, 2.0, 0.5, 1.5, 1.0])
    v = np.array([0.0, 0.01, 0.2, 1.0, 0.05])
    _, acc, ds, ts = _accumulated(n, r, p, inv, np.zeros(r))
    got = acc.with_persistent_error(v, inv)
    info, rhs = np.zeros((p, p)), np.zeros(p)
    for k in range(r):  # row k over the n cycles: covariance var I + v 1 1^T
        cov = np.eye(n) / inv[k] ** 2 + v[k] * np.ones((n, n))
        w = np.linalg.inv(cov)
        info += ds[:, k, :].T @ w @ ds[:, k, :]
        rhs += ds[:, k, :].T @ w @ ts[:, k]
    assert_allclose(got.info, info, rtol=1e-9)
    assert_allclose(got.rhs, rhs, rtol=1e-9)
    # the sandwich's map: a raw error e repeated in every cycle moves the right-hand side by sys_map @ e
    e = np.array([0.3, -0.2, 0.1, 0.5, -0.4])
    moved = sum(ds[:, k, :].T @ np.linalg.inv(np.eye(n) / inv[k] ** 2 + v[k] * np.ones((n, n))) @ np.full(n, e[k])
                for k in range(r))
    assert_allclose(got.sys_map @ e, moved, rtol=1e-9)
    # no repeated error, or no whitened sums (a state saved before them): the equations as they were
    assert acc.with_persistent_error(np.zeros(r), inv) is acc
    bare = Accumulator.empty(p, r).fold(acc.cycle_terms(ds[0] * inv[:, None], ts[0] * inv, inv, 0), 1.0,
                                        (ds[0], ts[0]))
    assert bare.with_persistent_error(v, inv) is bare


def test_a_bias_the_random_effect_states_does_not_draw_the_estimate():
    n, r, p = 400, 8, 3
    inv = np.full(r, 10.0)
    bias = np.array([0.5, -0.4, 0.3, 0.6, -0.5, 0.2, -0.3, 0.4])
    truth, acc, _, _ = _accumulated(n, r, p, inv, bias, seed=7)
    plain = np.linalg.solve(acc.info, acc.rhs)
    re = acc.with_persistent_error(np.full(r, 0.25), inv)
    marg = np.linalg.solve(re.info, re.rhs)
    # weighted by the noise alone the common error draws the estimate far outside its statistical sigma; as a
    # random effect the estimate rests on the cycles' variation, and its own covariance covers the error
    sig_plain = np.sqrt(np.diag(np.linalg.inv(acc.info)))
    sig_re = np.sqrt(np.diag(np.linalg.inv(re.info)))
    assert np.max(np.abs(plain - truth) / sig_plain) > 5.0
    assert np.all(np.abs(marg - truth) <= 3.0 * sig_re)
    assert np.all(np.abs(marg - truth) < np.abs(plain - truth))
    # after the change detector's discount the mean counts as 0.3 n cycles (var / 0.3 n + v): with v >> var / n
    # the estimate hardly moves (not exactly: the mean's share of the information is another)
    k = acc.discounted(0.3).with_persistent_error(np.full(r, 0.25), inv)
    assert_allclose(np.linalg.solve(k.info, k.rhs), marg, rtol=1e-3)
