"""The identification stage of one cycle (design.md §4 step 5): from the harmonic balance's rows to the smoothed
and this cycle's estimates.

1. Noise model and whitened rows (core.monitor.identify.noise_model); the whitened equations accumulated with forgetting
   (core.monitor.identify.accumulate.Accumulator) once the warm-up cycles are over.
2. Eq. 6 shares of the mean balance (core.monitor.identify.parameters): of the running balance by the running indicated means
   for the smoothed estimate, of this cycle's own for the cycle's estimate; added to the fixed priors' normal
   equations (core.monitor.identify.parameters.PriorNormal).
3. Posteriors (core.monitor.identify.posterior.posterior_from_normal): the accumulated equations, and this cycle's alone.
4. Reported estimates (core.monitor.identify.estimate.reported_estimate), the smoothed one's pull check
   (core.monitor.identify.pull_check).
Steps 1's accumulation to 4 are one kernel call (core.monitor.identify.step.identify_step, design note 115).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.balance.excitation import Excitation
from frictionwatch.core.monitor.balance.mean_balance import MeanBalance
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from frictionwatch.core.monitor.identify.estimate import ReportLimits
from frictionwatch.core.monitor.identify.free_response import without_free_response
from frictionwatch.core.monitor.identify.noise_model import NoiseSettings, ResidualStats, whitened_rows
from frictionwatch.core.monitor.identify.parameters import CycleRows, firing_mask, motored_friction_per_cylinder
from frictionwatch.core.monitor.identify.posterior import Posterior
from frictionwatch.core.monitor.identify.step import StepInputs, StepSettings, identify_step
from frictionwatch.core.monitor.report.results import FrictionEstimate
from frictionwatch.core.monitor.state import MonitorConfig, MonitorState
from frictionwatch.core.monitor.teeth.flywheel import FlywheelMotion


def same_cycles_sigma(stats: ResidualStats, memory: float) -> float:
    """1-sigma [N m] of the same-cycles balance's disagreement (identify_cycle's ``same``): the EWMA's standard error
    from the balance residual's own scatter (g / (2 - g) of the per-cycle variance, g = max(1 - memory, 1 / count))."""
    if stats.count == 0:
        return float("nan")
    g = max(1.0 - memory, 1.0 / stats.count)
    return math.sqrt(max(stats.balance_var, 0.0) * g / (2.0 - g))


@dataclass(frozen=True)
class Identification:
    """The identification's results of one cycle: updated residual statistics and accumulator, the running means
    of the sharing prior (indicated_mean (z,), balance_mean), the posteriors and reported estimates of the
    accumulated equations (smoothed) and of this cycle's alone (cycle), the firing mask (z,), the harmonic
    frequencies freq (M,) and this cycle's drift column (M,) complex (None: not used); cycle_terms: this cycle's
    own normal equations (the model-misfit statistic's effective degrees of freedom, core.monitor.checks.condition)."""

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
    cycle_terms: Accumulator | None = None


NO_BALANCE = ("prior: no mean balance (no load measurement, no cycle before for the kinetic-energy term, or the load "
              "stepped between the two)")


def _source(balanced: bool) -> str:
    return "data" if balanced else NO_BALANCE


def measured_or_withheld(est: FrictionEstimate, source: str) -> FrictionEstimate:
    """``est`` when its ``source`` is the data; otherwise the same with every friction figure withheld (NaN, not
    resolved) and ``source`` saying why. Without a mean balance (no load measurement, or no cycle before for the
    kinetic-energy term) the speed ripple alone does not pin the engine's total friction: the posterior is then the
    prior's numbers (TU/e fired files: scaling the preset's coefficients scaled the output), and so is the Eq. 6
    share (``prior_friction_torque_mean``), withheld too."""
    if source == "data":
        return est
    nan_z = np.full_like(est.friction_torque_mean, np.nan)
    nan_c = np.full_like(est.coefficients, np.nan)
    nan = float("nan")
    return replace(est, friction_torque_mean=nan_z, friction_torque_mean_sigma=nan_z, fmep=nan_z, fmep_sigma=nan_z,
                   coefficients=nan_c, coefficients_sigma=nan_c, coefficients_normalised=nan_c,
                   coefficients_normalised_sigma=nan_c, resolved=np.zeros_like(est.resolved),
                   coefficient_resolved=np.zeros_like(est.coefficient_resolved), total_friction_torque=nan,
                   total_friction_torque_sigma=nan, total_fmep=nan, total_fmep_sigma=nan, source=source,
                   prior_friction_torque_mean=nan_z)


def forgetting_factor(cfg: MonitorConfig, n_cyl: int, period_s: float = float("nan")) -> float:
    """Per-cycle factor of the accumulated equations: ``cfg.forgetting`` if set, else 1 - 1/N_window with N_window =
    max(400, 100 z, tau / period_s) cycles, tau = ``cfg.forgetting_time_s`` (the wear time scale; more cylinders
    need more cycles, physics.md §12.5); period_s the cycle's duration (not finite: the cycle rule alone)."""
    if cfg.forgetting is not None:
        return cfg.forgetting
    window = max(400.0, 100.0 * n_cyl)
    tau = cfg.forgetting_time_s
    if tau is not None and math.isfinite(period_s) and period_s > 0.0:
        window = max(window, tau / period_s)
    return 1.0 - 1.0 / window


