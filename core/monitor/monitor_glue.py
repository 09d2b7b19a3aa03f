"""The small steps of core.monitor.monitor.process_cycle between the harmonic balance and the posteriors: the noise
model and whitened rows, the Eq. 6 shares of both estimates with their prior normal equations, the per-spec
constants they need (kept in the state as ``MonitorState.glue_plan``). Each fast path is one kernel
(core.monitor.monitor_kernels); the separate steps it replaces stay as the general path for unusual inputs."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from frictionwatch.core.monitor.accumulate import ResidualStats
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.flywheel import FlywheelMotion
from frictionwatch.core.monitor.frozen_init import fast_constructor
from frictionwatch.core.monitor.identify import CycleRows
from frictionwatch.core.monitor.monitor_kernels import (
    firing_into,
    noise_rows,
    noise_rows_cycle,
    pairwise_sum,
    share_normal_into,
    shares_pair_into,
)
from frictionwatch.core.monitor.sharing import CHEN_FLYNN_BAR, SharedLoss, motored_friction_per_cylinder, share_mean_loss

if TYPE_CHECKING:
    from frictionwatch.core.monitor.monitor import MonitorConfig, MonitorState

FOUR_PI = 4.0 * np.pi
_make_stats = fast_constructor(ResidualStats)  # ResidualStats(**fields), cheaper


def _with_share(prior_normal: tuple, cylinder_rows: np.ndarray, share: SharedLoss) -> tuple[np.ndarray, np.ndarray]:
    """Normal equations of the fixed priors plus the Eq. 6 share rows (``FixedPriors.with_share(share).normal()``)."""
    _, n_base, r_base = prior_normal
    if not np.all(np.isfinite(share.friction_mean)):
        return n_base, r_base
    sig = np.maximum(share.sigma, 1e-6)
    w = cylinder_rows / sig[:, None]
    return n_base + w.T @ w, r_base + w.T @ (share.friction_mean / sig)


def noise_model_rows(cfg: MonitorConfig, spec: EngineSpec, state: MonitorState, fly: FlywheelMotion,
                     rows: CycleRows, balance: float, t_i: float, drift_var: float, coupling_loss: float):
    """Updated residual statistics, whitened rows a (2M+1, P), y, inv_sigma, sys_var (2M+1,), the harmonic
    frequencies (M,) and the drift column i freq drift_harm (M,) complex (None without drift nuisance) of one
    cycle (core.monitor.monitor_kernels.noise_rows_cycle; the steps are described there and in core.monitor.monitor.process_cycle).
    A tooth fit with another harmonic count than the monitor's goes the general path."""
    m = state.n_harmonics
    p = rows.design.shape[1]
    st = state.stats
    sys_balance = ((cfg.balance_rel_error * t_i) ** 2 + (cfg.coupling_rel_error * coupling_loss) ** 2
                   + (cfg.load_rel_error * spec.rated_torque_nm) ** 2)
    if fly.harmonics.shape[0] != m:  # a tooth fit of another order: the separate steps
        return noise_model_rows_general(cfg, spec, state, fly, rows, balance, t_i, drift_var, sys_balance)
    out_mean = np.empty(m, dtype=np.complex128)
    out_var = np.empty(m)
    out_scalars = np.empty(3)
    a = np.empty((2 * m + 1, p))
    y = np.empty(2 * m + 1)
    buf = np.empty(3 * (2 * m + 1) + m)  # inv_sigma, sys_var, freq: fresh per cycle (they go on)
    n2 = 2 * m + 1
    inv_sigma = buf[:n2]
    sys_var = buf[n2:2 * n2]
    freq = buf[2 * n2:2 * n2 + m]
    drift_col = np.empty(m, dtype=np.complex128)
    noise_rows_cycle(_c128(rows.design), _c128(rows.target), np.ascontiguousarray(state.theta, dtype=np.float64),
                     float(fly.omega_mean), np.ascontiguousarray(fly.pattern_harmonics[:, -1], dtype=np.complex128),
                     bool(cfg.drift_nuisance),
                     _c128(st.mean), np.ascontiguousarray(st.var, dtype=np.float64), float(st.balance_mean),
                     float(st.balance_var), float(st.count), float(cfg.noise_memory), float(balance),
                     np.ascontiguousarray(rows.mean_row, dtype=np.float64), float(fly.residual_rms),
                     float(fly.n_edges), float(t_i), float(drift_var), float(fly.period), _c128(fly.harmonics),
                     float(cfg.model_rel_error), float(sys_balance), freq, drift_col, out_mean, out_var, out_scalars,
                     a, y, inv_sigma, sys_var)
    stats = _make_stats(mean=out_mean, var=out_var, balance_mean=float(out_scalars[0]),
                        balance_var=float(out_scalars[1]), count=st.count + 1)
    return stats, a, y, inv_sigma, sys_var, freq, drift_col if cfg.drift_nuisance else None


