"""Numba kernel of one cycle's noise model and whitened rows (core.monitor.identify.noise_model.whitened_rows). The numpy
reference is ``whitened_rows_reference`` in tests/core/test_noise_model.py."""

from __future__ import annotations

import math

import numba
import numpy as np

# the cycle's scalars and the settings, one float64 vector (a typed record costs ~4x more to build and pass per
# cycle); COUNT and USE_DRIFT hold an integer and a flag as floats
NOISE_FIELDS = (
    "omega",  # mean speed of the cycle [rad/s]
    "period",  # cycle duration [s]
    "residual_rms",  # tooth-fit residual [rad]
    "n_edges",  # tooth edges in the fit
    "balance",  # mean balance T_fM [N m] (NaN: no load measurement)
    "t_i",  # total indicated mean torque [N m]
    "drift_var",  # variance of the cycle-to-cycle mean-speed step [rad^2/s^2]
    "balance_mean",  # residual statistics of the balance row before this cycle
    "balance_var",
    "count",  # cycles in the statistics before this cycle
    "memory",  # EWMA factor of the statistics
    "model_rel_error",  # repeatable model error of a speed harmonic, relative
    "sys_balance",  # repeatable-error variance of the balance row [N^2 m^2]
    "use_drift",  # 1.0: this cycle's drift is a random effect
)
(OMEGA, PERIOD, RESIDUAL_RMS, N_EDGES, BALANCE, T_I, DRIFT_VAR, BALANCE_MEAN, BALANCE_VAR, COUNT, MEMORY,
 MODEL_REL_ERROR, SYS_BALANCE, USE_DRIFT) = range(len(NOISE_FIELDS))


@numba.njit(cache=True)
def _abs2(z):
    return z.real * z.real + z.imag * z.imag


@numba.njit(cache=True)
def noise_kernel(design, target, mean_row, params, drift_harm, harmonics, prev_mean, prev_var, rec):
    """design (M, P) complex, target (M,) complex, mean_row (P,), params (P,) the previous estimate, drift_harm (M,)
    complex: the drift pattern's angle harmonics, harmonics (M,) complex: the fitted angle harmonics, prev_mean (M,)
    complex and prev_var (M,): the statistics before; rec (len(NOISE_FIELDS),): the cycle's scalars and settings.

    Returns (mean, var, balance_mean, balance_var) updated statistics, (a (2M+1, P), y, inv_sigma, sys_var) the
    whitened rows, freq (M,) and drift_col (M,) complex = i freq drift_harm."""
    m, p = design.shape
    freq = np.empty(m)
    drift_col = np.empty(m, dtype=np.complex128)
    for i in range(m):
        freq[i] = 0.5 * rec[OMEGA] * (i + 1)
        drift_col[i] = 1j * freq[i] * drift_harm[i]
    resid = np.empty(m, dtype=np.complex128)
    for i in range(m):
        s = 0j
        for j in range(p):
            s += design[i, j] * params[j]
        resid[i] = target[i] - s
    if rec[USE_DRIFT] != 0.0:  # the residual without this cycle's best-fitting drift
        dd = 0.0
        dr = 0.0
        for i in range(m):
            dd += _abs2(drift_col[i])
            dr += drift_col[i].real * resid[i].real + drift_col[i].imag * resid[i].imag
        f = dr / max(dd, 1e-300)
        for i in range(m):
            resid[i] = resid[i] - drift_col[i] * f
    balance = rec[BALANCE]
    bal_resid = 0.0
    if math.isfinite(balance):
        bal_resid = balance - np.dot(mean_row, params)
    # the EWMA statistics (core.monitor.identify.accumulate.ResidualStats.update)
    n = int(rec[COUNT]) + 1
    g = max(1.0 - rec[MEMORY], 1.0 / n)
    mean = np.empty(m, dtype=np.complex128)
    var = np.empty(m)
    for i in range(m):
        d = resid[i] - prev_mean[i]
        mean[i] = prev_mean[i] + g * d
        var[i] = (1.0 - g) * (prev_var[i] + g * 0.5 * _abs2(d)) if n > 1 else 0.5 * _abs2(resid[i])
    db = bal_resid - rec[BALANCE_MEAN]
    bal_mean = rec[BALANCE_MEAN] + g * db
    bal_var = (1.0 - g) * (rec[BALANCE_VAR] + g * db * db) if n > 1 else bal_resid**2
    # whitening: the variance, floored by the tooth-fit residual's share
    sigma = np.empty(m)
    for i in range(m):
        floor = freq[i] ** 2 * 2.0 * rec[RESIDUAL_RMS]**2 / rec[N_EDGES] + 1e-12
        sigma[i] = math.sqrt(max(var[i], floor))
    if n > 2:
        sigma_bal = math.sqrt(max(bal_var, (0.002 * rec[T_I]) ** 2, 1e-6))
    else:  # too few cycles for a variance: 5 % of the indicated torque
        sigma_bal = 0.05 * abs(rec[T_I])
    a = np.empty((2 * m + 1, p))
    y = np.empty(2 * m + 1)
    for i in range(m):
        for j in range(p):
            a[i, j] = design[i, j].real / sigma[i]
            a[m + i, j] = design[i, j].imag / sigma[i]
        y[i] = target[i].real / sigma[i]
        y[m + i] = target[i].imag / sigma[i]
    if rec[USE_DRIFT] != 0.0 and rec[DRIFT_VAR] > 0:  # the drift as a random effect (Sherman-Morrison)
        dw = np.empty(2 * m)
        for i in range(m):
            dw[i] = drift_col[i].real / sigma[i]
            dw[m + i] = drift_col[i].imag / sigma[i]
        nd = np.dot(dw, dw)
        s2 = rec[DRIFT_VAR] * (0.5 * rec[PERIOD]) ** 2  # speed-step variance -> drift-coefficient variance
        if nd > 0:
            c = (1.0 - 1.0 / math.sqrt(1.0 + s2 * nd)) / nd
            v = np.zeros(p)
            for i in range(2 * m):
                for j in range(p):
                    v[j] += dw[i] * a[i, j]
            vy = np.dot(dw, y[:2 * m])
            for i in range(2 * m):
                for j in range(p):
                    a[i, j] -= c * dw[i] * v[j]
                y[i] -= c * dw[i] * vy
    for j in range(p):  # the mean balance (a zero row without a load measurement)
        a[2 * m, j] = mean_row[j] / sigma_bal if math.isfinite(balance) else 0.0
    y[2 * m] = balance / sigma_bal if math.isfinite(balance) else 0.0
    inv_sigma = np.empty(2 * m + 1)
    sys_var = np.empty(2 * m + 1)
    for i in range(m):
        inv_sigma[i] = 1.0 / sigma[i]
        inv_sigma[m + i] = 1.0 / sigma[i]
        e = rec[MODEL_REL_ERROR] * freq[i] * math.sqrt(_abs2(harmonics[i]))  # of the speed harmonic's size
        v2 = max(_abs2(mean[i]), e * e) / 2.0
        sys_var[i] = v2
        sys_var[m + i] = v2
    inv_sigma[2 * m] = 1.0 / sigma_bal
    sys_var[2 * m] = rec[SYS_BALANCE]
    return mean, var, bal_mean, bal_var, a, y, inv_sigma, sys_var, freq, drift_col
