"""The drive train's free response carried into a cycle's window, taken out of its speed equations (issue 29,
design note 105).

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

Each carried mode's free response is a free unknown of the cycle (its two real amplitudes): its columns, the speed
harmonics k = 1..M of Re(c e^(lambda t)) over the window t in [0, T),

    c I_k(lambda) + conj(c) I_k(conj(lambda)),   I_k(l) = (e^(l T) - 1) / (T (l - i k 2 pi / T))

(the monitor's harmonics: angle Re(h e^(+i k w t)), w = 2 pi / T, speed i k w h; the factor common to every k
does not matter to a projection), whitened like the rows, are projected out of the flywheel's whitened rows and
targets (a random effect of unbounded variance, as ``fit_drift`` does for the drift). What the equations lose is
what those two columns could explain; they keep what is orthogonal to them.

``carried_modes`` chooses the modes: Im lambda at most the highest fitted harmonic's frequency and |e^(lambda T)| >=
``carry`` (MonitorConfig.free_response_carry; 0, off, by default: note 105). One kernel (``free_response_kernel``), its numpy reference
``free_response_reference``.
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
def free_response_kernel(a, y, inv_sigma, cols):
    """(a, y) with the whitened columns ``cols`` (M, 2q) complex projected out of their first 2M rows (real parts,
    imaginary parts; the rows after them untouched): Gram-Schmidt twice on the 2q whitened columns, a column with
    nothing left (below 1e-12 of its size) dropped. New arrays."""
    m, q = cols.shape
    r, p = a.shape
    a = a.copy()
    y = y.copy()
    basis = np.zeros((q, 2 * m))
    kept = 0
    for j in range(q):
        v = np.empty(2 * m)
        for i in range(m):
            v[i] = cols[i, j].real * inv_sigma[i]
            v[m + i] = cols[i, j].imag * inv_sigma[m + i]
        size = np.sqrt(np.dot(v, v))
        for _ in range(2):
            for b in range(kept):
                c = np.dot(basis[b], v)
                for i in range(2 * m):
                    v[i] -= c * basis[b, i]
        norm = np.sqrt(np.dot(v, v))
        if norm > 1e-12 * size and norm > 0.0:
            for i in range(2 * m):
                basis[kept, i] = v[i] / norm
            kept += 1
    for b in range(kept):
        u = basis[b]
        for k in range(p):
            c = 0.0
            for i in range(2 * m):
                c += u[i] * a[i, k]
            for i in range(2 * m):
                a[i, k] -= c * u[i]
        c = 0.0
        for i in range(2 * m):
            c += u[i] * y[i]
        for i in range(2 * m):
            y[i] -= c * u[i]
    return a, y


def free_response_reference(a: np.ndarray, y: np.ndarray, inv_sigma: np.ndarray,
                            cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``free_response_kernel`` by numpy: the orthogonal projector onto the whitened columns' complement (SVD rank
    at 1e-12), applied to the first 2M rows."""
    m = cols.shape[0]
    fw = np.concatenate([cols.real, cols.imag]) * inv_sigma[:2 * m, None]
    u, s, _ = np.linalg.svd(fw, full_matrices=False)
    u = u[:, s > 1e-12 * s.max()] if s.size and s.max() > 0.0 else u[:, :0]
    a, y = a.copy(), y.copy()
    a[:2 * m] -= u @ (u.T @ a[:2 * m])
    y[:2 * m] -= u @ (u.T @ y[:2 * m])
    return a, y


def without_free_response(white, modes: np.ndarray | None, period: float, carry: float):
    """``white`` (core.monitor.identify.noise_model.WhitenedCycle) with the carried modes' free response projected
    out of its flywheel rows (itself where no mode is carried)."""
    m = white.freq.shape[0]
    lams = carried_modes(modes, period, m, carry)
    if lams.shape[0] == 0:
        return white
    a, y = free_response_kernel(white.a, white.y, white.inv_sigma, free_response_columns(lams, period, m))
    return replace(white, a=a, y=y)
