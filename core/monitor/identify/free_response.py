"""The drive train's free response carried into a cycle's window, a random effect of its speed equations (issue 29,
design notes 105, 108).

The harmonic balance models a cycle's speed as the periodic response to that cycle's torques. The plant is not
periodic: each cycle's combustion differs, and the chain's state at the window's start is the end of the cycle
before, not the periodic solution of this one. The difference is a free vibration, sum over the chain's modes of
Re(c e^(lambda t)), whose amplitudes c are set by the cycles before (a late cylinder's deviation, genset-v20's
cylinder 13 at 648 deg of 720, is still ringing when the next window starts). A mode that keeps much of its
amplitude over one cycle, |e^(lambda T)|, and lies in the fitted band puts a repeated pattern into the low orders
that the friction columns absorb: at one load on genset-v20 (the electromechanical mode 2.4 Hz, 0.74 of it carried
over a cycle at 1500 rpm, and the chain's first flexible mode 19.6 Hz, 0.32) the data-only point of cylinder 13
was +127 % from the truth on sigma 25 % at 1,750 cycles (seed 43) and +194 % on 43 % at 1,000 (seed 47); with
those two modes' free response taken out of every cycle's rows +54 % on 29 % and +85 % on 58 % (note 105).

Each carried mode's free response is a random effect of the cycle (its two real amplitudes): its columns D, the
speed harmonics k = 1..M of Re(c e^(lambda t)) over the window t in [0, T),

    c I_k(lambda) + conj(c) I_k(conj(lambda)),   I_k(l) = (e^(l T) - 1) / (T (l - i k 2 pi / T))

(the monitor's harmonics: angle Re(h e^(+i k w t)), w = 2 pi / T, speed i k w h), whitened like the rows. The two
coefficients of a mode have a prior variance s from the data: the EWMA of each cycle's GLS coefficients squared on
the residual at the previous estimate less their noise (design note 108; kept in the residual statistics beside
the drift's step variance), and the flywheel's whitened rows are whitened again by (I + D S D^T)^(-1/2) (2 columns
per mode: a small eigenproblem on their span). A mode that rings strongly (s large) is as good as projected out
(note 105's projection, the limit s -> inf); one that carries little keeps the low orders' information in place
(maruti-3cyl's 39.5 Hz mode: note 105's projection cost it its split).

``carried_modes`` chooses the modes: Im lambda at most the highest fitted harmonic's frequency and |e^(lambda T)| >=
``carry`` (MonitorConfig.free_response_carry). A cycle's work is three kernels, each beside its numpy reference:
``free_response_design`` (the modes, their columns, whitened; ``free_response_design_reference``),
``free_response_moments`` (the coefficients' moments by one SVD; ``coefficient_moments``) and
``free_response_kernel`` (the rows whitened again; ``free_response_reference``), with the EWMA between them
(``free_response_variance``), called as one (``free_response_step_kernel``; ``without_free_response_reference`` its
reference, the four one after another, design note 115). As numpy calls the same work cost ~1-1.7 ms a cycle on
a loaded box, ~0.3 ms as four kernels (design note 111).
"""

from __future__ import annotations

from dataclasses import replace

import numba
import numpy as np


def carried_modes(modes: np.ndarray | None, period: float, n_harmonics: int, carry: float) -> np.ndarray:
    """The eigenvalues of ``modes`` (core.model.dynamics.free_modes) whose free response keeps at least ``carry`` of
    its amplitude over one cycle of ``period`` [s] and whose frequency is within the M = ``n_harmonics`` fitted
    harmonics (M 2 pi / T); empty where none (or ``carry`` <= 0: off)."""
    if modes is None or carry <= 0.0 or not np.isfinite(period) or period <= 0.0:
        return np.empty(0, dtype=np.complex128)
    lam = np.asarray(modes, dtype=np.complex128)
    keep = (np.exp(lam.real * period) >= carry) & (lam.imag <= n_harmonics * 2.0 * np.pi / period)
    return np.ascontiguousarray(lam[keep])


