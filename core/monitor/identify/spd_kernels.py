"""Small symmetric positive-definite kernels of core.monitor.identify.posterior_kernels (P <= ~50): Cholesky factor, triangular solve,
inverse by Cholesky, by half-size blocks and BLAS gemms (from ``BLOCKED_MIN`` on), and of a sum of two matrices with a
decoupled diagonal tail.

Loops over rows of ~20-50 elements are bound by loop overhead and loads, not by arithmetic (LLVM's vector loops
handle 16 doubles a pass, the rest goes element by element): the factor and the inverse fold four rows into each pass
over a target row, and the larger inverses go by blocks whose products are BLAS calls. Tested against numpy in
tests/core/test_posterior_kernels.py.
"""

from __future__ import annotations

import numba
import numpy as np

# reassociation lets LLVM vectorise the dot-product reductions (their rounding differs from LAPACK's anyway); no
# 'nnan'/'ninf': the positivity and finiteness tests must see NaN and inf
FASTMATH = {"reassoc", "contract", "nsz", "arcp"}


@numba.njit(cache=True, fastmath=FASTMATH)
def cholesky(a, out):
    """Lower Cholesky factor of the leading m x m block of the symmetric a (lower triangle read), m = out.shape[0],
    into out (m, m) (zeroed above the diagonal).

    Dot-product (left-looking) form, four rows per pass over the factor's row j (its loads shared: the small
    sizes are bound by loop overhead and loads, not by arithmetic).
    Returns the smallest pivot ratio L_jj^2 / a_jj (1 for m = 0), or -1 if a pivot is not positive."""
    n = out.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            out[i, j] = 0.0
    worst = 1.0
    for j in range(n):
        s = a[j, j]
        for k in range(j):
            s -= out[j, k] * out[j, k]
        if not s > 0.0:
            return -1.0
        ratio = s / a[j, j]
        if ratio < worst:
            worst = ratio
        ljj = np.sqrt(s)
        out[j, j] = ljj
        i = j + 1
        while i + 4 <= n:
            t0 = a[i, j]
            t1 = a[i + 1, j]
            t2 = a[i + 2, j]
            t3 = a[i + 3, j]
            for k in range(j):
                v = out[j, k]
                t0 -= out[i, k] * v
                t1 -= out[i + 1, k] * v
                t2 -= out[i + 2, k] * v
                t3 -= out[i + 3, k] * v
            out[i, j] = t0 / ljj
            out[i + 1, j] = t1 / ljj
            out[i + 2, j] = t2 / ljj
            out[i + 3, j] = t3 / ljj
            i += 4
        while i < n:
            t = a[i, j]
            for k in range(j):
                t -= out[i, k] * out[j, k]
            out[i, j] = t / ljj
            i += 1
    return worst


@numba.njit(cache=True, fastmath=FASTMATH)
def cho_solve(chol, b):
    """x = (L L^T)^-1 b for the lower factor L (n, n) and b (n,)."""
    n = chol.shape[0]
    z = np.empty(n)
    for i in range(n):
        t = b[i]
        for k in range(i):
            t -= chol[i, k] * z[k]
        z[i] = t / chol[i, i]
    for i in range(n - 1, -1, -1):
        t = z[i]
        for k in range(i + 1, n):
            t -= chol[k, i] * z[k]
        z[i] = t / chol[i, i]
    return z


@numba.njit(cache=True, fastmath=FASTMATH)
def cho_inverse_into(chol, y, out):
    """out[:m, :m] = (L L^T)^-1, exactly symmetric, for the lower factor L (m, m); y (m, m) is scratch (<- L^-1,
    zeros above the diagonal).

    Y = L^-1 row by row (each row built in a separate buffer: row updates that do not alias vectorise), then
    Y^T Y as a sum of outer products of Y's rows (lower triangle), mirrored. Both fold four rows of Y into each
    pass over the target row (the zeros above Y's diagonal let the four share one loop)."""
    n = chol.shape[0]
    row = np.empty(n)
    for i in range(n):
        for j in range(n):
            row[j] = 0.0
        row[i] = 1.0
        k = 0
        while k + 4 <= i:
            f0 = chol[i, k]
            f1 = chol[i, k + 1]
            f2 = chol[i, k + 2]
            f3 = chol[i, k + 3]
            for j in range(k + 4):
                row[j] -= f0 * y[k, j] + f1 * y[k + 1, j] + f2 * y[k + 2, j] + f3 * y[k + 3, j]
            k += 4
        while k < i:
            f = chol[i, k]
            for j in range(k + 1):
                row[j] -= f * y[k, j]
            k += 1
        d = 1.0 / chol[i, i]
        for j in range(n):
            y[i, j] = row[j] * d
    for i in range(n):
        for j in range(i + 1):
            out[i, j] = 0.0
    k = 0
    while k + 4 <= n:  # sum over k of the outer products of rows k of Y, lower triangle
        for i in range(k + 4):
            f0 = y[k, i]
            f1 = y[k + 1, i]
            f2 = y[k + 2, i]
            f3 = y[k + 3, i]
            for j in range(i + 1):
                out[i, j] += f0 * y[k, j] + f1 * y[k + 1, j] + f2 * y[k + 2, j] + f3 * y[k + 3, j]
        k += 4
    while k < n:
        for i in range(k + 1):
            f = y[k, i]
            for j in range(i + 1):
                out[i, j] += f * y[k, j]
        k += 1
    for i in range(n):
        for j in range(i):
            out[j, i] = out[i, j]


