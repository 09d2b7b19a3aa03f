"""The identification stage of one cycle (design.md §4 step 5): from the harmonic balance's rows to the smoothed
and this cycle's estimates.

1. Noise model and whitened rows (core.monitor.identify.noise_model); the whitened equations accumulated with forgetting
   (core.monitor.identify.accumulate.Accumulator) once the warm-up cycles are over.
2. Eq. 6 shares of the mean balance (core.monitor.identify.sharing): of the running balance by the running indicated means
   for the smoothed estimate, of this cycle's own for the cycle's estimate; added to the fixed priors' normal
   equations (core.monitor.identify.priors.PriorNormal).
3. Posteriors (core.monitor.identify.accumulate.posterior_from_normal): the accumulated equations, and this cycle's alone.
4. Reported estimates (core.monitor.identify.estimate.friction_estimate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.indicated import piston_positions, tdc_centres, window_starts, works_with_alone
from frictionwatch.core.model.kinematics import cylinder_kinematics_kernel, kinematics, variable_inertia
from frictionwatch.core.monitor.balance.excitation import Excitation
from frictionwatch.core.monitor.identify.accumulate import (
    Accumulator,
    CycleTerms,
    Posterior,
    ResidualStats,
    posterior_from_normal,
)
from frictionwatch.core.monitor.identify.accumulate_kernels import cycle_step_kernel
from frictionwatch.core.monitor.identify.energy_kernels import cycle_energy_kernel
from frictionwatch.core.monitor.identify.estimate import (
    BalanceCheck,
    CalibrationSensitivity,
    ReportLimits,
    reported_estimate,
)
from frictionwatch.core.monitor.identify.layout import CycleRows
from frictionwatch.core.monitor.identify.noise_model import NoiseSettings, whitened_rows
from frictionwatch.core.monitor.identify.pull_check import with_pull
from frictionwatch.core.monitor.identify.sharing import firing_mask, motored_friction_per_cylinder, share_mean_loss
from frictionwatch.core.monitor.report.results import FrictionEstimate
from frictionwatch.core.monitor.state import (
    EnergyWeights,
    GridGeometry,
    MonitorConfig,
    MonitorState,
    PreviousCycle,
)
from frictionwatch.core.monitor.teeth.flywheel import FlywheelMotion
from frictionwatch.core.types import Cycle

FOUR_PI = 4.0 * np.pi


@dataclass(frozen=True)
class MeanBalance:
    """This cycle's mean torque balance [N m]: indicated (sum over cylinders, the cycle's own window), load
    (measured, plus the load's own ripple work), coupling_loss (modelled damper/coupling dissipation), kinetic =
    the change of the cycles' angle-averaged kinetic energy / 4 pi from the cycle before to this one
    (``transient_balance``) and friction = indicated_window - the two cycles' mean load and coupling loss - kinetic
    (NaN without a load measurement or without the previous cycle); imep_centred (z,) [Pa] over each cylinder's own
    firing window, None without the previous cycle; acceleration [rad/s^2] kinetic / J(2 pi) and indicated_window
    [N m] the two cycles' indicated torque under the balance's triangular weight;
    tdc_sensitivity (z,) [N m/rad] each cylinder's dT_iM/dDelta (core.monitor.identify.estimate.indicated_tdc_sensitivity),
    None where not computed (then the calibration adds no TDC term)."""

    indicated: float
    load: float
    coupling_loss: float
    friction: float
    kinetic: float = float("nan")
    imep_centred: np.ndarray | None = None
    acceleration: float = float("nan")
    indicated_window: float = float("nan")
    tdc_sensitivity: np.ndarray | None = None


def mid_cycle_speed(spec: EngineSpec, cycle: Cycle) -> float:
    """Speed [rad/s] at the middle of the cycle (cylinder 1's gas-exchange TDC, theta = 2 pi): 1 / (dt/dtheta) of a
    quadratic in angle fitted (one least-squares solve) to the edge times within +-MID_SPEED_HALF_WIDTH (about 30
    edges of a 60-2 wheel). Two edges +-18 deg apart quantised the speed to 1 timer tick in 2 ms (simulated Deutz
    at 1 MHz: J a in steps of 0.115 N m on 7.6); the fit averages that down ~10x. A tooth-spacing error and the
    speed ripple repeat every cycle at this angle and drop out of a difference of two cycles; the quadratic keeps
    the linear deceleration out of the slope at the centre. The commissioning's inertia window uses it
    (core.monitor.calibration.inertia); the monitor's balance takes each cycle's mean energy (design note 69)."""
    ang = cycle.tooth_angle - 2.0 * np.pi
    near = np.abs(ang) <= MID_SPEED_HALF_WIDTH
    if np.count_nonzero(near) < 5:
        return float("nan")
    t = (cycle.tooth_ticks[near] - cycle.tooth_ticks[near][0]) / cycle.tick_hz
    a = ang[near]
    dt_dtheta = np.linalg.lstsq(np.stack([np.ones_like(a), a, a * a], axis=1), t, rcond=None)[0][1]
    return float(1.0 / dt_dtheta) if dt_dtheta > 0 else float("nan")


MID_SPEED_HALF_WIDTH = np.radians(90.0)


def mid_cycle_inertia(spec: EngineSpec) -> float:
    """J(theta) [kg m^2] at theta = 2 pi: the rotating inertia plus each reciprocating mass times x'(theta)^2."""
    local = np.mod(2.0 * np.pi - spec.firing_angles, 4.0 * np.pi)
    _, dx, _ = kinematics(local, spec.kinematics_params())
    return spec.total_inertia + spec.reciprocating_mass * float(np.sum(dx * dx))


def grid_geometry(spec: EngineSpec, grid: np.ndarray) -> GridGeometry:
    """The piston positions of every cylinder on the cycles' grid, J at theta = 2 pi, each cylinder's own firing
    window and the triangular weights of the transient balance's indicated torque (made once per grid)."""
    positions = piston_positions(grid, spec.firing_angles, spec.kinematics_params())
    z, n = spec.n_cyl, grid.shape[0]
    dx, ddx = np.empty((z, n)), np.empty((z, n))
    cylinder_kinematics_kernel(np.ascontiguousarray(grid, dtype=np.float64),
                               np.ascontiguousarray(spec.firing_angles, dtype=np.float64),
                               np.ascontiguousarray(spec.kinematics_params(), dtype=np.float64), dx, ddx)
    centres = tdc_centres(spec.firing_angles)[None, :]
    return GridGeometry(float(grid[0]), int(n), positions, mid_cycle_inertia(spec), ddx,
                        window_starts(grid, centres), window_starts(grid, np.zeros((1, z))),
                        *triangle_weights(grid, positions, spec.piston_area))


def triangle_weights(grid: np.ndarray, positions: np.ndarray, area: float) -> tuple[np.ndarray, np.ndarray]:
    """(previous, current) (z, n) [m^2/rad]: the coefficients that take two consecutive cycles' pressures [Pa] to
    the transient balance's indicated torque beyond the two cycles' plain mean [N m]:
    sum(previous_p * previous) + sum(current_p * current) = (1/4 pi) [int over the previous cycle of T (phi/4 pi - 1/2)
    + int over the current one of T (1/2 - phi/4 pi)] dphi, T = sum_k p_k A x_k' the gas torque, by the trapezoid
    rule on the grid (each interval's weight at its middle; the previous cycle's last interval ends on the current
    cycle's first sample, the current cycle's closes on its own first). The weights have zero mean over each cycle,
    so the grid's trapezoid bias (~0.5 % of a work) enters only this small difference."""
    n = grid.shape[0]
    step = FOUR_PI / n
    mid = (grid + 0.5 * step) / FOUR_PI  # each interval's middle, a fraction of the cycle
    dx = np.roll(positions, -1, axis=1) - positions  # x is 4 pi periodic: the last interval ends on x[0]
    g_prev, g_cur = (mid - 0.5) * dx, (0.5 - mid) * dx  # (z, n) an interval's weight x its dx
    scale = 0.5 * area / FOUR_PI
    prev = np.ascontiguousarray(scale * (g_prev + np.concatenate((np.zeros_like(g_prev[:, :1]), g_prev[:, :-1]), 1)))
    cur = scale * (g_cur + np.roll(g_cur, 1, axis=1))
    cur[:, 0] += scale * g_prev[:, -1]  # the previous cycle's last interval ends on the current cycle's first sample
    return prev, np.ascontiguousarray(cur)


def triangle_weights_reference(grid: np.ndarray, positions: np.ndarray, area: float, previous: np.ndarray,
                               current: np.ndarray) -> float:
    """``triangle_weights``' sum by the plain trapezoid of the weighted gas-torque work along [previous | current]
    (its reference, tests/core/test_transient_balance.py)."""
    n = grid.shape[0]
    step = FOUR_PI / n
    frac = (grid + 0.5 * step) / FOUR_PI
    total = 0.0
    for k in range(positions.shape[0]):
        x_next = np.roll(positions[k], -1)
        p_prev_next = np.append(previous[k, 1:], current[k, 0])
        p_cur_next = np.roll(current[k], -1)
        total += np.sum((frac - 0.5) * 0.5 * (previous[k] + p_prev_next) * (x_next - positions[k]))
        total += np.sum((0.5 - frac) * 0.5 * (current[k] + p_cur_next) * (x_next - positions[k]))
    return float(total * area / FOUR_PI)


def energy_weights(spec: EngineSpec, tooth_angle: np.ndarray) -> EnergyWeights:
    """The weights of ``cycle_energy`` at a cycle's edges (fixed by their nominal angles): per tooth interval,
    1/2 J over the interval's part inside [0, 4 pi) (Simpson's rule over that part; J(theta) the rotating inertia
    plus every reciprocating mass times x'^2, as ``mid_cycle_inertia`` at one angle) x its nominal pitch^2 x that
    part's length / 4 pi, so that the interval's speed pitch / dt gives its share of the cycle's mean energy."""
    a = np.array(tooth_angle, dtype=np.float64)
    lo, hi = np.clip(a[:-1], 0.0, FOUR_PI), np.clip(a[1:], 0.0, FOUR_PI)
    pts = np.concatenate((lo, 0.5 * (lo + hi), hi))
    j = variable_inertia(pts, spec.firing_angles, spec.kinematics_params(), spec.reciprocating_mass,
                         spec.total_inertia)[0].reshape(3, -1)
    j_mean = (j[0] + 4.0 * j[1] + j[2]) / 6.0
    pitch = a[1:] - a[:-1]
    return EnergyWeights(a, np.ascontiguousarray(0.5 * j_mean * pitch * pitch * (hi - lo) / FOUR_PI))


def cycle_energy(cycle: Cycle, weights: EnergyWeights) -> float:
    """The cycle's angle-averaged kinetic energy (1/4 pi) int_0^4pi 1/2 J(theta) w(theta)^2 dtheta [J], w in each
    tooth interval its pitch over its measured time (``energy_weights``). An edge time's error enters two adjacent
    intervals with opposite signs and telescopes to first order: of the cycle's ~120 edges only the two boundary
    ones count, as in a difference of two speeds. NaN when an interval is not positive. One kernel call
    (core.monitor.identify.energy_kernels); ``cycle_energy_reference`` is its numpy."""
    ticks = cycle.tooth_ticks
    if ticks.dtype != np.int64 or not ticks.flags.c_contiguous or ticks.shape[0] != weights.weights.shape[0] + 1:
        return cycle_energy_reference(cycle, weights)
    return float(cycle_energy_kernel(ticks, weights.weights, float(cycle.tick_hz)))


def cycle_energy_reference(cycle: Cycle, weights: EnergyWeights) -> float:
    """``cycle_energy`` in numpy (its reference)."""
    dt = np.diff(np.asarray(cycle.tooth_ticks)).astype(np.float64) / cycle.tick_hz
    if dt.shape != weights.weights.shape or not np.all(dt > 0):
        return float("nan")
    return float(weights.weights @ (1.0 / (dt * dt)))


def transient_balance(spec: EngineSpec, cycle: Cycle, pressure: np.ndarray, indicated_cycle: np.ndarray,
                      energy: float, previous: PreviousCycle | None, load: float, coupling_loss: float,
                      geometry: GridGeometry, load_early: float) -> tuple[float, float, float, float,
                                                                          np.ndarray | None]:
    """(friction, kinetic, acceleration, indicated, imep_centred) of one cycle and the cycle just before it
    (``previous``; None when that cycle is not at hand: all NaN and None); indicated_cycle (z,) [N m] the
    cylinders' work means over this cycle's own window (``Excitation.indicated_mean``); energy [J] this cycle's
    angle-averaged kinetic energy (``cycle_energy``).

    The rigid shaft line's energy balance with each cycle's angle-averaged energy Ebar = (1/4 pi) int E dtheta,
    E = 1/2 J(theta) w^2, over its own [0, 4 pi): (Ebar_c - Ebar_c-1) / 4 pi is exactly the mean net torque
    under a triangular weight over the two cycles (phi / 4 pi on the previous cycle at its angle phi, 1 - phi / 4 pi
    on this one; half the weight on each, centred on cylinder 1's firing TDC between them). So the indicated torque
    is the two cycles' gas torque under that weight, the load and the coupling loss the two cycles' mean, and the
    friction the two cycles' mean friction. Why the mean energy and not E at one angle: every engine order is
    periodic in 4 pi, so the shaft's speed ripple drops out of Ebar to first order; E at theta = 2 pi holds the
    ripple there, which repeats from cycle to cycle only at a steady speed: while the speed settles near a shaft
    mode it does not (maruti 4000 -> 1500 rpm: the one-angle term was off by -0.34 N m, 5x the balance's floor;
    design note 69). And why the triangle and not the plain cycle means: within a fired single-cylinder cycle E
    swings by ~13 %, so plain cycle-mean speeds against the torques of one window were off at a fired -> motored
    step (simulated TU/e: 1.5 N m on 0.8); weighting the torques as the energies weight them is exact for a rigid
    shaft. Measured energies and no fitted drift (which biased an earlier per-cycle estimate, design notes §3): the
    term telescopes over a run, a steady run gets no bias, a coast-down or a load step gets the torque that changed
    the speed. acceleration [rad/s^2] is the kinetic term over J(2 pi) (kinetic = J(2 pi) a, as the transient fit
    and the coast-down report take it: core.monitor.balance.transient).

    The load under the same triangle: the previous cycle's late half (``previous.load_late``) and this cycle's
    early half (``load_early``), each from the load readings' own spans (drivers.assembly.cycle_parts.load_mean;
    the caller puts the cycle's mean there where they are not given). When the cycles' means step by more than
    2 % of the rated torque the window's load is still not known well enough (where in a reading's span the step
    fell; the coupling's wind-up) and friction is NaN (that cycle): a step late in this cycle, in the reading after
    its end, now shows in its mean and voids it (deutz two-point s9 cycle 145: +11.8 N m before, design note 76)."""
    nan = float("nan")
    if previous is None or not (math.isfinite(previous.energy) and math.isfinite(energy)):
        return nan, nan, nan, nan, None
    # the windows' first samples and the triangle's weights are fixed by the grid (GridGeometry); the pressures
    # are the monitor's checked ones
    if geometry.window_starts is None or geometry.alone_starts is None or geometry.triangle_previous is None:
        geometry = grid_geometry(spec, cycle.grid)
    x, area = geometry.positions, spec.piston_area
    cur = np.ascontiguousarray(pressure, dtype=np.float64)
    prev = np.ascontiguousarray(previous.pressure, dtype=np.float64)
    (own,), (alone,) = works_with_alone(x, prev, cur, geometry.window_starts, geometry.alone_starts, area)
    kinetic = (energy - previous.energy) / FOUR_PI
    ind = np.asarray(indicated_cycle)
    # the grid's works enter only as the triangle's zero-mean weighting; the two cycles' accurate means carry the
    # level: the 720-point trapezoid reads ~0.5 % below the work the monitor's time grid takes (K9K 1100 rpm:
    # 0.28 N m of indicated torque, 2 % of the friction), a bias the weighting's zero mean cancels
    indicated = 0.5 * (float(ind.sum()) + previous.indicated) + float(
        np.vdot(prev, geometry.triangle_previous) + np.vdot(cur, geometry.triangle_current))
    imep = (ind * FOUR_PI + own - alone) / spec.displacement_cyl
    load_stepped = abs(load - previous.load) > LOAD_STEP_FRACTION * spec.rated_torque_nm
    window_load = 0.5 * (previous.load_late + load_early)
    friction = nan if load_stepped else indicated - window_load - 0.5 * (coupling_loss + previous.coupling_loss) - kinetic
    return friction, kinetic, kinetic / geometry.inertia_mid, indicated, imep


LOAD_STEP_FRACTION = 0.02  # of the rated torque: a larger load change between two cycles voids that balance


def raw_rows(a: np.ndarray, y: np.ndarray, inv_sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The raw rows and targets of one cycle's whitened equations (a zero weight, a row not there: zeros)."""
    scale = np.divide(1.0, inv_sigma, out=np.zeros(inv_sigma.shape, inv_sigma.dtype), where=inv_sigma > 0.0)
    return a * scale[:, None], y * scale


def speed_budget(acc: Accumulator, params: np.ndarray, white, model_rel_error: float,
                 harmonics: np.ndarray) -> np.ndarray:
    """The repeatable-error variance per raw row (R,) of the accumulated equations: for the flywheel's M harmonics,
    the accumulated cycles' persistent residual at ``params`` (less its own sampling variance, var / W per
    component) or ``model_rel_error`` of this cycle's harmonic, whichever is larger; the other rows (the free end's,
    the mean balance) as the noise model states them.

    Not this cycle's noise statistics alone (``white.sys_var``: their 100-cycle EWMA of the residual at the previous
    estimate): after a load ramp that EWMA held the ramp's transient and the systematic sigma of every accumulated
    cycle rose with it (genset-v20, +-20 % profile, seed 29: a cylinder's from ~6 % to 9-17 % 100 cycles after a
    ramp, 17 measured cylinders to 3; design note 35)."""
    r = acc.persistent_residual(params)
    sys_var = np.array(white.sys_var, dtype=np.float64)
    if r is None:
        return sys_var
    m = white.freq.shape[0]
    mean2 = r[:m] ** 2 + r[m:2 * m] ** 2 - 2.0 * white.stats.var / max(acc.raw_weight, 1.0)
    e = model_rel_error * white.freq * np.abs(harmonics)
    v = np.maximum(mean2, e * e) / 2.0
    sys_var[:m] = v
    sys_var[m:2 * m] = v
    return sys_var


def accumulate_cycle(acc: Accumulator, white, forgetting: float, fold: bool, params: np.ndarray,
                     model_rel_error: float, harmonics: np.ndarray) -> tuple[CycleTerms, Accumulator, np.ndarray]:
    """One cycle's accumulation step: (the cycle's terms (the last row, the mean balance, as the reference), the
    accumulator after folding them in with ``forgetting`` and the raw rows when ``fold`` (else ``acc`` itself), the
    speed rows' repeatable-error budget at ``params`` on that accumulator). One kernel call
    (accumulate_kernels.cycle_step_kernel) where ``accumulate_cycle_reference`` makes four helper calls and builds
    two records (design note 63); arrays of another dtype or layout, or shapes that do not fit, take the
    reference (which converts, or names what does not fit)."""
    lam = float(forgetting)
    if not 0.0 <= lam <= 1.0:
        return accumulate_cycle_reference(acc, white, lam, fold, params, model_rel_error, harmonics)
    kept = acc.raw_rows is not None and acc.raw_target is not None
    raw = (acc.raw_rows, acc.raw_target) if kept else (np.empty((0, 0)), np.empty(0))
    raw_weight = (lam * acc.raw_weight + 1.0 if kept else 1.0) if fold else acc.raw_weight
    try:
        ok, terms, arrays, budget = cycle_step_kernel(
            white.a, white.y, white.inv_sigma, lam, bool(fold),
            (acc.info, acc.rhs, acc.sys_map, acc.info_reference, *raw), raw_weight,
            np.asarray(params, dtype=np.float64), (white.sys_var, white.stats.var, white.freq, harmonics),
            float(model_rel_error))
    except TypeError:  # another dtype or layout: the reference converts
        ok = False
    if not ok:
        return accumulate_cycle_reference(acc, white, lam, fold, params, model_rel_error, harmonics)
    info, rhs, yty, sys_map, ref = terms
    terms = CycleTerms(info, rhs, yty, float(white.a.shape[0]), sys_map, ref)
    if fold:
        acc = Accumulator(*arrays[:2], lam * acc.yty + yty, lam * acc.weight + 1.0, lam * acc.rows + terms.rows,
                          *arrays[2:], raw_weight)
    return terms, acc, budget


def accumulate_cycle_reference(acc: Accumulator, white, forgetting: float, fold: bool, params: np.ndarray,
                               model_rel_error: float, harmonics: np.ndarray) -> tuple[CycleTerms, Accumulator,
                                                                                       np.ndarray]:
    """``accumulate_cycle`` by its helpers, one after another (its reference, and the general path)."""
    terms = acc.cycle_terms(white.a, white.y, white.inv_sigma, 1)  # the mean-balance row: reference
    if fold:
        acc = acc.fold(terms, forgetting, raw_rows(white.a, white.y, white.inv_sigma))
    return terms, acc, speed_budget(acc, params, white, model_rel_error, harmonics)


def same_cycles_balance(stats: ResidualStats, fit_total: float) -> float:
    """The mean balance the model-error floor compares the smoothed estimate's total ``fit_total`` [N m] (at this
    cycle's operating point) with: that total plus the fit's mean disagreement with the balance over the same
    recent cycles (``stats.balance_mean``: the noise model's EWMA of each cycle's balance minus the fit's
    total at that cycle's operating point). So both sides stand at the same operating points.

    Not the running mean of the balance itself (``Identification.balance_mean``, the sharing prior's): under a load
    profile that averages every point of the run while the fit's total is this cycle's, and the floor read the
    load dependence of friction as model error (genset-v20, +-20 % profile, seed 29, 2,800 cycles at 0.55 of rated:
    the fit 1,561 N m against the truth's 1,597, the run's mean balance 1,675, a 7.2 % floor on every cylinder, 10
    measured cylinders to 0; bench/second_wheel_trace.py, design note 35). NaN before any statistics."""
    if stats.count == 0 or not math.isfinite(fit_total):
        return float("nan")
    return float(fit_total) + float(stats.balance_mean)


def same_cycles_sigma(stats: ResidualStats, memory: float) -> float:
    """1-sigma [N m] of ``same_cycles_balance``'s disagreement: the EWMA's standard error from the balance
    residual's own scatter (g / (2 - g) of the per-cycle variance, g = max(1 - memory, 1 / count))."""
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
                   free_rows: tuple | None = None) -> Identification:
    """One cycle's identification; ``state`` is the monitor's state before the cycle (not changed). ``free_rows``:
    a second wheel's whitened rows (a, y, inv_sigma, sys_var; core.monitor.identify.free_end_rows), accumulated with
    the flywheel's (the joint fit of both wheels), before the mean-balance row."""
    lam = forgetting_factor(cfg, spec.n_cyl, fly.period)
    sys_balance = ((cfg.balance_rel_error * mean.indicated) ** 2 + (cfg.coupling_rel_error * mean.coupling_loss) ** 2
                   + (cfg.load_rel_error * spec.rated_torque_nm) ** 2)
    noise = NoiseSettings(memory=cfg.noise_memory, model_rel_error=cfg.model_rel_error,
                          use_drift=cfg.drift_nuisance, sys_balance=sys_balance)
    white = whitened_rows(noise, state.stats, fly, rows, state.params, mean.friction, mean.indicated, drift_var)
    if free_rows is not None:  # both wheels: the free end's rows between the flywheel's and the mean balance
        a2, y2, inv2, sys2 = free_rows
        white = replace(white, a=np.concatenate([white.a[:-1], a2, white.a[-1:]]),
                        y=np.concatenate([white.y[:-1], y2, white.y[-1:]]),
                        inv_sigma=np.concatenate([white.inv_sigma[:-1], inv2, white.inv_sigma[-1:]]),
                        sys_var=np.concatenate([white.sys_var[:-1], sys2, white.sys_var[-1:]]))
    terms, acc, budget = accumulate_cycle(state.accumulator, white, lam, state.cycles >= cfg.warmup_cycles,
                                          state.params, cfg.model_rel_error, fly.harmonics)

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
    post_s = posterior_from_normal(acc, *state.prior.with_share(cyl_rows, share_s), budget, state.lower)
    acc_c = Accumulator.of_terms(terms)
    post_c = posterior_from_normal(acc_c, *state.prior.with_share(cyl_rows, share_c), white.sys_var, state.lower)
    limits = ReportLimits(cfg.resolve_rel, cfg.coefficient_snr, cfg.min_data_gain)
    floor, bal_sigma = cfg.model_error_floor, math.sqrt(white.stats.balance_var)
    misfit = state.condition.misfit if state.condition is not None else 1.0  # the window up to the last cycle
    # the floor compares the smoothed estimate with the balance at the same operating points (no balance: NaN)
    same = (same_cycles_balance(white.stats, float(rows.mean_row @ post_s.params)) if math.isfinite(bal_mean)
            else float("nan"))
    check_s = BalanceCheck(ind_mean, same, same_cycles_sigma(white.stats, cfg.noise_memory), mean.coupling_loss,
                           misfit)
    check_c = BalanceCheck(t_i, balance, bal_sigma, mean.coupling_loss, misfit)
    # the calibration's remaining uncertainty (TDC, gain, J) on top: the mean balance passes it into friction whole
    tdc = mean.tdc_sensitivity if mean.tdc_sensitivity is not None else np.zeros(spec.n_cyl)
    cal = cfg.calibration
    est_s = reported_estimate(spec, layout, post_s, exc.basis_mean, share_s.friction_mean, limits, cyl_rows, floor,
                              check_s, cal, CalibrationSensitivity(tdc, ind_mean))
    est_c = reported_estimate(spec, layout, post_c, exc.basis_mean, share_c.friction_mean, limits, cyl_rows, floor,
                              check_c, cal, CalibrationSensitivity(tdc, t_i, mean.kinetic))
    # the smoothed figures drawn by a repeated error the sandwich does not see (one cycle's equations alone fix no
    # data-only point: the cycle's estimate is not checked)
    est_s = with_pull(est_s, cfg.pull_check.sigma(acc, post_s, cyl_rows, share_s.friction_mean), cfg.resolve_rel, spec)
    # the smoothed estimate stands on a balance when one was accumulated, or, during the warm-up (nothing
    # accumulated), when the Eq. 6 share it holds is of a measured running balance; the cycle's on its own
    balanced = float(acc.info_reference.trace()) > 0.0 or (acc.weight == 0.0 and math.isfinite(bal_mean))
    est_s = measured_or_withheld(est_s, _source(balanced))
    est_c = measured_or_withheld(est_c, _source(math.isfinite(balance)))
    return Identification(stats=white.stats, accumulator=acc, indicated_mean=ind_mean, balance_mean=bal_mean,
                          smoothed=post_s, cycle=post_c, smoothed_estimate=est_s, cycle_estimate=est_c, fire=fire,
                          freq=white.freq, drift_col=white.drift_col, cycle_terms=acc_c)