def free_response_columns(lams: np.ndarray, period: float, n_harmonics: int) -> np.ndarray:
    """(M, 2q) complex: per mode the speed harmonics of Re(c e^(lambda t)) per unit Re c and per unit Im c."""
    k = np.arange(1, n_harmonics + 1)
    cols = np.empty((n_harmonics, 2 * lams.shape[0]), dtype=np.complex128)
    for j, lam in enumerate(lams):
        i1 = (np.exp(lam * period) - 1.0) / (period * (lam - 2j * np.pi * k / period))
        i2 = (np.exp(np.conj(lam) * period) - 1.0) / (period * (np.conj(lam) - 2j * np.pi * k / period))
        cols[:, 2 * j] = i1 + i2  # Re(c e^(lambda t)) = (c e^(lambda t) + conj(c) e^(conj(lambda) t)) / 2, c = 1
        cols[:, 2 * j + 1] = 1j * (i1 - i2)  # c = i
    return cols


@numba.njit(cache=True)
def free_response_kernel(a, y, dw, s):
    """(a, y) whitened again for the random free response: the first 2M rows (real parts, imaginary parts; the rows
    after them untouched) times W = (I + G G^T)^(-1/2), G = dw diag(sqrt(s)), dw (2M, 2q) the free-response columns
    in the rows' whitened units, s (2q,) their coefficients' prior variances. G = Q R by Gram-Schmidt twice (a
    column with nothing left, below 1e-12 of its size, dropped), R R^T = V L V^T, U = Q V: W = I - U diag(1 -
    1/sqrt(1 + L)) U^T (s -> inf: the projection out of G's span; s = 0: nothing). New arrays."""
    m2, q = dw.shape
    r, p = a.shape
    a = a.copy()
    y = y.copy()
    basis = np.zeros((q, m2))
    kept = 0
    for j in range(q):
        v = dw[:, j] * np.sqrt(max(s[j], 0.0))
        size = np.sqrt(np.dot(v, v))
        for _ in range(2):
            for b in range(kept):
                v -= np.dot(basis[b], v) * basis[b]
        norm = np.sqrt(np.dot(v, v))
        if norm > 1e-12 * size and norm > 0.0:
            basis[kept] = v / norm
            kept += 1
    if kept == 0:
        return a, y
    qb = basis[:kept]  # (k, 2M), orthonormal rows
    rr = np.zeros((kept, q))  # R = Q^T G
    for j in range(q):
        g = dw[:, j] * np.sqrt(max(s[j], 0.0))
        for b in range(kept):
            rr[b, j] = np.dot(qb[b], g)
    lam, vec = np.linalg.eigh(rr @ rr.T)
    u = vec.T @ qb  # (k, 2M): U^T
    for b in range(kept):
        f = 1.0 - 1.0 / np.sqrt(1.0 + max(lam[b], 0.0))
        ub = u[b]
        for k in range(p):
            c = 0.0
            for i in range(m2):
                c += ub[i] * a[i, k]
            for i in range(m2):
                a[i, k] -= f * c * ub[i]
        c = 0.0
        for i in range(m2):
            c += ub[i] * y[i]
        for i in range(m2):
            y[i] -= f * c * ub[i]
    return a, y


def free_response_reference(a: np.ndarray, y: np.ndarray, dw: np.ndarray,
                            s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``free_response_kernel`` by numpy: the symmetric inverse square root of the full 2M x 2M covariance I + G
    G^T (eigh), applied to the first 2M rows."""
    m2 = dw.shape[0]
    g = dw * np.sqrt(np.maximum(s, 0.0))[None, :]
    w, v = np.linalg.eigh(np.eye(m2) + g @ g.T)
    root = (v / np.sqrt(w)[None, :]) @ v.T
    a, y = a.copy(), y.copy()
    a[:m2] = root @ a[:m2]
    y[:m2] = root @ y[:m2]
    return a, y


def whitened_columns(cols: np.ndarray, inv_sigma: np.ndarray, drift_col: np.ndarray | None, drift_var: float,
                     period: float) -> np.ndarray:
    """(2M, 2q) real: the free-response columns ``cols`` (M, 2q) complex in the flywheel rows' units: weighted by
    their ``inv_sigma`` (2M,) and whitened for the drift's random effect as the rows are (noise_model.noise_kernel's
    Sherman-Morrison W_d = I - c d d^T), so the free response's covariance in those rows is W_d D S D^T W_d."""
    m = cols.shape[0]
    dw = np.concatenate([cols.real, cols.imag]) * inv_sigma[:2 * m, None]
    if drift_col is not None and drift_col.shape[0] == m and drift_var > 0.0:
        d = np.concatenate([drift_col.real, drift_col.imag]) * inv_sigma[:2 * m]
        nd = float(d @ d)
        s2 = drift_var * (0.5 * period) ** 2  # as noise_kernel: speed-step variance -> drift-coefficient variance
        if nd > 0.0:
            c = (1.0 - 1.0 / np.sqrt(1.0 + s2 * nd)) / nd
            dw = dw - c * np.outer(d, d @ dw)
    return dw