def identify_cycle(cfg: MonitorConfig, spec: EngineSpec, state: MonitorState, fly: FlywheelMotion, rows: CycleRows,
                   exc: Excitation, pmax: np.ndarray, mean: MeanBalance, drift_var: float,
                   free_rows: tuple | None = None, modes: np.ndarray | None = None) -> Identification:
    """One cycle's identification; ``state`` is the monitor's state before the cycle (not changed). ``free_rows``:
    a second wheel's whitened rows (a, y, inv_sigma, sys_var; core.monitor.identify.noise_model), accumulated with
    the flywheel's (the joint fit of both wheels), before the mean-balance row. ``modes``: the chain's free-vibration
    eigenvalues (OperatingPoint.modes): those carried over a cycle have their free response a random effect of the
    flywheel's rows (core.monitor.identify.free_response; None: none)."""
    lam = forgetting_factor(cfg, spec.n_cyl, fly.period)
    sys_balance = ((cfg.balance_rel_error * mean.indicated) ** 2 + (cfg.coupling_rel_error * mean.coupling_loss) ** 2
                   + (cfg.load_rel_error * spec.rated_torque_nm) ** 2)
    noise = NoiseSettings(memory=cfg.noise_memory, model_rel_error=cfg.model_rel_error,
                          use_drift=cfg.drift_nuisance, sys_balance=sys_balance)
    white = whitened_rows(noise, state.stats, fly, rows, state.params, mean.friction, mean.indicated, drift_var)
    white = without_free_response(white, state.stats, state.params, modes, fly.period, cfg.free_response_carry,
                                  drift_var if noise.use_drift else 0.0, cfg.noise_memory)
    if free_rows is not None:  # both wheels: the free end's rows between the flywheel's and the mean balance
        a2, y2, inv2, sys2 = free_rows
        white = replace(white, a=np.concatenate([white.a[:-1], a2, white.a[-1:]]),
                        y=np.concatenate([white.y[:-1], y2, white.y[-1:]]),
                        inv_sigma=np.concatenate([white.inv_sigma[:-1], inv2, white.inv_sigma[-1:]]),
                        sys_var=np.concatenate([white.sys_var[:-1], sys2, white.sys_var[-1:]]))
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
    stats = white.stats
    # the floor compares the smoothed estimate's total at this cycle's operating point with that total plus the
    # fit's mean disagreement with the balance over the same recent cycles (stats.balance_mean: the noise model's
    # EWMA of each cycle's balance minus the fit's total then), so both sides stand at the same operating points.
    # Not the running mean of the balance (the sharing prior's): under a load profile that averages every point of
    # the run, and the floor read friction's load dependence as model error (genset-v20, +-20 % profile, seed 29:
    # a 7.2 % floor on every cylinder, 10 measured cylinders to 0; design note 35). NaN before any statistics
    same = (float(stats.balance_mean) if stats.count > 0 else float("nan"), same_cycles_sigma(stats, cfg.noise_memory),
            math.sqrt(stats.balance_var))
    misfit = state.condition.misfit if state.condition is not None else 1.0  # the window up to the last cycle
    # the calibration's remaining uncertainty (TDC, gain, J, load) on top: the mean balance passes it into friction whole
    tdc = mean.tdc_sensitivity if mean.tdc_sensitivity is not None else np.zeros(spec.n_cyl)
    layout = state.layout
    inp = StepInputs(white, fly.harmonics, rows.mean_row, rows.cylinder_rows[:, :layout.n_params], exc.basis_mean,
                     ind_mean, t_i, bal_mean, balance, motored, same, mean.coupling_loss, misfit, tdc, mean.kinetic,
                     mean.load, mean.load_from_power)
    settings = StepSettings(lam, state.cycles >= cfg.warmup_cycles,
                            ReportLimits(cfg.resolve_rel, cfg.coefficient_snr, cfg.min_data_gain),
                            cfg.model_error_floor, cfg.calibration, cfg.pull_check, cfg.model_rel_error,
                            cfg.share_spread)
    step = identify_step(spec, layout, state.prior, state.lower, state.accumulator, state.params, inp, settings)
    acc, post_s, post_c = step.accumulator, step.smoothed, step.cycle
    # the smoothed estimate stands on a balance when one was accumulated, or, during the warm-up (nothing
    # accumulated), when the Eq. 6 share it holds is of a measured running balance; the cycle's on its own
    balanced = float(acc.info_reference.trace()) > 0.0 or (acc.weight == 0.0 and math.isfinite(bal_mean))
    est_s = measured_or_withheld(step.smoothed_estimate, _source(balanced))
    est_c = measured_or_withheld(step.cycle_estimate, _source(math.isfinite(balance)))
    return Identification(stats=white.stats, accumulator=acc, indicated_mean=ind_mean, balance_mean=bal_mean,
                          smoothed=post_s, cycle=post_c, smoothed_estimate=est_s, cycle_estimate=est_c, fire=fire,
                          freq=white.freq, drift_col=white.drift_col,
                          cycle_terms=Accumulator.of_terms(step.terms))
