"""The noise model of one cycle's identification equations and their whitening (physics.md §12.3, design.md §4 step 5).

The residual of the speed harmonics at the previous estimate (without this cycle's best-fitting drift) updates the
per-harmonic statistics (core.monitor.accumulate.ResidualStats): their variance whitens the rows (floored by the
tooth-fit residual), their persistent mean is the systematic-error budget. This cycle's linear speed drift is a
random effect of prior variance s^2 (never accumulated): the rows are whitened with (I + s^2 d d^T)^-1 = W^T W,
W = I - c d d^T, c ||d||^2 = 1 - 1/sqrt(1 + s^2 ||d||^2) (Sherman-Morrison), so a large drift projects its column
out and a small one leaves the order-0.5 information in place. The last row is the mean balance (zero when there is
no load measurement). Plain numpy: (2M+1, P) arrays of a few thousand entries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from frictionwatch.core.monitor.accumulate import ResidualStats
from frictionwatch.core.monitor.flywheel import FlywheelMotion
from frictionwatch.core.monitor.identify import CycleRows


@dataclass(frozen=True)
class NoiseSettings:
    """memory: EWMA factor of the residual statistics; model_rel_error: repeatable model error of a speed harmonic
    relative to its size; use_drift: the cycle's drift is a random effect; sys_balance: variance of the repeatable
    error of the mean-balance row [N^2 m^2]."""

    memory: float
    model_rel_error: float
    use_drift: bool
    sys_balance: float


@dataclass(frozen=True)
class WhitenedCycle:
    """One cycle's whitened equations: a (2M+1, P), y (2M+1,) (real parts, imaginary parts, mean balance), the raw
    rows' weights inv_sigma (2M+1,) and repeatable-error variances sys_var (2M+1,), the updated statistics, the
    harmonic frequencies freq (M,) [rad/s] and the drift's speed column drift_col (M,) complex (None: not used)."""

    stats: ResidualStats
    a: np.ndarray
    y: np.ndarray
    inv_sigma: np.ndarray
    sys_var: np.ndarray
    freq: np.ndarray
    drift_col: np.ndarray | None


def whitened_rows(settings: NoiseSettings, stats: ResidualStats, fly: FlywheelMotion, rows: CycleRows,
                  params: np.ndarray, balance: float, t_i: float, drift_var: float) -> WhitenedCycle:
    """Noise model and whitened rows of one cycle. params (P,): the previous estimate; balance: this cycle's mean
    balance T_fM [N m] (NaN: no load measurement); t_i: total indicated mean torque [N m]; drift_var: variance of
    the cycle-to-cycle mean-speed step [rad^2/s^2]."""
    design = rows.design
    m = design.shape[0]
    if fly.harmonics.shape[0] != m or stats.mean.shape[0] != m:
        raise ValueError(f"the tooth fit ({fly.harmonics.shape[0]}), statistics ({stats.mean.shape[0]}) and rows "
                         f"({m}) must have the same harmonic count")
    freq = fly.freq
    resid = rows.target - design @ params
    drift_col = 1j * freq * fly.pattern_harmonics[:, -1] if settings.use_drift else None
    if drift_col is not None:  # the residual without this cycle's best-fitting drift
        dd = float(np.sum(np.abs(drift_col) ** 2))
        resid = resid - drift_col * (float(np.sum(drift_col.real * resid.real + drift_col.imag * resid.imag))
                                     / max(dd, 1e-300))
    bal_resid = balance - float(rows.mean_row @ params) if math.isfinite(balance) else 0.0
    new_stats = stats.update(resid, bal_resid, settings.memory)
    floor = freq**2 * 2.0 * fly.residual_rms**2 / fly.n_edges + 1e-12  # the tooth-fit residual's share
    sigma = np.sqrt(np.maximum(new_stats.var, floor))
    if new_stats.count > 2:
        sigma_bal = math.sqrt(max(new_stats.balance_var, (0.002 * t_i) ** 2, 1e-6))
    else:  # too few cycles for a variance: 5 % of the indicated torque
        sigma_bal = 0.05 * abs(t_i)
    inv2 = np.concatenate([1.0 / sigma, 1.0 / sigma])
    a = np.empty((2 * m + 1, design.shape[1]))
    y = np.empty(2 * m + 1)
    a[:m] = design.real / sigma[:, None]
    a[m:2 * m] = design.imag / sigma[:, None]
    y[:m] = rows.target.real / sigma
    y[m:2 * m] = rows.target.imag / sigma
    if drift_col is not None and drift_var > 0:
        dw = np.concatenate([drift_col.real, drift_col.imag]) / np.concatenate([sigma, sigma])
        nd = float(dw @ dw)
        s2 = drift_var * (0.5 * fly.period) ** 2  # speed step variance -> drift-coefficient variance
        if nd > 0:
            c = (1.0 - 1.0 / math.sqrt(1.0 + s2 * nd)) / nd
            a[:2 * m] -= c * np.outer(dw, dw @ a[:2 * m])
            y[:2 * m] -= c * dw * float(dw @ y[:2 * m])
    if math.isfinite(balance):
        a[2 * m] = rows.mean_row / sigma_bal
        y[2 * m] = balance / sigma_bal
    else:  # no load: the mean is not measured this cycle; the row carries nothing
        a[2 * m] = 0.0
        y[2 * m] = 0.0
    e = settings.model_rel_error * np.abs(freq * fly.harmonics)  # |i freq harmonics|: the speed harmonics' size
    v2 = np.maximum(np.abs(new_stats.mean) ** 2, e * e) / 2.0
    inv_sigma = np.append(inv2, 1.0 / sigma_bal)
    sys_var = np.concatenate([v2, v2, [settings.sys_balance]])
    return WhitenedCycle(stats=new_stats, a=a, y=y, inv_sigma=inv_sigma, sys_var=sys_var, freq=freq,
                         drift_col=drift_col)