def free_response_design_reference(modes: np.ndarray, period: float, carry: float, inv_sigma: np.ndarray,
                                   drift_col: np.ndarray, drift_var: float) -> np.ndarray:
    """``free_response_design`` by numpy: ``carried_modes``, ``free_response_columns``, ``whitened_columns``."""
    m = inv_sigma.shape[0] // 2
    lams = carried_modes(modes, period, m, carry)
    return whitened_columns(free_response_columns(lams, period, m), inv_sigma, drift_col, drift_var, period)


@numba.njit(cache=True)
def free_response_design(modes, period, carry, inv_sigma, drift_col, drift_var):
    """The carried modes' free-response columns in a cycle's whitened units, (2M, 2q) real: ``carried_modes``,
    ``free_response_columns`` and ``whitened_columns`` in one pass (their numpy reference). modes (n,) complex: the
    chain's eigenvalues (empty: none); inv_sigma (2M,): the flywheel rows' weights; drift_col (M,) complex: the
    drift's speed column (empty: the drift not a random effect); drift_var: its speed-step variance [rad^2/s^2].
    q = 0 where no mode is carried (or ``carry`` <= 0: off)."""
    m = inv_sigma.shape[0] // 2
    n_keep = 0
    keep = np.zeros(modes.shape[0], dtype=np.bool_)
    if carry > 0.0 and np.isfinite(period) and period > 0.0:
        for j in range(modes.shape[0]):
            lam = modes[j]
            if np.exp(lam.real * period) >= carry and lam.imag <= m * 2.0 * np.pi / period:
                keep[j] = True
                n_keep += 1
    dw = np.empty((2 * m, 2 * n_keep))
    col = 0
    for j in range(modes.shape[0]):
        if not keep[j]:
            continue
        lam = modes[j]
        e1 = np.exp(lam * period) - 1.0
        e2 = np.exp(np.conj(lam) * period) - 1.0
        for i in range(m):
            w = 2.0 * np.pi * (i + 1) / period
            i1 = e1 / (period * (lam - 1j * w))
            i2 = e2 / (period * (np.conj(lam) - 1j * w))
            re, im = i1 + i2, 1j * (i1 - i2)
            dw[i, col], dw[m + i, col] = re.real * inv_sigma[i], re.imag * inv_sigma[m + i]
            dw[i, col + 1], dw[m + i, col + 1] = im.real * inv_sigma[i], im.imag * inv_sigma[m + i]
        col += 2
    if drift_col.shape[0] == m and drift_var > 0.0 and n_keep > 0:
        d = np.empty(2 * m)
        for i in range(m):
            d[i] = drift_col[i].real * inv_sigma[i]
            d[m + i] = drift_col[i].imag * inv_sigma[m + i]
        nd = np.dot(d, d)
        s2 = drift_var * (0.5 * period) ** 2  # as noise_kernel: speed-step variance -> drift-coefficient variance
        if nd > 0.0:
            c = (1.0 - 1.0 / np.sqrt(1.0 + s2 * nd)) / nd
            for k in range(2 * n_keep):
                f = 0.0
                for i in range(2 * m):
                    f += d[i] * dw[i, k]
                for i in range(2 * m):
                    dw[i, k] -= c * f * d[i]
    return dw


