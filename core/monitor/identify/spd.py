"""Small symmetric positive-definite helpers of core.monitor.identify.posterior and the tooth fit (P <= ~50),
on LAPACK: numba's np.linalg (potrf, gesv) and potri, which np.linalg does not wrap, bound from the same library
numba's np.linalg calls (scipy.linalg.cython_lapack; ``inverse_from_factor``): the Cholesky factor with its smallest
pivot ratio, a solve, the inverse from a factor, and the inverse of a sum of two matrices by the reference's own calls
on the raw matrix, its bits, for matrices whose conditioning grows with the accumulated cycles
(``lapack_spd_inverse_of_sum``: whole, with its pivot ratio, the information N, design note 80;
``lapack_inverse_of_sum``: a coupled head and a decoupled diagonal tail, the reference information, note 75).

The monitor's matrices are badly scaled (raw condition ~1e12, ~1e3 on a unit diagonal): Cholesky's error is relative
to sqrt(C_ii C_jj) whatever the row scales (it is invariant under diagonal scaling; LU with partial pivoting is not),
so the raw matrix is factored as the reference factors it. A hand-written Cholesky, inverse and
blocked inverse stood here before issue 26 item 6; they gave less than the 20 % end to end that would justify
them (the branch's report quotes the same-run bench). Tested against numpy in tests/core/test_posterior_kernels.py.
"""

from __future__ import annotations

import llvmlite.binding as llvm
import numba
import numpy as np
import scipy.linalg.lapack
from numba import types
from numba.extending import get_cython_function_address

# reassociation lets LLVM vectorise the callers' dot-product loops (their rounding differs from LAPACK's anyway); no
# 'nnan'/'ninf': the positivity and finiteness tests must see NaN and inf
FASTMATH = {"reassoc", "contract", "nsz", "arcp"}

# LAPACK dpotri(uplo, n, a, lda, info), all by pointer, bound by symbol name: a cached kernel resolves the name when
# it is loaded (a ctypes pointer would be a constant address, which numba cannot cache)
llvm.add_symbol("frictionwatch_dpotri", get_cython_function_address("scipy.linalg.cython_lapack", "dpotri"))
_dpotri = types.ExternalFunction("frictionwatch_dpotri", types.void(*([types.voidptr] * 5)))
# dpotrf likewise: with dpotri, the calls scipy.linalg.lapack makes in the reference (accumulate.spd_inverse)
llvm.add_symbol("frictionwatch_dpotrf", get_cython_function_address("scipy.linalg.cython_lapack", "dpotrf"))
_dpotrf = types.ExternalFunction("frictionwatch_dpotrf", types.void(*([types.voidptr] * 5)))
_UPPER = ord("U")
_LOWER = ord("L")


@numba.njit(cache=True)
def _pivot_ratio(low, a):
    """The smallest pivot ratio L_jj^2 / a_jj of a's Cholesky factor ``low`` (1 for an empty one): how close a is to
    losing positive definiteness, whatever its row scales."""
    worst = 1.0
    for j in range(low.shape[0]):
        ratio = low[j, j] * low[j, j] / a[j, j]
        if ratio < worst:
            worst = ratio
    return worst


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
    for j in range(m):
        for i in range(m):
            out[i, j] = low[i, j]
    return _pivot_ratio(low, a)


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
def inverse_from_factor(low, out):
    """out = (L L^T)^-1 (n, n), exactly symmetric, from the lower Cholesky factor L (n, n) (C order; its strict upper
    triangle is not read): LAPACK potri (numpy reference: ``inverse_from_factor_reference``). Returns LAPACK's info:
    0, or > 0 if L has a zero pivot (out is then undefined)."""
    n = low.shape[0]
    x = np.empty((n, n))  # C-order lower = Fortran-order upper: potri with uplo 'U' reads and writes that triangle
    for i in range(n):
        for j in range(i + 1):
            x[i, j] = low[i, j]
    uplo = np.array([_UPPER], dtype=np.uint8)
    dims = np.array([n, max(n, 1), 0], dtype=np.int32)  # n, lda, info
    _dpotri(uplo.ctypes, dims[0:].ctypes, x.ctypes, dims[1:].ctypes, dims[2:].ctypes)
    for i in range(n):
        for j in range(i + 1):
            v = x[i, j]
            out[i, j] = v
            out[j, i] = v
    return int(dims[2])


