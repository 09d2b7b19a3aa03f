"""Numba kernels of the bounded MAP estimate and its posterior (core.identify.bounded_solve,
core.accumulate.posterior_from_normal) for the monitor's sizes (P <= ~50 parameters).

The bounded problem min theta^T N theta - 2 r^T theta, theta >= lower, is convex with N positive definite: when the
unconstrained minimiser (free nuisances eliminated exactly) already satisfies the bounds, it is the bounded optimum,
and NNLS is needed only when a bound is active. These kernels do that common case - Cholesky factors, triangular
solves and SPD inverses of small matrices, where the time of the scipy/LAPACK path went into Python call overhead -
and report a status instead of guessing near any decision the reference makes differently:

- ``NEEDS_BOUND``: a bound is active, or so nearly active (``FEASIBLE_MARGIN``) that NNLS's own tolerance decides;
- ``FALLBACK``: a factor's smallest pivot ratio L_jj^2 / A_jj is below ``PIVOT_RATIO_MIN`` (nearly singular: the
  reference's LAPACK factorisation might fail or differ by more than rounding), or the trace bound of the reference
  covariance is near ``max_condition`` (the reference switches to a pseudo-inverse there).

The callers then run the reference code (kept verbatim), so their behaviour in those cases is exactly the old one.
Otherwise the results equal the reference to rounding (<= 1e-10 relative on the monitor's matrices, whose scaled
condition numbers are ~1e2..5e3; tests/core/test_posterior_kernels.py).
"""

from __future__ import annotations

import numba
import numpy as np

OK = 0
NEEDS_BOUND = 1
FALLBACK = 2

PIVOT_RATIO_MIN = 1e-4  # below: left to the reference (rounding may exceed 1e-10; the monitor's are >= 3e-3)
FEASIBLE_MARGIN = 1e-9  # scaled distance to a bound, relative to max |x|, below which NNLS decides
REGULARISATION = 1e-12  # the reference's ridge on the unit-diagonal blocks (bounded_solve)
# reassociation lets LLVM vectorise the dot-product reductions (their rounding differs from LAPACK's anyway); no
# 'nnan'/'ninf': the positivity and finiteness tests must see NaN and inf
_FAST = {"reassoc", "contract", "nsz", "arcp"}


@numba.njit(cache=True, fastmath=_FAST)
def _cholesky(a, out):
    """Lower Cholesky factor of the symmetric a (n, n) (lower triangle read) into out (zeroed above the diagonal).

    Returns the smallest pivot ratio L_jj^2 / a_jj (1 for n = 0), or -1 if a pivot is not positive."""
    n = a.shape[0]
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
        for i in range(j + 1, n):
            t = a[i, j]
            for k in range(j):
                t -= out[i, k] * out[j, k]
            out[i, j] = t / ljj
        for i in range(j):
            out[i, j] = 0.0
    return worst


@numba.njit(cache=True, fastmath=_FAST)
def _cho_solve(chol, b):
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


@numba.njit(cache=True, fastmath=_FAST)
def _cho_inverse(chol):
    """(L L^T)^-1 (n, n), exactly symmetric, from the lower factor L: Y = L^-1, inverse = Y^T Y.

    Both steps as row updates (axpy over contiguous rows), which vectorise; the dot-product forms do not."""
    n = chol.shape[0]
    y = np.zeros((n, n))
    for i in range(n):
        y[i, i] = 1.0
        for k in range(i):
            f = chol[i, k]
            for j in range(k + 1):
                y[i, j] -= f * y[k, j]
        d = chol[i, i]
        for j in range(i + 1):
            y[i, j] = y[i, j] / d
    inv = np.zeros((n, n))
    for k in range(n):  # sum over k of the outer product of row k of Y, lower triangle
        for i in range(k + 1):
            f = y[k, i]
            for j in range(i + 1):
                inv[i, j] += f * y[k, j]
    for i in range(n):
        for j in range(i):
            inv[j, i] = inv[i, j]
    return inv


