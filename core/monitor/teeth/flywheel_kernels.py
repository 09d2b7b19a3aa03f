"""Numba kernels of the flywheel fit (core.monitor.teeth.flywheel): Fourier design over the tooth-edge times, normal equations,
their inverse (LAPACK potrf, potri), the pattern fit, the angle fit with its residual, and the tooth-learner update.

cos(m w1 tau) and sin(m w1 tau) come from the angle-addition recurrence: cos/sin once per edge, then the recurrence
across the edges (vectorised), not re-seeded (the former per-edge kernel re-seeded every 8 orders; that costs as much
as the rest of the design and changed nothing measurable in the fit): rounding grows about linearly with the order,
< 1e-14 at order 48 (the plain reference is ``np.cos(np.outer(tau, w))``, tests/core/test_flywheel_kernels.py).

Why the normal matrix needs no design product: the Fourier columns' inner products over the edges follow from the
power sums C_k = sum_i cos(k w1 tau_i), S_k = sum_i sin(k w1 tau_i), k = 0..2M, by the product-to-sum identities
(cos a cos b = (cos(a-b) + cos(a+b)) / 2, ...): O(n M) work instead of the O(n M^2) of D^T D. The sums of
orders M+1..2M come from the design's own rows by the angle-addition rule (two dot products per order), so no
rows beyond order M are formed.
"""

from __future__ import annotations

import numba
import numpy as np
import rocket_fft  # noqa: F401  (numpy.fft inside numba: ``series_rows_kernel``)
from frictionwatch.core.monitor.identify.spd import inverse_from_factor

FOUR_PI = 4.0 * np.pi

# status codes of the kernels (the Python wrappers turn them into ValueError; a normal matrix that is not positive
# definite raises np.linalg.LinAlgError from the Cholesky)
OK = 0
NOT_INCREASING = 1
BAD_SPAN = 3


@numba.njit(cache=True, fastmath={"reassoc", "nsz"})
def _dot(a, b):
    """sum_i a_i b_i (reassociated so it vectorises; rounding ~ eps sqrt(n))."""
    acc = 0.0
    for i in range(a.shape[0]):
        acc += a[i] * b[i]
    return acc


@numba.njit(cache=True, fastmath={"reassoc", "nsz"})
def _sum(a):
    acc = 0.0
    for i in range(a.shape[0]):
        acc += a[i]
    return acc


@numba.njit(cache=True, fastmath={"reassoc", "nsz"})
def _next_harmonic(cp, sp, c1, s1, cd, sd):
    """cd + i sd = (cp + i sp)(c1 + i s1), elementwise (one recurrence step); returns the sums
    of cd and sd (reassociated only so the reductions vectorise with the step)."""
    sc = 0.0
    ss = 0.0
    for i in range(cd.shape[0]):
        c = cp[i]
        s = sp[i]
        a = c * c1[i] - s * s1[i]
        b = s * c1[i] + c * s1[i]
        cd[i] = a
        sd[i] = b
        sc += a
        ss += b
    return sc, ss


@numba.njit(cache=True, fastmath={"reassoc", "nsz"})
def _angle_sum_sums(ca, sa, cb, sb):
    """(sum_i cos(a_i + b_i), sum_i sin(a_i + b_i)) from the cosines and sines of a and b (angle-addition rule)."""
    sc = 0.0
    ss = 0.0
    for i in range(ca.shape[0]):
        sc += ca[i] * cb[i] - sa[i] * sb[i]
        ss += sa[i] * cb[i] + ca[i] * sb[i]
    return sc, ss


@numba.njit(cache=True)
def _normal_matrix(design_t, n_drift, m_fit, csum, ssum, out):
    """Upper triangle of D^T D (p, p) from the power sums csum, ssum (2 m_fit + 1,) (module docstring)."""
    n = design_t.shape[1]
    c0 = n_drift
    s0 = n_drift + m_fit
    out[0, 0] = float(n)
    for k in range(1, m_fit + 1):
        out[0, c0 + k - 1] = csum[k]
        out[0, s0 + k - 1] = ssum[k]
    if n_drift == 2:
        q = design_t[1]
        out[0, 1] = _sum(q)
        for r in range(1, design_t.shape[0]):
            out[1, r] = _dot(q, design_t[r])
    for j in range(1, m_fit + 1):
        for k in range(j, m_fit + 1):
            out[c0 + j - 1, c0 + k - 1] = 0.5 * (csum[k - j] + csum[k + j])
            out[s0 + j - 1, s0 + k - 1] = 0.5 * (csum[k - j] - csum[k + j])
        for k in range(1, m_fit + 1):
            d = k - j
            sd = ssum[d] if d >= 0 else -ssum[-d]
            out[c0 + j - 1, s0 + k - 1] = 0.5 * (ssum[k + j] + sd)


