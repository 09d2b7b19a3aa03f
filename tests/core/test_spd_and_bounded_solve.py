"""The SPD helpers (core.monitor.identify.spd) and the bounded solve (core.monitor.identify.bounded_solve) that the
posterior kernels build on, against numpy's cholesky / solve / inv and scipy's NNLS (``bounded_solve_nnls``, the
code before the kernel, kept verbatim). Split from test_posterior_kernels.py, which checks the posterior as a whole.

The SPD inverses (the reference's own LAPACK potrf, potri on the raw matrix, whole or its coupled head with a
decoupled diagonal tail by reciprocals) are checked for the reference's bits and against numpy's inv to 1e-11 of
sqrt(C_ii C_jj), and the whole one's pivot ratio against the full natural-order Cholesky factor's; the bounded solve
against NNLS to 1e-10 of the largest scaled unknown (columns span 1e-3..1e3, so it is compared in the scaled
unknowns).
"""

import numpy as np
import pytest
from frictionwatch.core.monitor.identify import bounded_solve as bs
from frictionwatch.core.monitor.identify import spd
from frictionwatch.core.monitor.identify.bounded_solve import bounded_solve, bounded_solve_nnls
from frictionwatch.core.monitor.identify.spd import (
    inverse_from_factor,
    inverse_from_factor_reference,
    lapack_inverse_of_sum,
    lapack_spd_inverse_of_sum,
    spd_inverse,
    spd_inverse_decoupled,
)
from numpy.testing import assert_allclose, assert_array_equal


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("layout", ["nuisances_last", "mixed", "all_bounded", "all_free", "scalar_lower"])
def test_bounded_solve_matches_nnls_reference(seed, layout):
    rng = np.random.default_rng(100 + seed)
    p = 47
    a = rng.normal(size=(80, p)) * np.logspace(-3, 3, p)
    truth = 1.0 + rng.random(p)
    if seed % 2:  # half the cases: bounds active
        truth[rng.choice(p, 5, replace=False)] = -2.0
    y = a @ truth + 0.1 * rng.normal(size=80)
    lower = {"nuisances_last": np.concatenate([np.zeros(23), np.full(24, -np.inf)]),
             "mixed": np.where(rng.random(p) < 0.5, -np.inf, 0.5 * rng.random(p)),
             "all_bounded": np.zeros(p), "all_free": np.full(p, -np.inf), "scalar_lower": 0.0}[layout]
    info, rhs = a.T @ a, a.T @ y
    got = bounded_solve(info, rhs, lower)
    want = bounded_solve_nnls(info, rhs, lower)
    lo = np.broadcast_to(lower, (p,))
    assert np.all(got >= lo)
    # compared in the scaled unknowns x = d theta (the problem is solved in them; columns span 1e-3..1e3)
    d = np.sqrt(np.diag(info))
    assert_allclose(got * d, want * d, rtol=0, atol=1e-10 * np.max(np.abs(want * d)))


def test_bounded_solve_near_a_bound_leaves_it_to_nnls():
    # unconstrained optimum at +1e-13 (scaled) of the bound: within the margin, NNLS decides, as before
    info = np.array([[2.0, 0.5], [0.5, 1.0]])
    x = np.array([1e-13, 1.0])
    rhs = info @ x
    status, _ = bs.bounded_solve_kernel(info, rhs, np.zeros(2))
    assert status == bs.NEEDS_BOUND
    assert_array_equal(bounded_solve(info, rhs), bounded_solve_nnls(info, rhs))


@pytest.mark.parametrize("n", [1, 5, 28, 47])
def test_helpers_match_numpy(n):
    rng = np.random.default_rng(n)
    m = rng.normal(size=(n + 3, n)) * np.logspace(-2, 2, n)
    a = m.T @ m
    chol = np.empty((n, n))
    ratio = spd.cholesky(a, chol)
    want = np.linalg.cholesky(a)
    assert 0 < ratio <= 1
    assert_allclose(chol, want, rtol=0, atol=1e-13 * np.abs(want).max(axis=1, keepdims=True).max())
    b = rng.normal(size=n)
    x = spd.cho_solve(chol, b)
    d = np.sqrt(np.diag(a))
    assert_allclose(x * d, np.linalg.solve(a, b) * d, rtol=0, atol=1e-11 * np.max(np.abs(np.linalg.solve(a, b) * d)))
    indefinite = a.copy()
    indefinite[-1, -1] = -1.0
    assert spd.cholesky(indefinite, np.empty((n, n))) == -1.0