@numba.njit(cache=True, fastmath=FASTMATH)
def cho_inverse(chol):
    """(L L^T)^-1 (n, n), exactly symmetric, from the lower factor L."""
    n = chol.shape[0]
    out = np.empty((n, n))
    cho_inverse_into(chol, np.empty((n, n)), out)
    return out


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


BLOCKED_MIN = 32  # from this size on, the inverse goes by two half-size blocks and small gemms (BLAS)


@numba.njit(cache=True, fastmath=FASTMATH)
def spd_inverse_small(a, out):
    """out (m, m) = a^-1 for the symmetric a (m, m) (lower triangle read), by Cholesky.

    Returns the smallest pivot ratio, or -1 (out undefined)."""
    m = a.shape[0]
    chol = np.empty((m, m))
    worst = cholesky(a, chol)
    if worst < 0.0:
        return -1.0
    cho_inverse_into(chol, np.empty((m, m)), out)
    return worst


@numba.njit(cache=True, fastmath=FASTMATH)
def spd_inverse_blocked(a, b, m, out):
    """out[:m, :m] = inverse of the leading m x m block of the symmetric a + b (lower triangles read), by the
    Schur complement of its leading half: with P = A11^-1 A12 and S = A22 - A12^T P,

        A^-1 = [[A11^-1 + P S^-1 P^T, -P S^-1], [-S^-1 P^T, S^-1]],

    two half-size Cholesky inverses (small loops are bound by their overhead: eight times fewer operations take
    about a quarter of the time) and four small gemms (BLAS, not transposed in their second operand). The
    pivots of S's factor are those of the full factor of A: the ratios are taken against A22's diagonal.

    Returns the smallest pivot ratio L_jj^2 / A_jj, or -1 (out undefined)."""
    n1 = m // 2
    n2 = m - n1
    a11 = np.empty((n1, n1))
    a12 = np.empty((n1, n2))
    for i in range(n1):
        for j in range(i + 1):
            a11[i, j] = a[i, j] + b[i, j]
        for j in range(n2):
            a12[i, j] = a[n1 + j, i] + b[n1 + j, i]
    x11 = np.empty((n1, n1))
    worst = spd_inverse_small(a11, x11)
    if worst < 0.0:
        return -1.0
    p = np.dot(x11, a12)
    s = np.dot(a12.T, p)
    for i in range(n2):
        for j in range(i + 1):
            s[i, j] = (a[n1 + i, n1 + j] + b[n1 + i, n1 + j]) - s[i, j]
    chol = np.empty((n2, n2))
    if cholesky(s, chol) < 0.0:
        return -1.0
    for j in range(n2):
        ratio = chol[j, j] * chol[j, j] / (a[n1 + j, n1 + j] + b[n1 + j, n1 + j])
        if ratio < worst:
            worst = ratio
    q = np.empty((n2, n2))
    cho_inverse_into(chol, np.empty((n2, n2)), q)
    x12 = np.dot(p, q)
    p_t = np.empty((n2, n1))
    for i in range(n1):
        for j in range(n2):
            p_t[j, i] = p[i, j]
    pqp = np.dot(x12, p_t)
    for i in range(n1):
        for j in range(i + 1):
            v = x11[i, j] + pqp[i, j]
            out[i, j] = v
            out[j, i] = v
        for j in range(n2):
            v = -x12[i, j]
            out[i, n1 + j] = v
            out[n1 + j, i] = v
    for i in range(n2):
        for j in range(n2):
            out[n1 + i, n1 + j] = q[i, j]
    return worst


@numba.njit(cache=True, fastmath=FASTMATH)
def spd_inverse_of_sum(a, b, out, scale):
    """out = scale * (a + b)^-1 (n, n), exactly symmetric, for the symmetric positive-definite a + b (lower
    triangles read; the sum is never stored whole): the coupled head by Cholesky (``spd_inverse_blocked`` from
    ``BLOCKED_MIN`` on), reciprocals of a diagonal decoupled tail (``decoupled_tail``).

    Returns the smallest pivot ratio L_jj^2 / (a + b)_jj of the factor of a + b (1 for n = 0), or -1 if a pivot
    is not positive (out is then undefined)."""
    n = a.shape[0]
    k = decoupled_tail(a, b)
    for i in range(k, n):
        if not a[i, i] + b[i, i] > 0.0:
            return -1.0
    if k == n and k >= BLOCKED_MIN:
        worst = spd_inverse_blocked(a, b, k, out)
        if worst >= 0.0 and scale != 1.0:
            for i in range(n):
                for j in range(n):
                    out[i, j] *= scale
        return worst
    head = np.empty((k, k))
    if k >= BLOCKED_MIN:
        worst = spd_inverse_blocked(a, b, k, head)
    else:
        h = np.empty((k, k))
        for i in range(k):
            for j in range(i + 1):
                h[i, j] = a[i, j] + b[i, j]
        worst = spd_inverse_small(h, head)
    if worst < 0.0:
        return worst
    for i in range(k):
        for j in range(k):
            out[i, j] = head[i, j] * scale
        for j in range(k, n):
            out[i, j] = 0.0
    for i in range(k, n):
        for j in range(n):
            out[i, j] = 0.0
        out[i, i] = 1.0 / (a[i, i] + b[i, i]) * scale
    return worst


@numba.njit(cache=True, fastmath=FASTMATH)
def spd_inverse_into(a, out):
    """out = a^-1 (``spd_inverse_of_sum`` of a alone)."""
    return spd_inverse_of_sum(a, np.zeros(a.shape), out, 1.0)
