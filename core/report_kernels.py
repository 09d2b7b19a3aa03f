"""Numba kernel of the result's speed series (core.cycle_report): the speed residual, the ripple power and both
inverse series on the time grid in one call, with the cosine/sine tables of the grid kept per (M, n_t).

The plain-numpy reference (speed_residual + speed_power + harmonic_series by irfft) is in
tests/core/test_report_kernels.py. The direct sums differ from the inverse FFT by rounding only (~1e-16 of the
speed); everything else is bit for bit the code it replaces.
"""

from __future__ import annotations

import numba
import numpy as np

from core.monitor_kernels import speed_power, speed_residual

_TABLES: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}


def trig_tables(m: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of 2 pi (h k mod n) / n for harmonics h = 1..m and samples k = 0..n-1, (m, n) each, read-only,
    one pair per size (harmonic_series' convention: x_k = sum_h Re(X_h exp(i 2 pi h k / n)))."""
    key = (m, n)
    tab = _TABLES.get(key)
    if tab is None:
        h = np.arange(1, m + 1)[:, None]
        k = np.arange(n)[None, :]
        ang = (2.0 * np.pi / n) * ((h * k) % n)
        tab = (np.cos(ang), np.sin(ang))
        for t in tab:
            t.flags.writeable = False
        _TABLES[key] = tab
    return tab


@numba.njit(cache=True)
def speed_series(design, target, theta, p_f, drift, use_drift, freq, harmonics, omega_fly, cos_t, sin_t, resid,
                 extra):
    """Residual harmonics resid (M,) complex (measured - model, this cycle's best-fitting drift taken out if
    ``use_drift``), extra[0] = measured speed omega_fly (n_t,) minus the fitted tooth-pattern part
    design[:, p_f:] @ theta[p_f:] and extra[1] = that minus the residual (the model speed), both on the time grid.
    Returns (sum |resid|^2, sum |i freq harmonics|^2), each in numpy's pairwise order."""
    m = design.shape[0]
    series = np.empty((2, m), dtype=np.complex128)
    resid_sq = speed_residual(design, target, theta, p_f, drift, use_drift, series)
    power = speed_power(freq, harmonics)
    n = omega_fly.shape[0]
    pat = np.zeros(n)
    res = np.zeros(n)
    for h in range(m):
        pr = series[0, h].real
        pi = series[0, h].imag
        rr = series[1, h].real
        ri = series[1, h].imag
        for k in range(n):
            c = cos_t[h, k]
            s = sin_t[h, k]
            pat[k] += pr * c - pi * s
            res[k] += rr * c - ri * s
    for h in range(m):
        resid[h] = series[1, h]
    for k in range(n):
        v = omega_fly[k] - pat[k]
        extra[0, k] = v
        extra[1, k] = v - res[k]
    return resid_sq, power
