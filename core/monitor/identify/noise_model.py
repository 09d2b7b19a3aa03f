"""The noise model of one cycle's identification equations and their whitening (physics.md §12.3, design.md §4 step 5).

The residual of the speed harmonics at the previous estimate (without this cycle's best-fitting drift) updates the
per-harmonic statistics (core.monitor.identify.noise_model.ResidualStats): their variance whitens the rows (floored by the
tooth-fit residual), their persistent mean is the systematic-error budget. This cycle's linear speed drift is a
random effect of prior variance s^2 (never accumulated): the rows are whitened with (I + s^2 d d^T)^-1 = W^T W,
W = I - c d d^T, c ||d||^2 = 1 - 1/sqrt(1 + s^2 ||d||^2) (Sherman-Morrison), so a large drift projects its column
out and a small one leaves the order-0.5 information in place. The last row is the mean balance (zero when there is
no load measurement). One kernel (``noise_kernel`` below, called by ``whitened_rows``); its numpy reference is
``noise_rows_reference`` in tests/core/test_monitor_kernels.py.

The second wheel's speed equations, whitened, for the joint fit of both wheels (issue 29 item 1).

The harmonic balance gives them (core.monitor.balance.harmonic_balance, ``free_rows``): the measured free-end speed
harmonics minus the modelled ones, affine in the same friction parameters through the chain's transfer to the free
end. Only the **half orders** enter (harmonics m odd, order m/2 = 0.5, 1.5, ...): a tooth-spacing error is fixed in
angle and repeats every revolution, so it has integer orders only; at half orders the second wheel needs no
tooth-error nuisances of its own (its out-of-band pattern is learnt and removed by its tooth fit, its in-band
pattern would need nuisance columns at integer orders: not carried yet, so those rows are left out).

The noise model is the flywheel's (core.monitor.identify.noise_model.noise_kernel, written again here in numpy
for the half-order subset): per row the EWMA variance of the residual about its EWMA mean (the residual without the
cycle's best-fitting speed drift), floored by the tooth fit's own residual w^2 2 rms^2 / n_edges; the cycle's speed
drift as a random effect of the flywheel's step variance (Sherman-Morrison on the whitened rows: the drift pattern
q(u) leaks into order 0.5 and its neighbours, and a load ramp makes it large); the repeatable part v (EWMA mean or
``model_rel_error`` of the measured harmonic's size, whichever is larger) as the systematic variance, and in the
weight: a row is whitened by var + n v, n the cycles its statistics have seen, so the free end's repeatable error
limits what its rows add instead of growing unweighted in the systematic covariance (design note 35). A cycle
without the second wheel gives zero rows (nothing learnt, nothing assumed). Plain numpy (a dozen rows).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numba
import numpy as np
from frictionwatch.core.monitor.identify.parameters import CycleRows
from frictionwatch.core.monitor.teeth.flywheel import FlywheelMotion


@dataclass(frozen=True)
class ResidualStats:
    """Per-row residual statistics across cycles (EWMA): mean (persistent part) and variance about it (random part).

    Used as the noise model (whitening) and the systematic-error budget. Rows are complex harmonics (M,) plus the
    mean balance as a real scalar."""

    mean: np.ndarray  # (M,) complex
    var: np.ndarray  # (M,) per real component
    balance_mean: float
    balance_var: float
    count: int
    # the carried modes' free response (core.monitor.identify.free_response; None: none carried): per mode the EWMA
    # of each cycle's GLS coefficient squared and of its noise, their difference the mode's prior variance
    free_coef_sq: np.ndarray | None = None
    free_noise: np.ndarray | None = None
    free_count: int = 0

    @staticmethod
    def empty(n_harmonics: int) -> ResidualStats:
        return ResidualStats(np.zeros(n_harmonics, complex), np.zeros(n_harmonics), 0.0, 0.0, 0)

    def update(self, resid: np.ndarray, balance_resid: float, memory: float) -> ResidualStats:
        """Fold in one cycle's residuals; ``memory`` is the EWMA factor (e.g. 1 - 1/50); the first cycles average."""
        n = self.count + 1
        g = max(1.0 - memory, 1.0 / n)
        d = resid - self.mean
        db = balance_resid - self.balance_mean
        return replace(
            self,
            mean=self.mean + g * d,
            var=(1.0 - g) * (self.var + g * 0.5 * np.abs(d) ** 2) if n > 1 else 0.5 * np.abs(resid) ** 2,
            balance_mean=self.balance_mean + g * db,
            balance_var=(1.0 - g) * (self.balance_var + g * db * db) if n > 1 else balance_resid**2,
            count=n,
        )

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
    # the EWMA statistics (core.monitor.identify.noise_model.ResidualStats.update)
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
                    settings.sys_balance, settings.use_drift), dtype=np.float64)  # NOISE_FIELDS
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


