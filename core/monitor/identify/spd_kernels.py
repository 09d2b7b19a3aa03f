"""Small symmetric positive-definite helpers of core.monitor.identify.posterior_kernels (P <= ~50), on numba's
np.linalg (LAPACK potrf, getrf/getri, gesv): the Cholesky factor with its smallest pivot ratio, a solve, and the
inverse of a sum of two matrices with a decoupled diagonal tail.

The monitor's matrices are badly scaled (raw condition ~1e12, ~1e3 on a unit diagonal): the inverse is taken of the
unit-diagonal matrix D A D and scaled back, so its error is relative to sqrt(C_ii C_jj) whatever the row scales
(LU with partial pivoting is not invariant under diagonal scaling; Cholesky is). A hand-written Cholesky, inverse and
blocked inverse stood here before issue 26 item 6; they gave less than the 20 % end to end that would justify
them (the branch's report quotes the same-run bench). Tested against numpy in tests/core/test_posterior_kernels.py.
"""

from __future__ import annotations

import numba
import numpy as np

# reassociation lets LLVM vectorise the callers' dot-product loops (their rounding differs from LAPACK's anyway); no
# 'nnan'/'ninf': the positivity and finiteness tests must see NaN and inf
FASTMATH = {"reassoc", "contract", "nsz", "arcp"}


@numba.njit(cache=True)
def _factor(a):
    """np.linalg.cholesky of the symmetric a (lower triangle read), or an empty (0, 0) array if it is not
    positive definite (LinAlgError, or a pivot that is NaN or inf: potrf lets them through)."""
    try:
        low = np.linalg.cholesky(a)
    except Exception:  # np.linalg.LinAlgError: a kernel returns a status, it does not raise
        return np.empty((0, 0))
    for j in range(low.shape[0]):
        if not 0.0 < low[j, j] < np.inf:
            return np.empty((0, 0))
    return low


@numba.njit(cache=True)
def cholesky(a, out):
    """Lower Cholesky factor of the leading m x m block of the symmetric a (lower triangle read), m = out.shape[0],
    into out (m, m) (zeroed above the diagonal).

    Returns the smallest pivot ratio L_jj^2 / a_jj (1 for m = 0), or -1 if the block is not positive definite."""
    m = out.shape[0]
    if m == 0:
        return 1.0
    low = _factor(a[:m, :m])
    if low.shape[0] != m:
        return -1.0
    worst = 1.0
    for j in range(m):
        ratio = low[j, j] * low[j, j] / a[j, j]
        if ratio < worst:
            worst = ratio
        for i in range(m):
            out[i, j] = low[i, j]
    return worst


@numba.njit(cache=True)
def solve_or_nan(a, b):
    """np.linalg.solve(a, b) for a finite a (a factor that passed ``cholesky``); NaN where numba's solve refuses a
    non-finite b (a kernel returns NaN, which its callers' status tests catch, rather than raise)."""
    if a.shape[0] == 0:
        return b.copy()
    try:
        return np.linalg.solve(a, b)
    except Exception:  # np.linalg.LinAlgError: "Array must not contain infs or NaNs"
        return np.full_like(b, np.nan)


@numba.njit(cache=True)
def cho_solve(chol, b):
    """x = (L L^T)^-1 b for the lower factor L (n, n) and b (n,): two np.linalg.solve calls (the factor's
    diagonal dominates its columns in the monitor's unit-diagonal problems, so partial pivoting leaves it be)."""
    return solve_or_nan(chol.T, solve_or_nan(chol, b))


@numba.njit(cache=True)
def _scaled_inverse(h, scale, out):
    """out = scale * h^-1 (n, n), exactly symmetric, for the symmetric positive-definite h (full): np.linalg.inv of
    the unit-diagonal D h D, scaled back."""
    n = h.shape[0]
    d = np.empty(n)
    for i in range(n):
        d[i] = 1.0 / np.sqrt(h[i, i])
    s = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            s[i, j] = h[i, j] * d[i] * d[j]
    x = np.linalg.inv(s)
    for i in range(n):
        for j in range(i + 1):
            v = 0.5 * (x[i, j] + x[j, i]) * (d[i] * d[j]) * scale
            out[i, j] = v
            out[j, i] = v


@numba.njit(cache=True, fastmath=FASTMATH)
def decoupled_tail(a, b):
    """Start k of the trailing rows of the symmetric a + b (lower triangles read) that have no off-diagonal entry:
    a + b is then block diagonal, a full (k, k) head and a diagonal tail (the monitor's reference information: the
    free nuisances see only their own priors)."""
    n = a.shape[0]
    k = n
    while k > 0:
        i = k - 1
        nonzero = 0
        for j in range(i):  # counted, not searched: the loop vectorises
            nonzero += a[i, j] + b[i, j] != 0.0
        if nonzero:
            return k
        k -= 1
    return 0


@numba.njit(cache=True)
def spd_inverse_of_sum(a, b, out, scale):
    """out = scale * (a + b)^-1 (n, n), exactly symmetric, for the symmetric positive-definite a + b (lower
    triangles read): the coupled head by np.linalg (Cholesky for the pivot ratio, the inverse of its unit-diagonal
    form), reciprocals of a diagonal decoupled tail (``decoupled_tail``).

    Returns the smallest pivot ratio L_jj^2 / (a + b)_jj of the factor of a + b (1 for n = 0), or -1 if it is not
    positive definite (out is then undefined)."""
    n = a.shape[0]
    k = decoupled_tail(a, b)
    for i in range(k, n):
        if not a[i, i] + b[i, i] > 0.0:
            return -1.0
    head = np.empty((k, k))
    for i in range(k):
        for j in range(i + 1):
            v = a[i, j] + b[i, j]
            head[i, j] = v
            head[j, i] = v
    worst = 1.0
    if k > 0:
        low = _factor(head)
        if low.shape[0] != k:
            return -1.0
        for j in range(k):
            ratio = low[j, j] * low[j, j] / head[j, j]
            if ratio < worst:
                worst = ratio
        _scaled_inverse(head, scale, out[:k, :k])
    for i in range(k):
        for j in range(k, n):
            out[i, j] = 0.0
    for i in range(k, n):
        for j in range(n):
            out[i, j] = 0.0
        out[i, i] = 1.0 / (a[i, i] + b[i, i]) * scale
    return worst


@numba.njit(cache=True)
def spd_inverse_into(a, out):
    """out = a^-1 (``spd_inverse_of_sum`` of a alone)."""
    return spd_inverse_of_sum(a, np.zeros(a.shape), out, 1.0)