@numba.njit(cache=True, fastmath=_FAST)
def bounded_solve_kernel(info, rhs, lo):
    """Unconstrained minimiser of theta^T info theta - 2 rhs^T theta as ``bounded_solve`` forms it (unit-diagonal
    scaling, non-finite ``lo`` = free nuisance eliminated by its Schur complement, ridge 1e-12 on both blocks).

    Returns (status, theta (n,)); theta is valid only with status OK (all bounds inactive)."""
    n = info.shape[0]
    theta = np.empty(n)
    d = np.empty(n)
    for i in range(n):
        v = info[i, i]
        if v < 1e-300:
            v = 1e-300
        d[i] = np.sqrt(v)
    nf = 0
    for i in range(n):
        if not np.isfinite(lo[i]):
            nf += 1
    nb = n - nf
    bi = np.empty(nb, np.int64)
    fi = np.empty(nf, np.int64)
    jb = 0
    jf = 0
    for i in range(n):
        if np.isfinite(lo[i]):
            bi[jb] = i
            jb += 1
        else:
            fi[jf] = i
            jf += 1
    # unit-diagonal blocks in the order (free, bounded); products with 1/d (a division per element is slow)
    dinv = 1.0 / d
    s_ff = np.empty((nf, nf))
    s_fb = np.empty((nf, nb))
    s_bb = np.empty((nb, nb))
    for a in range(nf):
        da = dinv[fi[a]]
        for b in range(nf):
            s_ff[a, b] = info[fi[a], fi[b]] * (da * dinv[fi[b]])
        s_ff[a, a] += REGULARISATION
        for b in range(nb):
            s_fb[a, b] = info[fi[a], bi[b]] * (da * dinv[bi[b]])
    for a in range(nb):
        da = dinv[bi[a]]
        for b in range(nb):
            s_bb[a, b] = info[bi[a], bi[b]] * (da * dinv[bi[b]])
        s_bb[a, a] += REGULARISATION
    r = rhs / d
    # free block s_ff + ridge = Lf Lf^T; W = Lf^-1 s_fb and zf = Lf^-1 r_f by row updates
    chol_f = np.empty((nf, nf))
    if _cholesky(s_ff, chol_f) < PIVOT_RATIO_MIN:
        return FALLBACK, theta
    w = s_fb.copy()
    zf = np.empty(nf)
    for a in range(nf):
        zf[a] = r[fi[a]]
    for a in range(nf):
        for k in range(a):
            f = chol_f[a, k]
            for b in range(nb):
                w[a, b] -= f * w[k, b]
            zf[a] -= f * zf[k]
        f = 1.0 / chol_f[a, a]
        for b in range(nb):
            w[a, b] = w[a, b] * f
        zf[a] = zf[a] * f
    # bounded block: Schur complement s_bb - W^T W (+ ridge, already in s_bb), its unconstrained solution
    s_red = s_bb
    r_red = np.empty(nb)
    for a in range(nb):
        r_red[a] = r[bi[a]]
    for k in range(nf):
        for a in range(nb):
            f = w[k, a]
            for b in range(a + 1):
                s_red[a, b] -= f * w[k, b]
            r_red[a] -= f * zf[k]
    for a in range(nb):
        for b in range(a):
            s_red[b, a] = s_red[a, b]
    chol_b = np.empty((nb, nb))
    if _cholesky(s_red, chol_b) < PIVOT_RATIO_MIN:
        return FALLBACK, theta
    xb = _cho_solve(chol_b, r_red)
    scale = 0.0
    for a in range(nb):
        if abs(xb[a]) > scale:
            scale = abs(xb[a])
    for a in range(nb):
        if not xb[a] - lo[bi[a]] * d[bi[a]] > FEASIBLE_MARGIN * scale:
            return NEEDS_BOUND, theta
    # free parameters given the bounded ones: s_ff xf = r_f - s_fb xb
    rf = np.empty(nf)
    for a in range(nf):
        t = r[fi[a]]
        for b in range(nb):
            t -= s_fb[a, b] * xb[b]
        rf[a] = t
    xf = _cho_solve(chol_f, rf)
    for a in range(nb):
        theta[bi[a]] = xb[a] / d[bi[a]]
    for a in range(nf):
        theta[fi[a]] = xf[a] / d[fi[a]]
    return OK, theta


@numba.njit(cache=True, fastmath=_FAST)
def posterior_moments_kernel(acc_info, acc_rhs, yty, rows, sys_map, info_reference, n_pr, sys_var, theta,
                             max_condition):
    """chi^2 reduced, statistical, total and reference covariances of ``posterior_from_normal`` at theta.

    Returns (status, chi2_red, cov_stat, covariance, cov_reference); the arrays are valid only with status OK."""
    n = acc_info.shape[0]
    info = acc_info + n_pr
    dof = rows - n
    quad = 0.0
    lin = 0.0
    for j in range(n):
        t = 0.0
        for i in range(n):
            t += theta[i] * acc_info[i, j]
        quad += t * theta[j]
        lin += theta[j] * acc_rhs[j]
    chi2 = yty - 2.0 * lin + quad
    chi2_red = chi2 / dof if dof > 0 else 1.0
    c = chi2_red if chi2_red > 1.0 else 1.0  # Python's max(1.0, x): nan keeps 1.0
    empty = np.empty((0, 0))
    chol = np.empty((n, n))
    if _cholesky(info, chol) < PIVOT_RATIO_MIN:
        return FALLBACK, chi2_red, empty, empty, empty
    inv = _cho_inverse(chol)
    ref_info = info_reference + n_pr
    if _cholesky(ref_info, chol) < PIVOT_RATIO_MIN:
        return FALLBACK, chi2_red, empty, empty, empty
    ref = _cho_inverse(chol)
    if np.isfinite(max_condition):
        bound = np.trace(ref_info) * np.trace(ref)
        if not bound < max_condition * (1.0 - 1e-6):  # at or near the reference's pseudo-inverse switch
            return FALLBACK, chi2_red, empty, empty, empty
    g = np.dot(inv, sys_map)  # a repeated raw error e moves theta by inv B e
    gs = g * sys_var.reshape(1, -1)
    cov_sys = np.dot(gs, np.ascontiguousarray(g.T))  # a contiguous copy: faster than the transposed gemm
    cov_stat = inv * c
    return OK, chi2_red, cov_stat, cov_stat + cov_sys, ref * c


@numba.njit(cache=True, fastmath=_FAST)
def posterior_kernel(acc_info, acc_rhs, yty, rows, sys_map, info_reference, n_pr, r_pr, sys_var, lo, max_condition):
    """``bounded_solve_kernel`` on (acc_info + n_pr, acc_rhs + r_pr), then ``posterior_moments_kernel``.

    Returns (status, theta, chi2_red, cov_stat, covariance, cov_reference)."""
    status, theta = bounded_solve_kernel(acc_info + n_pr, acc_rhs + r_pr, lo)
    if status != OK:
        empty = np.empty((0, 0))
        return status, theta, 1.0, empty, empty, empty
    status, chi2_red, cov_stat, cov, ref = posterior_moments_kernel(
        acc_info, acc_rhs, yty, rows, sys_map, info_reference, n_pr, sys_var, theta, max_condition)
    return status, theta, chi2_red, cov_stat, cov, ref


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