def half_order_rows(m: int, max_order: float = np.inf) -> np.ndarray:
    """Indices j of the harmonics m = j + 1 that are half orders (j even), up to order ``max_order``."""
    j = np.arange(0, m, 2)
    return j[(j + 1) / 2.0 <= max_order]


def free_end_whitened(stats: ResidualStats | None, design: np.ndarray, target: np.ndarray, params: np.ndarray,
                      harmonics: np.ndarray, fit: tuple[float, float, float, int], drift: tuple[np.ndarray | None, float],
                      noise: tuple[float, float], max_order: float = np.inf
                      ) -> tuple[ResidualStats, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(stats, a (2H, P), y (2H,), inv_sigma (2H,), sys_var (2H,)) of the H half-order rows of one cycle.

    design (M, P) complex, target (M,) complex: the free-end speed equations; params (P,) the previous estimate;
    harmonics (M,) complex [rad]: the free end's fitted angle harmonics; fit = (omega [rad/s], period [s],
    residual_rms [rad], n_edges) of its tooth fit; drift = (its drift pattern's harmonics (M,) complex [rad] or None,
    the variance of the cycle-to-cycle mean-speed step [rad^2/s^2]); noise = (memory of the statistics,
    model_rel_error); stats: the rows' residual statistics before this cycle (None: none yet); max_order: the
    highest half order taken (MonitorConfig.second_wheel_max_order)."""
    omega, period, residual_rms, n_edges = fit
    drift_harm, drift_var = drift
    memory, model_rel_error = noise
    rows = half_order_rows(design.shape[0], max_order)
    d, t = design[rows], target[rows]
    if stats is None or stats.mean.shape[0] != rows.size:
        stats = ResidualStats.empty(rows.size)
    freq = 0.5 * omega * (rows + 1)
    resid = t - d @ params
    col = None if drift_harm is None else 1j * freq * drift_harm[rows]
    if col is not None:  # the residual without this cycle's best-fitting drift
        resid = resid - col * (np.vdot(col, resid).real / max(np.vdot(col, col).real, 1e-300))
    stats = stats.update(resid, 0.0, memory)
    floor = freq**2 * 2.0 * residual_rms**2 / max(n_edges, 1) + 1e-12
    e = model_rel_error * freq * np.abs(harmonics[rows])
    v = np.maximum(np.abs(stats.mean) ** 2, e * e) / 2.0  # the repeatable part, per real component
    # weighted by what n cycles of a row can tell: its mean's variance is var / n + v, so each cycle counts with
    # 1 / (var + n v) (``stats.count`` cycles so far, the forgetting window's upper bound); weighted by var alone,
    # the free end's repeatable leak (design notes: up to 52 % of a harmonic) drew the estimate while its
    # systematic covariance grew with it (genset-v20 +-20 % profile, seed 29: the joint fit's statistical
    # sigma 3.3 % of a cylinder, systematic 11-17 %, fewer cylinders measured than one wheel; design note 35)
    sigma = np.sqrt(np.maximum(stats.var, floor) + stats.count * v)
    inv = np.concatenate([1.0 / sigma, 1.0 / sigma])
    a = np.concatenate([d.real, d.imag]) * inv[:, None]
    y = np.concatenate([t.real, t.imag]) * inv
    if col is not None and drift_var > 0:  # the drift as a random effect (noise_kernel's Sherman-Morrison)
        dw = np.concatenate([col.real, col.imag]) * inv
        nd = float(dw @ dw)
        s2 = drift_var * (0.5 * period) ** 2  # speed-step variance -> drift-coefficient variance
        if nd > 0:
            c = (1.0 - 1.0 / np.sqrt(1.0 + s2 * nd)) / nd
            a = a - c * np.outer(dw, dw @ a)
            y = y - c * dw * (dw @ y)
    return stats, a, y, inv, np.concatenate([v, v])


def no_free_end_rows(m: int, p: int, max_order: float = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                          np.ndarray]:
    """Zero rows (a cycle without the second wheel): (a, y, inv_sigma, sys_var) of the same shapes."""
    h = 2 * half_order_rows(m, max_order).size
    return np.zeros((h, p)), np.zeros(h), np.zeros(h), np.zeros(h)