@numba.njit(cache=True)
def free_response_moments(dw, a, y, params):
    """``coefficient_moments`` (its numpy reference) by one SVD of dw (2M, 2q), on the residual at ``params`` of the
    first 2M rows of (a, y): b = V S^-1 U^T r and diag (D^T D)^+ = sum_j V_j^2 / S_j^2 over the singular values
    above lstsq's cut-off (eps max(2M, 2q) S_max; the reference's pinv of D^T D cuts S^2 at 1e-15 S_max^2, the same
    columns unless one is within 3e-8 of the others' span). Per mode (q,): coefficient^2 and its noise part."""
    m2, q2 = dw.shape
    resid = y[:m2] - a[:m2] @ params
    u, s, vt = np.linalg.svd(dw, full_matrices=False)
    cut = np.finfo(np.float64).eps * max(m2, q2) * s[0]
    b = np.zeros(q2)
    inv_n = np.zeros(q2)  # diag (D^T D)^+
    rank = 0
    for j in range(s.shape[0]):
        if s[j] <= cut:
            continue
        rank += 1
        uj = np.dot(u[:, j], resid) / s[j]
        for k in range(q2):
            b[k] += vt[j, k] * uj
            inv_n[k] += vt[j, k] ** 2 / s[j] ** 2
    left = resid - dw @ b
    scale = np.dot(left, left) / max(m2 - rank, 1)
    q = q2 // 2
    coef_sq, noise = np.empty(q), np.empty(q)
    for j in range(q):
        coef_sq[j] = 0.5 * (b[2 * j] ** 2 + b[2 * j + 1] ** 2)
        noise[j] = 0.5 * scale * (inv_n[2 * j] + inv_n[2 * j + 1])
    return coef_sq, noise