@numba.njit(cache=True)
def prepare_fit_kernel(ticks, tick_hz, n_drift, m_fit, n_harm, patterns, pattern_period, drift_pattern, prepared, pat):
    """Angle-independent part of the flywheel fit of the edges ``ticks`` (n,) (core.monitor.teeth.flywheel.prepare_fit).

    Fills ``prepared`` = (tau, design_t, scale, normal_inv): tau (n,) [s], design_t (p, n) = D^T with rows [1,
    (u (u - 1)), cos k w1 tau (k = 1..m_fit), sin ...], scale (p,) = column norms of D, normal_inv (p, p) = inverse of
    the unit-scaled normal matrix (LAPACK, exactly symmetric); and pat (n_harm, q) complex = fitted harmonics of the
    patterns (n, q0) and, with ``drift_pattern``, of a last pattern u (u - 1), u from the ticks. With
    ``pattern_period`` T > 0, patterns holds only the first T rows: edge e uses row e % T (tooth patterns repeat every
    revolution), and the design rows are summed over the repeats before the product (half the work for a
    two-revolution cycle). Returns a status code (OK, NOT_INCREASING); a normal matrix that is not positive definite
    raises np.linalg.LinAlgError."""
    tau, design_t, scale, normal_inv = prepared
    n = ticks.shape[0]
    p = n_drift + 2 * m_fit
    t0 = ticks[0]
    for i in range(1, n):
        if ticks[i] <= ticks[i - 1]:
            return NOT_INCREASING
    for i in range(n):
        tau[i] = float(ticks[i] - t0) / tick_hz  # exact integer differences, then seconds
    period = tau[n - 1]
    w1 = 0.5 * (FOUR_PI / period)
    c0 = n_drift
    s0 = n_drift + m_fit
    for i in range(n):
        design_t[0, i] = 1.0
    if n_drift == 2:
        for i in range(n):
            u = tau[i] / period
            design_t[1, i] = u * (u - 1.0)
    c1 = design_t[c0]
    s1 = design_t[s0]
    for i in range(n):
        a = tau[i] * w1
        c1[i] = np.cos(a)
        s1[i] = np.sin(a)
    # power sums up to order 2 m_fit: orders 2..m_fit by the recurrence into the design, the orders above from
    # the product rule cos((m + j) a) = cos(m a) cos(j a) - sin(m a) sin(j a) (two dot products; no design rows)
    csum = np.empty(2 * m_fit + 1)
    ssum = np.empty(2 * m_fit + 1)
    csum[0] = float(n)
    ssum[0] = 0.0
    csum[1] = _sum(c1)
    ssum[1] = _sum(s1)
    for k in range(2, m_fit + 1):
        csum[k], ssum[k] = _next_harmonic(design_t[c0 + k - 2], design_t[s0 + k - 2], c1, s1, design_t[c0 + k - 1],
                                          design_t[s0 + k - 1])
    cm = design_t[c0 + m_fit - 1]
    sm = design_t[s0 + m_fit - 1]
    for j in range(1, m_fit + 1):
        csum[m_fit + j], ssum[m_fit + j] = _angle_sum_sums(cm, sm, design_t[c0 + j - 1], design_t[s0 + j - 1])
    normal = np.empty((p, p))
    _normal_matrix(design_t, n_drift, m_fit, csum, ssum, normal)
    for j in range(p):
        scale[j] = np.sqrt(normal[j, j])
    # unit-scaled columns: the Fourier columns are nearly orthogonal over the edges, so this is well conditioned
    for j in range(p):
        for k in range(j, p):
            v = normal[j, k] / (scale[j] * scale[k])
            normal[j, k] = v
            normal[k, j] = v
    # LAPACK, not hand triangular solves (< 20 % end to end, issue 26 item 6): potrf raises LinAlgError if not
    # positive definite, potri inverts from that factor (exactly symmetric); with the inverse (well conditioned: see
    # above) the solves below are BLAS products
    inverse_from_factor(np.linalg.cholesky(normal), normal_inv)
    q0 = patterns.shape[1]
    if q0 == 0 and not drift_pattern:
        return OK
    x = np.empty((p, q0))  # pattern columns; the drift pattern (not periodic) is solved apart, as a vector
    xd = np.zeros(p)
    qp = np.empty(n)
    if drift_pattern:
        den = float(ticks[n - 1] - t0)
        for i in range(n):
            u = float(ticks[i] - t0) / den
            qp[i] = u * (u - 1.0)
    if q0 > 0 and pattern_period > 0:
        folded = np.empty((p, pattern_period))
        for j in range(p):
            xd[j] = _fold_row(design_t[j], pattern_period, folded[j], qp, drift_pattern)
        x = np.dot(folded, patterns)  # a new array: x[:, :] = ... compiled ~2.7 s of broadcasting setitem
    else:
        if q0 > 0:
            x = np.dot(design_t, patterns)
        if drift_pattern:
            for j in range(p):
                xd[j] = _dot(design_t[j], qp)
    for j in range(p):
        inv = scale[j]
        for c in range(q0):
            x[j, c] /= inv
        xd[j] /= inv
    if q0 > 0:
        x = np.dot(normal_inv, x)
    if drift_pattern:
        xd = np.dot(normal_inv, xd)
    for k in range(n_harm):
        a = scale[c0 + k]
        b = scale[s0 + k]
        for c in range(q0):
            pat[k, c] = complex(x[c0 + k, c] / a, -(x[s0 + k, c] / b))
        if drift_pattern:
            pat[k, q0] = complex(xd[c0 + k] / a, -(xd[s0 + k] / b))
    return OK


