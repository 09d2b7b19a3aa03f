"""The identification stage of one cycle (design.md §4 step 5): from the harmonic balance's rows to the smoothed
and this cycle's estimates.

1. Noise model and whitened rows (core.monitor.noise_model); the whitened equations accumulated with forgetting
   (core.monitor.accumulate.Accumulator) once the warm-up cycles are over.
2. Eq. 6 shares of the mean balance (core.monitor.sharing): of the running balance by the running indicated means
   for the smoothed estimate, of this cycle's own for the cycle's estimate; added to the fixed priors' normal
   equations (core.monitor.priors.PriorNormal).
3. Posteriors (core.monitor.accumulate.posterior_from_normal): the accumulated equations, and this cycle's alone.
4. Reported estimates (core.monitor.estimate.friction_estimate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.accumulate import Accumulator, Posterior, ResidualStats, posterior_from_normal
from frictionwatch.core.monitor.estimate import BalanceCheck, ReportLimits, friction_estimate
from frictionwatch.core.monitor.excitation import Excitation
from frictionwatch.core.monitor.flywheel import FlywheelMotion
from frictionwatch.core.monitor.identify import CycleRows
from frictionwatch.core.monitor.noise_model import NoiseSettings, whitened_rows
from frictionwatch.core.monitor.results import FrictionEstimate
from frictionwatch.core.monitor.sharing import firing_mask, motored_friction_per_cylinder, share_mean_loss
from frictionwatch.core.monitor.state import MonitorConfig, MonitorState


@dataclass(frozen=True)
class MeanBalance:
    """This cycle's mean torque balance [N m]: indicated (sum over cylinders), load (measured, plus the load's own
    ripple work), coupling_loss (modelled damper/coupling dissipation) and friction = indicated - load - coupling
    (NaN without a load measurement)."""

    indicated: float
    load: float
    coupling_loss: float
    friction: float


@dataclass(frozen=True)
class Identification:
    """The identification's results of one cycle: updated residual statistics and accumulator, the running means
    of the sharing prior (indicated_mean (z,), balance_mean), the posteriors and reported estimates of the
    accumulated equations (smoothed) and of this cycle's alone (cycle), the firing mask (z,), the harmonic
    frequencies freq (M,) and this cycle's drift column (M,) complex (None: not used)."""

    stats: ResidualStats
    accumulator: Accumulator
    indicated_mean: np.ndarray
    balance_mean: float
    smoothed: Posterior
    cycle: Posterior
    smoothed_estimate: FrictionEstimate
    cycle_estimate: FrictionEstimate
    fire: np.ndarray
    freq: np.ndarray
    drift_col: np.ndarray | None


def forgetting_factor(cfg: MonitorConfig, n_cyl: int) -> float:
    """Per-cycle factor of the accumulated equations: 1 - 1/N_window, N_window = max(400, 100 z) cycles unless set
    (more cylinders need more cycles; physics.md §12.5)."""
    return cfg.forgetting if cfg.forgetting is not None else 1.0 - 1.0 / max(400.0, 100.0 * n_cyl)


def identify_cycle(cfg: MonitorConfig, spec: EngineSpec, state: MonitorState, fly: FlywheelMotion, rows: CycleRows,
                   exc: Excitation, pmax: np.ndarray, mean: MeanBalance, drift_var: float) -> Identification:
    """One cycle's identification; ``state`` is the monitor's state before the cycle (not changed)."""
    lam = forgetting_factor(cfg, spec.n_cyl)
    sys_balance = ((cfg.balance_rel_error * mean.indicated) ** 2 + (cfg.coupling_rel_error * mean.coupling_loss) ** 2
                   + (cfg.load_rel_error * spec.rated_torque_nm) ** 2)
    noise = NoiseSettings(memory=cfg.noise_memory, model_rel_error=cfg.model_rel_error,
                          use_drift=cfg.drift_nuisance, sys_balance=sys_balance)
    white = whitened_rows(noise, state.stats, fly, rows, state.params, mean.friction, mean.indicated, drift_var)
    terms = state.accumulator.cycle_terms(white.a, white.y, white.inv_sigma, 1)  # the mean-balance row: reference
    acc = state.accumulator.fold(terms, lam) if state.cycles >= cfg.warmup_cycles else state.accumulator

    # running means of the sharing prior of the smoothed estimate
    g = max(1.0 - lam, 1.0 / (state.cycles + 1))
    t_i = exc.indicated_mean
    ind_mean = t_i.copy() if state.cycles == 0 else state.indicated_mean + g * (t_i - state.indicated_mean)
    balance = mean.friction
    if not math.isfinite(balance):
        bal_mean = state.balance_mean
    elif not math.isfinite(state.balance_mean):
        bal_mean = balance
    else:
        bal_mean = state.balance_mean + g * (balance - state.balance_mean)
    fire = firing_mask(t_i)
    pmax_motored = float(np.mean(pmax[~fire])) if not fire.all() else 0.0
    motored = motored_friction_per_cylinder(spec, fly.omega_mean * 60.0 / (2.0 * np.pi), pmax_motored)
    share_s = share_mean_loss(bal_mean, ind_mean, motored, cfg.share_spread)
    share_c = share_mean_loss(balance if math.isfinite(balance) else bal_mean, t_i, motored, cfg.share_spread)
    layout = state.layout
    cyl_rows = rows.cylinder_rows[:, :layout.n_params]  # the friction parameters' part
    post_s = posterior_from_normal(acc, *state.prior.with_share(cyl_rows, share_s), white.sys_var, state.lower)
    post_c = posterior_from_normal(Accumulator.of_terms(terms), *state.prior.with_share(cyl_rows, share_c),
                                   white.sys_var, state.lower)
    limits = ReportLimits(cfg.resolve_rel, cfg.coefficient_snr, cfg.min_data_gain)
    # the model-error floor compares each estimate with the mean balance over the same cycles (its EWMA's sigma
    # from the balance's own scatter: g / (2 - g) of the per-cycle variance)
    floor, bal_sigma = cfg.model_error_floor, math.sqrt(white.stats.balance_var)
    misfit = state.condition.misfit if state.condition is not None else 1.0  # the window up to the last cycle
    check_s = BalanceCheck(ind_mean, bal_mean, bal_sigma * math.sqrt(g / (2.0 - g)), mean.coupling_loss, misfit)
    check_c = BalanceCheck(t_i, balance, bal_sigma, mean.coupling_loss, misfit)
    est_s = friction_estimate(spec, layout, post_s, exc.basis_mean, share_s.friction_mean, limits, cyl_rows, floor,
                              check_s)
    est_c = friction_estimate(spec, layout, post_c, exc.basis_mean, share_c.friction_mean, limits, cyl_rows, floor,
                              check_c)
    return Identification(stats=white.stats, accumulator=acc, indicated_mean=ind_mean, balance_mean=bal_mean,
                          smoothed=post_s, cycle=post_c, smoothed_estimate=est_s, cycle_estimate=est_c, fire=fire,
                          freq=white.freq, drift_col=white.drift_col)