def _spd(rng, n, tail=0):
    """A badly scaled SPD matrix (scaled condition ~1e3) whose last ``tail`` rows/columns are decoupled and diagonal."""
    m = rng.normal(size=(n + 3, n)) * np.logspace(-2, 2, n)
    a = m.T @ m
    k = n - tail
    a[k:, :] = 0.0
    a[:, k:] = 0.0
    a[range(k, n), range(k, n)] = rng.random(tail) * 10.0 + 0.1
    return a


@pytest.mark.parametrize("n, tail", [(1, 0), (1, 1), (5, 0), (23, 0), (31, 0), (32, 0), (47, 0), (47, 24), (47, 47),
                                     (61, 3), (28, 22)])
def test_spd_inverse_matches_numpy(n, tail):
    rng = np.random.default_rng(n + 100 * tail)
    a = _spd(rng, n, tail)
    b = np.diag(rng.random(n) * np.diag(a))  # a second addend, like the prior's normal matrix
    total = a + b
    assert spd.decoupled_tail(a, b) == (n - tail if n - tail > 1 else 0)  # a 1 x 1 head is a diagonal entry too
    out = np.empty((n, n))
    ratio = lapack_spd_inverse_of_sum(a, b, out, 2.5)  # N's inverse: the whole raw matrix (spd_inverse's calls)
    assert_array_equal(out, 2.5 * spd_inverse(total))
    want = 2.5 * np.linalg.inv(total)
    assert_array_equal(out, out.T)
    s = np.sqrt(np.outer(np.diag(want), np.diag(want)))
    assert np.max(np.abs(out - want) / s) < 1e-11
    # the pivot ratio is the full natural-order factor's min L_jj^2 / a_jj
    chol = np.linalg.cholesky(total)
    assert_allclose(ratio, np.min(np.diag(chol) ** 2 / np.diag(total)), rtol=1e-12)
    split = np.empty((n, n))  # the reference information's: the coupled head, reciprocals on the tail
    assert lapack_inverse_of_sum(a, b, split, 1.0) == 0  # scale 1: with 2.5 the tail's reciprocals differ by an ulp
    assert_array_equal(split, spd_inverse_decoupled(total))
    assert np.max(np.abs(2.5 * split - want) / s) < 1e-11
    indefinite = b.copy()
    indefinite[n // 2, n // 2] = -total[n // 2, n // 2] - 1.0
    assert lapack_spd_inverse_of_sum(a, indefinite, out, 1.0) == -1.0
    assert lapack_inverse_of_sum(a, indefinite, out, 1.0) == -1


@pytest.mark.parametrize("n", [1, 2, 7, 29, 33, 47, 49])
def test_inverse_from_factor_matches_numpy(n):
    """potri from the factor (``inverse_from_factor``) against numpy's inverse of L L^T on unit-diagonal matrices
    (correlated columns: condition up to 6e5): within 10 eps cond of sqrt(C_ii C_jj) (both are backward-stable
    inverses; 4e-12 at n = 29, condition 6.3e5), exactly symmetric, the strict upper triangle of the factor not
    read."""
    rng = np.random.default_rng(n)
    m = rng.normal(size=(3 * n, n)) @ (np.eye(n) + 0.3 * rng.normal(size=(n, n)))
    a = m.T @ m
    d = 1.0 / np.sqrt(np.diag(a))
    scaled = a * d[:, None] * d[None, :]
    low = np.linalg.cholesky(scaled)
    want = inverse_from_factor_reference(low)
    low[np.triu_indices(n, 1)] = np.nan  # not read
    out = np.empty((n, n))
    assert inverse_from_factor(low, out) == 0
    assert_array_equal(out, out.T)
    s = np.sqrt(np.outer(np.diag(want), np.diag(want)))
    assert np.max(np.abs(out - want) / s) < 10 * np.finfo(float).eps * np.linalg.cond(scaled)
    singular = np.tril(np.ones((n, n)))
    singular[n - 1, n - 1] = 0.0
    assert inverse_from_factor(singular, out) == n  # LAPACK's info: the zero pivot's (1-based) index