def inverse_from_factor_reference(low: np.ndarray) -> np.ndarray:
    """``inverse_from_factor`` in numpy: the inverse of L L^T (L lower, its upper triangle ignored)."""
    low = np.tril(low)
    return np.linalg.inv(low @ low.T)


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
def lapack_inverse_of_sum(a, b, out, scale):
    """out = scale * (a + b)^-1 (n, n), exactly symmetric, by the calls of its reference
    (core.monitor.identify.spd.spd_inverse_decoupled) on the same numbers: s = a + b element by element;
    its coupled head (``decoupled_tail``) by LAPACK potrf then potri (``_lapack_head_inverse``); the diagonal tail
    by reciprocals; then x scale. Same library, same calls, same input: the reference's bits however badly
    conditioned s is (equality checked in tests/core/test_posterior_kernels.py).

    For a matrix whose conditioning the data do not bound (the reference information: a rank-one balance that grows
    with the accumulated cycles against fixed priors, design note 75), where an inverse by another route agrees with
    the reference only to ~eps x cond. Returns 0, or -1 if s is not numerically positive definite (LAPACK's info
    > 0, or a tail entry <= 0 or NaN; out is then undefined)."""
    n = a.shape[0]
    k = decoupled_tail(a, b)
    for i in range(k, n):
        if not a[i, i] + b[i, i] > 0.0:
            return -1
    if _lapack_head_inverse(a, b, out, k, scale) < 0.0:
        return -1
    _decoupled_tail_inverse(a, b, out, k, scale)
    return 0


@numba.njit(cache=True)
def lapack_spd_inverse_of_sum(a, b, out, scale):
    """out = scale * (a + b)^-1 (n, n), exactly symmetric, by the calls of its reference
    (core.monitor.identify.spd.spd_inverse: potrf then potri on the whole raw matrix, no tail split) on the
    same numbers: its bits at any condition. For the information matrix N = acc.info + priors, whose condition grows
    with the accumulated cycles on genset-v20 (design note 80).

    Returns the smallest pivot ratio L_jj^2 / s_jj of s's factor (that of the unit-diagonal form: Cholesky is
    invariant under diagonal scaling; 1 for n = 0), or -1 if s is not numerically positive definite (LAPACK's info
    > 0; out is then undefined)."""
    return _lapack_head_inverse(a, b, out, a.shape[0], scale)


@numba.njit(cache=True)
def _lapack_head_inverse(a, b, out, k, scale):
    """out[:k, :k] = scale * (a + b)[:k, :k]^-1 by LAPACK dpotrf then dpotri ('L') on the head's lower triangle in
    Fortran order, as scipy.linalg.lapack passes a C-ordered array (a transposed copy), the lower triangle mirrored
    (the reference's tril + tril(-1).T), then x scale. Returns the factor's smallest pivot ratio L_jj^2 / s_jj (1 for
    k = 0), or -1 if LAPACK refuses (info > 0)."""
    if k == 0:
        return 1.0
    x = np.empty((k, k))  # C order holding the transpose = Fortran order holding the head, as f2py passes it
    for i in range(k):
        for j in range(k):
            x[j, i] = a[i, j] + b[i, j]
    uplo = np.array([_LOWER], dtype=np.uint8)
    dims = np.array([k, k, 0], dtype=np.int32)  # n, lda, info
    _dpotrf(uplo.ctypes, dims[0:].ctypes, x.ctypes, dims[1:].ctypes, dims[2:].ctypes)
    if dims[2] != 0:
        return -1.0
    worst = 1.0
    for j in range(k):
        ratio = x[j, j] * x[j, j] / (a[j, j] + b[j, j])
        if not ratio > 0.0:  # a NaN pivot that potrf let through
            return -1.0
        if ratio < worst:
            worst = ratio
    _dpotri(uplo.ctypes, dims[0:].ctypes, x.ctypes, dims[1:].ctypes, dims[2:].ctypes)
    if dims[2] != 0:
        return -1.0
    for i in range(k):  # Fortran (i, j), i >= j: the lower triangle potri wrote; tril + tril(-1).T, then x scale
        for j in range(i + 1):
            v = x[j, i] * scale
            out[i, j] = v
            out[j, i] = v
    return worst


