"""The bounded MAP estimate: argmin_{theta >= lower} theta^T N theta - 2 r^T theta on small SPD systems, by a numba
kernel in the common case (no bound active) with NNLS as its general path and reference, and the paper's Eq. 5 fit.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.linalg
import scipy.linalg.lapack
import scipy.optimize
from frictionwatch.core.monitor.identify.spd import FASTMATH, as_vector, cho_solve, cholesky, lower_vector, solve_or_nan

OK = 0
NEEDS_BOUND = 1
FALLBACK = 2
BAD_SHAPE = 3  # the arrays' shapes do not fit together (the caller's validating path raises the ValueError)

PIVOT_RATIO_MIN = 1e-4  # bounded_solve_kernel's factors: below, NNLS (its rounding ~1e-15 / ratio apart, note 75)
FEASIBLE_MARGIN = 1e-9  # scaled distance to a bound, relative to max |x|, below which NNLS decides
REGULARISATION = 1e-12  # the reference's ridge on the unit-diagonal blocks (bounded_solve)


_getrf = scipy.linalg.lapack.dgetrf
_getrs = scipy.linalg.lapack.dgetrs
_trtrs = scipy.linalg.lapack.dtrtrs


@numba.njit(cache=True, fastmath=FASTMATH)
def bounded_solve_kernel(info, rhs, lo):
    """Unconstrained minimiser of params^T info params - 2 rhs^T params as ``bounded_solve`` forms it (unit-diagonal
    scaling, non-finite ``lo`` = free nuisance eliminated by its Schur complement, ridge 1e-12 on both blocks).

    Returns (status, params (n,)); params is valid only with status OK (all bounds inactive)."""
    n = info.shape[0]
    params = np.empty(n)
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
    # free block s_ff + ridge = Lf Lf^T; W = Lf^-1 s_fb and zf = Lf^-1 r_f in one solve
    chol_f = np.empty((nf, nf))
    if cholesky(s_ff, chol_f) < PIVOT_RATIO_MIN:
        return FALLBACK, params
    rhs_f = np.empty((nf, nb + 1))
    for a in range(nf):
        for b in range(nb):
            rhs_f[a, b] = s_fb[a, b]
        rhs_f[a, nb] = r[fi[a]]
    wz = solve_or_nan(chol_f, rhs_f)
    w = wz[:, :nb]
    zf = wz[:, nb]
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
    if cholesky(s_red, chol_b) < PIVOT_RATIO_MIN:
        return FALLBACK, params
    xb = cho_solve(chol_b, r_red)
    scale = 0.0
    for a in range(nb):
        if abs(xb[a]) > scale:
            scale = abs(xb[a])
    for a in range(nb):
        if not xb[a] - lo[bi[a]] * d[bi[a]] > FEASIBLE_MARGIN * scale:
            return NEEDS_BOUND, params
    # free parameters given the bounded ones: s_ff xf = r_f - s_fb xb
    rf = np.empty(nf)
    for a in range(nf):
        t = r[fi[a]]
        for b in range(nb):
            t -= s_fb[a, b] * xb[b]
        rf[a] = t
    xf = cho_solve(chol_f, rf)
    for a in range(nb):
        params[bi[a]] = xb[a] / d[bi[a]]
    for a in range(nf):
        params[fi[a]] = xf[a] / d[fi[a]]
    return OK, params


def bounded_solve(info: np.ndarray, rhs: np.ndarray, lower: float | np.ndarray = 0.0) -> np.ndarray:
    """argmin_{theta >= lower} theta^T info theta - 2 rhs^T theta for a symmetric positive-definite ``info``.

    ``lower`` may be -inf for free parameters (nuisances): they are eliminated exactly (Schur complement) before the
    bounded part is solved and recovered after. Never forms a least-squares problem from raw rows: it factors the
    (already accumulated) information matrix, column-scaled to unit diagonal (physics.md §8). The problem is convex:
    when its unconstrained minimiser meets the bounds it is the answer (core.monitor.identify.posterior); otherwise, or when
    the factors are nearly singular, NNLS on the triangular factor decides (``bounded_solve_nnls``)."""
    info = np.asarray(info, dtype=np.float64)
    n = info.shape[0]
    if info.shape == (n, n):
        lo = lower_vector(lower, n)
        status, theta = bounded_solve_kernel(np.ascontiguousarray(info), as_vector(rhs, n, "rhs"), lo)
        if status == OK:
            return theta
    return bounded_solve_nnls(info, rhs, lower)


def bounded_solve_nnls(info: np.ndarray, rhs: np.ndarray, lower: float | np.ndarray = 0.0) -> np.ndarray:
    """``bounded_solve`` by NNLS on the Cholesky factor of the reduced, unit-diagonal information matrix: the
    general path (a bound active, nearly singular factors) and the reference of the fast one."""
    n = info.shape[0]
    lo = np.broadcast_to(np.asarray(lower, dtype=np.float64), (n,))
    free = ~np.isfinite(lo)
    n_free = int(free.sum())
    d = np.sqrt(np.clip(np.diag(info), 1e-300, None))
    s = info / np.outer(d, d)
    r = rhs / d
    if 0 < n_free < n and free[n - n_free:].all():  # nuisances last (the monitor's layout): plain slices
        nb = n - n_free
        bnd = slice(0, nb)
        fre = slice(nb, n)
    else:
        bnd = np.flatnonzero(~free)
        fre = np.flatnonzero(free)
    s_bb = s[bnd][:, bnd] if isinstance(bnd, np.ndarray) else s[bnd, bnd]
    out = np.empty(n)
    if n_free:
        s_ff = (s[fre][:, fre] if isinstance(fre, np.ndarray) else s[fre, fre]) + 1e-12 * np.eye(n_free)
        s_bf = s[bnd][:, fre] if isinstance(bnd, np.ndarray) else s[bnd, fre]
        lu, piv, _ = _getrf(s_ff)  # one factorisation for the three solves
        x_ff = _getrs(lu, piv, np.column_stack([s_bf.T, r[fre]]))[0]
        s_red = s_bb - s_bf @ x_ff[:, :-1]
        r_red = r[bnd] - s_bf @ x_ff[:, -1]
    else:
        s_red, r_red = s, r
    if n_free < n:
        lo_x = lo[bnd] * d[bnd]
        chol = np.linalg.cholesky(s_red + 1e-12 * np.eye(s_red.shape[0]))  # s = L L^T
        y = _trtrs(chol, r_red, lower=1)[0]
        # min ||L^T x - y||^2 with x >= lo_x: substitute x = x' + lo_x
        x, _ = scipy.optimize.nnls(chol.T, y - chol.T @ lo_x, maxiter=50 * s_red.shape[0])
        out[bnd] = x + lo_x
    if n_free:
        out[fre] = _getrs(lu, piv, r[fre] - s_bf.T @ out[bnd])[0]
    return out / d


def p_omega_fit(basis: np.ndarray, friction: np.ndarray, mean_row: np.ndarray | None = None,
                mean_target: float | None = None, mean_weight: float = 1e6) -> np.ndarray:
    """Paper 000 Eq. 5 with a >= 0: fit a (6,) to a measured friction trace T_F (p,) = F (p, 6) a.

    Column-scaled, bounded (NNLS); the mean condition sum_l a_l <F_l> = T_fM (paper 000 Eq. 7) enters as a heavily
    weighted row (``mean_weight`` times the rms of the equations), i.e. an equality to working precision."""
    f = np.asarray(basis, dtype=np.float64)
    t = np.asarray(friction, dtype=np.float64)
    if f.ndim != 2 or f.shape[0] != t.shape[0]:
        raise ValueError(f"basis must be (p, n_terms) matching friction (p,), got {f.shape} and {t.shape}")
    scale = np.sqrt(np.mean(f * f, axis=0))
    keep = scale > 0
    a_mat = f[:, keep] / scale[keep]
    b = t
    if mean_row is not None and mean_target is not None:
        wgt = mean_weight / np.sqrt(a_mat.shape[0])
        a_mat = np.vstack([a_mat, wgt * np.asarray(mean_row)[keep] / scale[keep]])
        b = np.append(b, wgt * mean_target)
    x, _ = scipy.optimize.nnls(a_mat, b, maxiter=100 * a_mat.shape[1])
    out = np.zeros(f.shape[1])
    out[keep] = x / scale[keep]
    return out
