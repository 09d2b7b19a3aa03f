"""The noise model of one cycle's identification equations and their whitening (physics.md §12.3, design.md §4 step 5).

The residual of the speed harmonics at the previous estimate (without this cycle's best-fitting drift) updates the
per-harmonic statistics (core.monitor.identify.accumulate.ResidualStats): their variance whitens the rows (floored by the
tooth-fit residual), their persistent mean is the systematic-error budget. This cycle's linear speed drift is a
random effect of prior variance s^2 (never accumulated): the rows are whitened with (I + s^2 d d^T)^-1 = W^T W,
W = I - c d d^T, c ||d||^2 = 1 - 1/sqrt(1 + s^2 ||d||^2) (Sherman-Morrison), so a large drift projects its column
out and a small one leaves the order-0.5 information in place. The last row is the mean balance (zero when there is
no load measurement). One kernel (core.monitor.identify.noise_model_kernels).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from frictionwatch.core.monitor.identify.accumulate import ResidualStats
from frictionwatch.core.monitor.identify.layout import CycleRows
from frictionwatch.core.monitor.identify.noise_model_kernels import noise_kernel
from frictionwatch.core.monitor.teeth.flywheel import FlywheelMotion


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
    m = rows.design.shape[0]
    if fly.harmonics.shape[0] != m or stats.mean.shape[0] != m or np.shape(params) != (rows.design.shape[1],):
        raise ValueError(f"the tooth fit ({fly.harmonics.shape[0]}), statistics ({stats.mean.shape[0]}) and rows "
                         f"({m}) must have the same harmonic count, params one value per column")
    rec = np.array((fly.omega_mean, fly.period, fly.residual_rms, fly.n_edges, balance, t_i, drift_var,
                    stats.balance_mean, stats.balance_var, stats.count, settings.memory, settings.model_rel_error,
                    settings.sys_balance, settings.use_drift), dtype=np.float64)  # noise_model_kernels.NOISE_FIELDS
    # the statistics' and rows' arrays come from kernels (C-contiguous; another layout is another specialisation);
    # the drift pattern is a column of the tooth patterns, copied to be contiguous
    mean, var, bal_mean, bal_var, a, y, inv_sigma, sys_var, freq, drift_col = noise_kernel(
        rows.design, rows.target, rows.mean_row, np.asarray(params, dtype=np.float64),
        np.ascontiguousarray(fly.pattern_harmonics[:, -1], dtype=np.complex128), fly.harmonics, stats.mean, stats.var,
        rec)
    new_stats = ResidualStats(mean=mean, var=var, balance_mean=float(bal_mean), balance_var=float(bal_var),
                              count=stats.count + 1)
    return WhitenedCycle(stats=new_stats, a=a, y=y, inv_sigma=inv_sigma, sys_var=sys_var, freq=freq,
                         drift_col=drift_col if settings.use_drift else None)