def noise_model_rows_general(cfg: MonitorConfig, spec: EngineSpec, state: MonitorState, fly: FlywheelMotion,
                             rows: CycleRows, balance: float, t_i: float, drift_var: float, sys_balance: float):
    """``noise_model_rows`` for a tooth fit whose harmonic count differs from the monitor's (fit_order)."""
    m = state.n_harmonics
    p = rows.design.shape[1]
    st = state.stats
    freq = fly.freq
    floor = freq**2 * 2.0 * fly.residual_rms**2 / fly.n_edges + 1e-12
    out_mean = np.empty(m, dtype=np.complex128)
    out_var = np.empty(m)
    out_scalars = np.empty(3)
    a = np.empty((2 * m + 1, p))
    y = np.empty(2 * m + 1)
    inv_sigma = np.empty(2 * m + 1)
    sys_var = np.empty(2 * m + 1)
    noise_rows(np.ascontiguousarray(rows.design, dtype=np.complex128),
               np.ascontiguousarray(rows.target, dtype=np.complex128),
               np.ascontiguousarray(state.theta, dtype=np.float64), freq,
               np.ascontiguousarray(fly.pattern_harmonics[:, -1], dtype=np.complex128), bool(cfg.drift_nuisance),
               np.ascontiguousarray(st.mean, dtype=np.complex128), np.ascontiguousarray(st.var, dtype=np.float64),
               np.array([st.balance_mean, st.balance_var, st.count], dtype=np.float64), float(cfg.noise_memory),
               float(balance), np.ascontiguousarray(rows.mean_row, dtype=np.float64),
               np.ascontiguousarray(floor, dtype=np.float64), float(t_i), float(drift_var), float(fly.period),
               np.ascontiguousarray(fly.harmonics, dtype=np.complex128), float(cfg.model_rel_error),
               float(sys_balance), out_mean, out_var, out_scalars, a, y, inv_sigma, sys_var)
    stats = ResidualStats(mean=out_mean, var=out_var, balance_mean=float(out_scalars[0]),
                          balance_var=float(out_scalars[1]), count=st.count + 1)
    drift_col = freq_times_1j(freq, fly.pattern_harmonics[:, -1]) if cfg.drift_nuisance else None
    return stats, a, y, inv_sigma, sys_var, freq, drift_col


def _c128(x: np.ndarray) -> np.ndarray:
    """x itself when it is already complex128 (any layout: the kernels take strided views), else a converted copy."""
    return x if x.dtype == np.complex128 else np.ascontiguousarray(x, dtype=np.complex128)


def freq_times_1j(freq: np.ndarray, harmonics: np.ndarray) -> np.ndarray:
    """``1j * freq * harmonics`` (M,) complex."""
    return 1j * freq * harmonics


_LOWER: dict[tuple[int, int], np.ndarray] = {}


def _lower_bounds(n_params: int, n_nuisance: int) -> np.ndarray:
    """Lower bounds [0 for the friction scales, -inf (free) for the nuisances]; one read-only array per size."""
    key = (n_params, n_nuisance)
    lo = _LOWER.get(key)
    if lo is None:
        lo = np.concatenate([np.zeros(n_params), np.full(n_nuisance, -np.inf)])
        lo.flags.writeable = False
        _LOWER[key] = lo
    return lo


def glue_plan(spec: EngineSpec, state: MonitorState) -> tuple:
    """Per-spec constants of the glue, kept in the state: (spec, [stroke, displacement_cyl, Chen-Flynn A, B, C, D]
    of core.monitor.sharing.motored_friction_per_cylinder, lower bounds of the posterior, (4 pi / displacement_cyl,
    4 pi / displacement) of core.monitor.estimate)."""
    consts = np.array([spec.stroke, spec.displacement_cyl, *CHEN_FLYNN_BAR], dtype=np.float64)
    mep_factors = (FOUR_PI / spec.displacement_cyl, FOUR_PI / spec.displacement)
    return spec, consts, _lower_bounds(state.layout.n_params, state.n_nuisance), mep_factors