@numba.njit(cache=True, fastmath={"reassoc", "nsz"})
def _fold_row(row, period, out, qp, with_dot):
    """out[e] = sum_r row[e + r period] (the design row summed over the pattern's repeats); returns row . qp when
    ``with_dot`` (one pass over the row for both)."""
    n = row.shape[0]
    acc = 0.0
    for e in range(period):
        out[e] = row[e]
    start = period
    while start < n:
        for e in range(min(n - start, period)):
            out[e] += row[start + e]
        start += period
    if with_dot:
        for i in range(n):
            acc += row[i] * qp[i]
    return acc


@numba.njit(cache=True)
def fit_angles_kernel(design_t, scale, normal_inv, tau, omega, ang, n_drift, m_fit, harm, resid):
    """Least-squares fit of the edge angles ang (n,) [rad] on a prepared design (core.monitor.teeth.flywheel.fit_prepared).

    Fills harm (n_harm,) complex and resid (n,) [rad]; returns (status, offset, drift, rms residual)."""
    n = ang.shape[0]
    p = design_t.shape[0]
    for i in range(1, n):
        if not ang[i] > ang[i - 1]:
            return NOT_INCREASING, 0.0, 0.0, 0.0
    a0 = ang[0]
    if not abs(ang[n - 1] - a0 - FOUR_PI) <= 1e-6:
        return BAD_SPAN, 0.0, 0.0, 0.0
    for i in range(n):
        resid[i] = ang[i] - a0 - omega * tau[i]  # phi, the angle deviation
    rhs = np.empty(p)
    for j in range(p):
        rhs[j] = _dot(design_t[j], resid) / scale[j]
    coef = np.dot(normal_inv, rhs)
    for j in range(p):
        coef[j] /= scale[j]
    for j in range(p):
        cj = coef[j]
        row = design_t[j]
        for i in range(n):
            resid[i] -= cj * row[i]
    c0 = n_drift
    s0 = n_drift + m_fit
    for k in range(harm.shape[0]):
        harm[k] = complex(coef[c0 + k], -coef[s0 + k])
    rms = np.sqrt(_dot(resid, resid) / n)
    return OK, coef[0], (coef[1] if n_drift == 2 else 0.0), rms


@numba.njit(cache=True)
def tooth_update_kernel(correction, tooth_index, residual, gain):
    """One EWMA step of the tooth-spacing correction (core.monitor.teeth.flywheel.ToothLearner.update); returns the new array."""
    n = correction.shape[0]
    total = np.zeros(n)
    hits = np.zeros(n, dtype=np.int64)
    for e in range(tooth_index.shape[0] - 1):  # the closing edge repeats the first position
        k = tooth_index[e] % n
        total[k] += residual[e]
        hits[k] += 1
    c = correction.copy()
    acc = 0.0
    seen = 0
    for k in range(n):
        if hits[k] > 0:
            # an edge whose tooth sits eps further than assumed is reached later: its residual is -(eps - corr)
            c[k] -= gain * total[k] / hits[k]
            acc += c[k]
            seen += 1
    if seen:
        mean = acc / seen
        for k in range(n):
            if hits[k] > 0:
                c[k] -= mean  # tooth errors sum to zero over a revolution
    return c


@numba.njit(cache=True)
def series_rows_kernel(coeffs, n, mean):
    """frictionwatch.core.monitor.teeth.flywheel.harmonic_series of rows coeffs (r, M) complex on n samples: mean + the inverse rfft of the
    harmonics scaled by n / 2 (the same spectrum and transform as the numpy code, so the same numbers)."""
    r, m = coeffs.shape
    spec = np.zeros((r, n // 2 + 1), dtype=np.complex128)
    half = 0.5 * n
    for k in range(r):
        for j in range(m):
            spec[k, j + 1] = coeffs[k, j] * half
    out = np.fft.irfft(spec, n, -1)
    if mean != 0.0:
        for k in range(r):
            for i in range(n):
                out[k, i] += mean
    return out