@numba.njit(cache=True)
def _decoupled_tail_inverse(a, b, out, k, scale):
    """The rest of out = scale * (a + b)^-1 once its (k, k) head is in place: zero off the two diagonal blocks,
    reciprocals of the decoupled tail (``decoupled_tail``) on the diagonal."""
    n = a.shape[0]
    for i in range(k):
        for j in range(k, n):
            out[i, j] = 0.0
    for i in range(k, n):
        for j in range(n):
            out[i, j] = 0.0
        out[i, i] = 1.0 / (a[i, i] + b[i, i]) * scale


_potrf = scipy.linalg.lapack.dpotrf
_potri = scipy.linalg.lapack.dpotri


def spd_inverse_lower(a: np.ndarray) -> np.ndarray | None:
    """The inverse of a symmetric positive-definite matrix in the lower triangle of the result (LAPACK potrf then
    potri; the upper triangle holds the factor's leftovers); None if ``a`` is not numerically positive definite. For
    a caller that mirrors the triangle itself (the pull check's kernel): the symmetrisation is ~half the cost of a
    47 x 47 inverse."""
    c, info = _potrf(a, lower=True, clean=False, overwrite_a=False)
    if info != 0:
        return None
    inv, info = _potri(c, lower=True, overwrite_c=True)
    return inv if info == 0 else None


def spd_inverse(a: np.ndarray, max_condition: float = np.inf) -> np.ndarray | None:
    """Inverse of a symmetric positive-definite matrix by Cholesky (LAPACK potrf/potri), exactly symmetric; None if
    ``a`` is not numerically positive definite or its condition number may exceed ``max_condition`` (bounded by
    trace(a) trace(a^-1) >= lambda_max / lambda_min)."""
    inv = spd_inverse_lower(a)
    if inv is None:
        return None
    inv = np.tril(inv) + np.tril(inv, -1).T  # potri fills the lower triangle only
    if np.isfinite(max_condition):
        bound = float(np.trace(a)) * float(np.trace(inv))
        if not bound < max_condition:
            return None
    return inv


def spd_inverse_decoupled(a: np.ndarray, max_condition: float = np.inf) -> np.ndarray | None:
    """``spd_inverse`` of a matrix whose trailing rows may have no off-diagonal entry (the reference information:
    nuisances that only their priors see): the coupled head by ``spd_inverse``'s calls (potrf, potri), the diagonal
    tail by reciprocals; None as ``spd_inverse`` (not positive definite, or trace(a) trace(a^-1) not below
    ``max_condition``). The reference of core.monitor.identify.spd.lapack_inverse_of_sum (equal bits)."""
    n = a.shape[0]
    coupled = np.flatnonzero(np.any(np.tril(a, -1) != 0.0, axis=1))
    k = int(coupled[-1]) + 1 if coupled.size else 0
    tail = np.diag(a)[k:]
    if not np.all(tail > 0.0):
        return None
    inv = np.zeros((n, n))
    if k:
        head = spd_inverse_lower(np.ascontiguousarray(a[:k, :k]))
        if head is None:
            return None
        inv[:k, :k] = np.tril(head) + np.tril(head, -1).T
    inv[k:, k:] = np.diag(1.0 / tail)
    if np.isfinite(max_condition) and not float(np.trace(a)) * float(np.trace(inv)) < max_condition:
        return None
    return inv


def lower_vector(lower: float | np.ndarray, n: int) -> np.ndarray:
    """``lower`` broadcast to a contiguous float64 (n,) (raises ValueError if it does not broadcast)."""
    lo = np.asarray(lower, dtype=np.float64)
    if lo.shape == (n,):
        return lo if lo.flags.c_contiguous else np.ascontiguousarray(lo)
    return np.ascontiguousarray(np.broadcast_to(lo, (n,)))


def as_matrix(a: np.ndarray, n: int, m: int | None = None, name: str = "matrix") -> np.ndarray:
    """a as a C-contiguous float64 (n, m) array (m = n by default); ValueError on another shape."""
    out = np.ascontiguousarray(a, dtype=np.float64)
    shape = (n, n if m is None else m)
    if out.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {out.shape}")
    return out


def as_vector(a: np.ndarray, n: int, name: str = "vector") -> np.ndarray:
    """a as a C-contiguous float64 (n,) array; ValueError on another shape."""
    out = np.ascontiguousarray(a, dtype=np.float64)
    if out.shape != (n,):
        raise ValueError(f"{name} must have shape {(n,)}, got {out.shape}")
    return out