def shares_pair(spec: EngineSpec, state: MonitorState, prior_normal: tuple, cylinder_rows: np.ndarray,
                indicated_mean: np.ndarray, pmax: np.ndarray, g: float, total_s: float, total_c: float, rpm: float,
                motored_consts: np.ndarray, spread: float):
    """Running indicated means, firing mask and the two ``_share_and_normal`` of core.monitor.monitor.process_cycle
    (smoothed: running means; this cycle: its own) in one kernel call; the general path (odd layouts) in the
    separate steps.
    Returns ind_mean, share_s, share_c (z,) [N m], fire (z,) bool, n_fire, N_s, r_s, N_c, r_c."""
    z = spec.n_cyl
    _, n_base, r_base = prior_normal
    t_i = indicated_mean
    rows = cylinder_rows
    if (t_i.dtype == np.float64 and t_i.flags.c_contiguous and t_i.shape == (z,) and pmax.dtype == np.float64
            and rows.dtype == np.float64 and rows.flags.c_contiguous and rows.shape[0] == z
            and rows.shape[1] <= n_base.shape[0] and n_base.flags.c_contiguous and r_base.flags.c_contiguous):
        p = n_base.shape[0]
        buf = np.empty(5 * z)
        ind_mean = buf[:z]
        fire = np.empty(z, dtype=np.bool_)
        normal = np.empty((2, p, p))  # [smoothed, this cycle]: fresh per cycle (the posteriors may keep them)
        rhs = np.empty((2, p))
        n_s, n_c = normal[0], normal[1]
        r_s, r_c = rhs[0], rhs[1]
        n_fire = shares_pair_into(t_i, pmax, state.indicated_mean, state.cycles == 0, g, total_s, total_c, rpm,
                                  motored_consts, spread, n_base, r_base, rows, ind_mean, buf[z:2 * z],
                                  buf[2 * z:3 * z], buf[3 * z:4 * z], buf[4 * z:], fire, n_s, r_s, n_c, r_c)
        return ind_mean, buf[z:2 * z], buf[3 * z:4 * z], fire, n_fire, n_s, r_s, n_c, r_c
    ind_mean = t_i.copy() if state.cycles == 0 else state.indicated_mean + g * (t_i - state.indicated_mean)
    fire = np.empty(z, dtype=np.bool_)
    n_fire = firing_into(np.ascontiguousarray(t_i, dtype=np.float64), 0.15, fire)
    pmax_motored = 0.0
    if n_fire < z:  # np.mean of the motored cylinders' peaks
        pmax_motored = pairwise_sum(np.ascontiguousarray(pmax[~fire]), 0, z - n_fire) / (z - n_fire)
    motored = motored_friction_per_cylinder(spec, rpm, pmax_motored)
    share_s, n_s, r_s = _share_and_normal(prior_normal, rows, total_s, ind_mean, motored, spread)
    share_c, n_c, r_c = _share_and_normal(prior_normal, rows, total_c, t_i, motored, spread)
    return ind_mean, share_s.friction_mean, share_c.friction_mean, fire, n_fire, n_s, r_s, n_c, r_c


def _share_and_normal(prior_normal: tuple, cylinder_rows: np.ndarray, friction_total: float,
                      indicated_mean: np.ndarray, motored_friction: float,
                      spread: float) -> tuple[SharedLoss, np.ndarray, np.ndarray]:
    """``share_mean_loss`` and ``_with_share`` in two kernel calls."""
    share = share_mean_loss(friction_total, indicated_mean, motored_friction, spread)
    _, n_base, r_base = prior_normal
    rows = cylinder_rows
    if not (rows.dtype == np.float64 and rows.flags.c_contiguous and n_base.flags.c_contiguous
            and r_base.flags.c_contiguous):
        n_pr, r_pr = _with_share(prior_normal, np.pad(rows, ((0, 0), (0, n_base.shape[0] - rows.shape[1]))), share)
        return share, n_pr, r_pr
    n_out = np.empty(n_base.shape)
    r_out = np.empty(r_base.shape)
    if share_normal_into(n_base, r_base, rows, share.friction_mean, share.sigma, n_out, r_out):
        return share, n_out, r_out
    return share, n_base, r_base