def coefficient_moments(dw: np.ndarray, resid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(``free_response_moments``' numpy reference.) One cycle's GLS free-response coefficients on its whitened residual
    ``resid`` (2M,) (the rows at the previous estimate): per mode (q,) the mean square of its two coefficients and the
    part of it the noise gives, (D^T D)^+ scaled by what the residual has left after them (its mean square per degree of
    freedom: the rows' variance already holds the free response, so a whitened row's noise is below 1 where it is
    large)."""
    b, _, rank, _ = np.linalg.lstsq(dw, resid, rcond=None)
    dof = max(dw.shape[0] - rank, 1)
    scale = float(np.sum((resid - dw @ b) ** 2)) / dof
    noise = scale * np.diag(np.linalg.pinv(dw.T @ dw))
    return 0.5 * (b[0::2] ** 2 + b[1::2] ** 2), 0.5 * (noise[0::2] + noise[1::2])


def free_response_variance(prev, coef_sq: np.ndarray, noise: np.ndarray, memory: float) -> tuple:
    """One cycle's coefficient moments folded into the free-response EWMA of the statistics ``prev``
    (noise_model.ResidualStats; ``memory``; restarted when the carried modes' count changes): (coefficient^2 EWMA,
    noise EWMA, cycles in them, the prior variance per mode they give, max(EWMA coefficient^2 - EWMA noise, 0))."""
    q = coef_sq.shape[0]
    if prev.free_coef_sq is None or prev.free_coef_sq.shape[0] != q:
        n, sq, nz = 1, coef_sq, noise
    else:
        n = prev.free_count + 1
        g = max(1.0 - memory, 1.0 / n)
        sq = prev.free_coef_sq + g * (coef_sq - prev.free_coef_sq)
        nz = prev.free_noise + g * (noise - prev.free_noise)
    return sq, nz, n, np.maximum(sq - nz, 0.0)


@numba.njit(cache=True)
def free_response_step_kernel(modes, drift, white, prev, settings):
    """``without_free_response_reference``'s numbers in one call: modes (n,) complex; drift (the drift column (M,)
    complex, empty: none); white = (a, y, inv_sigma) the whitened rows, inv_sigma's first 2M the flywheel's; prev =
    (params (P,), the statistics' free_coef_sq and free_noise (q,), empty: none); settings = (period, carry,
    drift_var, memory, the statistics' free_count, M the harmonics). Returns (q: the carried modes, 0: nothing done;
    a, y; the EWMA of coefficient^2 and of noise, the cycles in them)."""
    a, y, inv_sigma = white
    params, prev_sq, prev_nz = prev
    period, carry, drift_var, memory = settings[0], settings[1], settings[2], settings[3]
    dw = free_response_design(modes, period, carry, inv_sigma[:2 * int(settings[5])], drift, drift_var)
    q = dw.shape[1] // 2
    if q == 0:
        return 0, a, y, prev_sq, prev_nz, 0
    coef_sq, noise = free_response_moments(dw, a, y, params)
    if prev_sq.shape[0] != q:  # free_response_variance: restarted when the carried modes' count changes
        n, sq, nz = 1, coef_sq, noise
    else:
        n = int(settings[4]) + 1
        g = max(1.0 - memory, 1.0 / n)
        sq, nz = np.empty(q), np.empty(q)
        for j in range(q):
            sq[j] = prev_sq[j] + g * (coef_sq[j] - prev_sq[j])
            nz[j] = prev_nz[j] + g * (noise[j] - prev_nz[j])
    var2 = np.empty(2 * q)  # np.repeat(max(sq - nz, 0), 2); NaN stays NaN as np.maximum keeps it
    for j in range(q):
        v = sq[j] - nz[j]
        var2[2 * j] = var2[2 * j + 1] = 0.0 if v < 0.0 else v
    a, y = free_response_kernel(a, y, dw, var2)
    return q, a, y, sq, nz, n


def without_free_response(white, prev, params: np.ndarray, modes: np.ndarray | None, period: float, carry: float,
                          drift_var: float, memory: float):
    """``without_free_response_reference``'s answer from one ``free_response_step_kernel`` call."""
    if modes is None or carry <= 0.0:
        return white
    m = white.freq.shape[0]
    drift = white.drift_col if white.drift_col is not None else np.empty(0, dtype=np.complex128)
    empty = np.empty(0)
    sq0 = prev.free_coef_sq if prev.free_coef_sq is not None else empty
    nz0 = prev.free_noise if prev.free_noise is not None else empty
    if white.inv_sigma.shape[0] < 2 * m or drift.shape[0] not in (0, m):
        return without_free_response_reference(white, prev, params, modes, period, carry, drift_var, memory)
    q, a, y, sq, nz, n = free_response_step_kernel(
        np.asarray(modes, dtype=np.complex128), drift, (white.a, white.y, white.inv_sigma),
        (np.asarray(params, dtype=np.float64), sq0, nz0),
        np.array((period, carry, drift_var, memory, prev.free_count, m), dtype=np.float64))
    if q == 0:
        return white
    return replace(white, a=a, y=y, stats=replace(white.stats, free_coef_sq=sq, free_noise=nz, free_count=n))


def without_free_response_reference(white, prev, params: np.ndarray, modes: np.ndarray | None, period: float,
                                    carry: float, drift_var: float, memory: float):
    """``white`` (noise_model.WhitenedCycle) with the carried modes' free response a random effect of its flywheel
    rows: each mode's two coefficients of prior variance from the data (the EWMA in the statistics ``prev``, the
    ones before this cycle, with this cycle's folded in, as the drift's step variance is), the rows whitened again
    by (I + D S D^T)^(-1/2). Itself where no mode is carried."""
    if modes is None or carry <= 0.0:
        return white
    m = white.freq.shape[0]
    drift = white.drift_col if white.drift_col is not None else np.empty(0, dtype=np.complex128)
    dw = free_response_design(modes, period, carry, white.inv_sigma[:2 * m], drift, drift_var)
    if dw.shape[1] == 0:
        return white
    coef_sq, noise = free_response_moments(dw, white.a, white.y, params)
    sq, nz, n, var = free_response_variance(prev, coef_sq, noise, memory)
    a, y = free_response_kernel(white.a, white.y, dw, np.repeat(var, 2))
    return replace(white, a=a, y=y, stats=replace(white.stats, free_coef_sq=sq, free_noise=nz, free_count=n))
