"""The second wheel's speed equations, whitened, for the joint fit of both wheels (issue 29 item 1).

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

import numpy as np
from frictionwatch.core.monitor.identify.accumulate import ResidualStats


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
