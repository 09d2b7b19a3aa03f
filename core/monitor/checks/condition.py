"""Engine-condition flags, every cycle (issue 16 item 2, the monitor side), and the change detector's reset.

Flags go into ``CycleResult.flags`` as ``<kind>`` (engine) or ``<kind>_cyl<k>`` (cylinder k, 1-based):

    misfire_cyl<k>           in a fired cycle (some cylinder burned), cylinder k did not burn, or burned partially:
                             its indicated work over the cycle below ``partial_fraction`` of its reference (the
                             median of its burned siblings'; a single cylinder: the EWMA of its own fully burned
                             cycles). Per cycle.
    motored                  (the engine) no cylinder burned this cycle: ignition off, a coast-down, a motored
                             test; a regime, not a misfire (a single cylinder's one unburned cycle reads so too:
                             one cycle cannot tell the two apart)
    A burn is judged from each cylinder's pressure ratio at mirrored angles about its firing TDC (``burn_ratio``).
    blow_by_cyl<k>           compression loss: over the condition window the cylinder's compression rise (pressure
                             at ``late`` over ``early`` degrees before its firing TDC, a ratio: a pressure gain
                             error cancels), its peak pressure AND its indicated work are all below its siblings'
                             beyond the healthy scatter (a pegging offset moves pmax the other way, a lean cylinder
                             keeps its compression, so neither reads as blow-by)
    ring_wear_cyl<k>         blow-by plus that cylinder's friction resolved and above its siblings' by > 2 sigma
    model_misfit             the speed fit's reduced chi^2 over the window beyond what its noise model allows
    condition_change_cyl<k>  the change detector (core.monitor.checks.change) saw cylinder k's friction step (not named
                             within ``settle`` cycles of an operating-point change)
    estimate_reset           (not a condition: an estimator event) after any detected change the accumulated
                             equations are discounted once (Accumulator.discounted), so the smoothed estimate
                             follows the new state instead of averaging the two

The window statistics are EWMAs carried in ``ConditionState`` (core.monitor.state); a flag is decided on each
cycle from the window that ends there, so it stays on while the condition lasts. The sibling comparison uses the
median of the cylinders (a single-cylinder engine has no siblings: no blow-by or ring-wear flag).

The per-cycle numbers come from one kernel (``condition_kernel``, core.monitor.checks.condition_kernels: the levels,
their windows, the combustion flags, the cycle's chi^2, the blow-by and worn-ring tests, the change detector's step
and the ring indicators at the throws' angles) on pressure samples whose grid columns are fixed once per grid
(``condition_tables``, carried in the state); ``assess_condition`` gathers its inputs and names its flags.
``assess_condition_reference`` is the same step by the plain numpy functions beside the kernels
(``compression_rise``, ``burn_ratio``, ``sibling_deviation``, ``_ewma``, ``combustion_flags_reference``,
``cycle_chi2_reduced_reference``, change.detect_change_reference, ring_pressure.ring_indicators_reference):
tests/core/test_condition_step.py compares the two over simulated logs, tests/core/test_condition_kernels.py each
kernel with its piece.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.checks.change import (
    ChangeSettings,
    cusum_limits,
    detect_change_reference,
    detector_after,
    follow_smoothed,
)
from frictionwatch.core.monitor.checks.check import CheckInput, CheckStep
from frictionwatch.core.monitor.checks.condition_kernels import (
    FIRED,
    MOTORED,
    combustion_kernel,
    condition_kernel,
    cycle_chi2_kernel,
)
from frictionwatch.core.monitor.checks.ring_pressure import (
    RingIndicators,
    RingTables,
    ThrowMotion,
    ring_indicators_reference,
    ring_tables,
    ring_windows,
)
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from frictionwatch.core.monitor.identify.identification import Identification
from frictionwatch.core.monitor.identify.posterior import Posterior
from frictionwatch.core.monitor.report.results import FrictionEstimate
from frictionwatch.core.monitor.state import ConditionState, ConditionTables
from frictionwatch.core.tuned import MONITOR_RECORD, read_tuned

FOUR_PI = 4.0 * np.pi
_TUNED = read_tuned(MONITOR_RECORD)  # the floors' hand-set values with their provenance (core.tuned)


@dataclass(frozen=True)
class ConditionSettings:
    """Window and thresholds of the condition flags.

    window: cycles of the EWMA window; warmup: cycles before any window flag.
    early_deg, late_margin_deg: the compression rise is p(late) / p(early), early = ``early_deg`` before the
    cylinder's firing TDC, late = ``late_margin_deg`` before the stated start of combustion, at most ``late_max_deg``
    compression_floor, peak_floor, indicated_floor: the persistent part of a healthy cylinder's deviation from its
    siblings in ln(compression rise), ln(pmax) and ln(indicated torque) that no window average removes (fuel spread,
    heat transfer). Measured on healthy simulator logs (Maruti 3000 rpm 0.8 load, 300 cycles, all default effects,
    2 % COV of IMEP): window means within 0.0011, 0.013 and 0.019, per-cycle scatter 0.015-0.020, 0.016-0.019 and
    0.015-0.021; blow-by (12 % mass loss, cylinder 2) read -0.023, -0.026 and -0.069. A flag needs all three below
    -(floor + ``z_flag`` standard errors of the window mean): a lean or weak cylinder has no compression loss, a
    pressure gain error cancels in the compression rise, a pegging offset raises pmax.
    misfit_excess: the mean reduced chi^2 of the cycle's own fit (``cycle_chi2_reduced``) over ``misfit_window``
    cycles above 1 that flags a model misfit; each cycle's value counts up to ``misfit_cap`` (the 15 wild cycles
    of a load step do not make a window's misfit; a chain 20 % off reads a median of 3..5 on the K9K, a healthy
    log 0.8)
    settle: cycles after an operating-point change (the monitor rebuilt its transfer functions: the mean speed moved
    0.5 %) in which a detected change resets the estimate without being named as the engine's
    ring_sigmas: a worn ring needs the cylinder's friction above its siblings' mean by this many sigmas
    burn_half_deg, burn_log_ratio: a cylinder burned when ln(p(TDC + h) / p(TDC - h)) > burn_log_ratio, h =
    burn_half_deg. Calibrated on TU/e group14 ENGINEOFF, ENGINEOFF2 (motored: -0.13..-0.08), E0NOLOAD1..3 (fired at
    no load: >= 0.61) and simulated 12-cycle logs of every preset (seed 2: misfired cylinders <= -0.009, fired at 5 %
    load >= 0.21, polito-4cyl lowest); tested on the other group14 files (tests/realdata/test_tue_regimes.py).
    partial_fraction: a burned cylinder whose indicated torque over the cycle is below this fraction of its
    reference misfired partially (the firing mask's fraction, core.monitor.identify.parameters; TU/e E0NOLOAD4's partial burn:
    0.14 N m against 2.0-3.0, its weakest full burn 1.45); burn_window: cycles of a single cylinder's reference EWMA.
    The cycle's indicated torque, not its centred IMEP: a cylinder firing late in the cycle has its centred window
    on the combustion of the cycle before, where the burn ratio and this work are of the same combustion
    """

    window: float = 50.0
    warmup: int = 30
    early_deg: float = 100.0
    late_margin_deg: float = 10.0
    late_max_deg: float = 20.0
    compression_floor: float = _TUNED["CONDITION_COMPRESSION_FLOOR"].value
    peak_floor: float = _TUNED["CONDITION_PEAK_FLOOR"].value
    indicated_floor: float = _TUNED["CONDITION_INDICATED_FLOOR"].value
    z_flag: float = 3.0
    misfit_excess: float = 0.5
    misfit_cap: float = 3.0
    misfit_window: float = 100.0
    settle: int = 60
    ring_sigmas: float = 2.0
    burn_half_deg: float = 45.0
    burn_log_ratio: float = _TUNED["CONDITION_BURN_LOG_RATIO"].value
    partial_fraction: float = _TUNED["CONDITION_PARTIAL_FRACTION"].value
    burn_window: float = 50.0
    change: ChangeSettings = ChangeSettings()

    def __post_init__(self) -> None:
        # the condition kernel's limits (burn (3,), the window's floors (3,), the CUSUM's (5,)): constants of the
        # settings, made once here, not three arrays and a call into change.py every cycle. An attribute, not a
        # field (equality and repr see the settings only); the kernels only read them, so one instance serves all
        object.__setattr__(self, "kernel_limits", (
            np.array([self.burn_log_ratio, self.partial_fraction, self.burn_window]),
            np.array([self.compression_floor, self.peak_floor, self.indicated_floor]),
            cusum_limits(self.change)))


DEFAULT_SETTINGS = ConditionSettings()


@dataclass(frozen=True)
class ConditionStep:
    """One cycle's condition: the new state, the flags, the accumulator to carry on (discounted after a change) and
    the pressure-based ring indicators of every cylinder (core.monitor.checks.ring_pressure; for service.alerts)."""

    state: ConditionState
    flags: tuple[str, ...]
    accumulator: Accumulator
    ring: RingIndicators | None = None


def compression_rise(spec: EngineSpec, grid: np.ndarray, pressure: np.ndarray, settings: ConditionSettings
                     ) -> np.ndarray:
    """(z,) ln(p(late) / p(early)) of each cylinder before its firing TDC (NaN where a pressure is not positive)."""
    late = min(settings.late_max_deg, settings.late_margin_deg - spec.combustion.start_deg)
    return log_pressure_ratio(spec, grid, pressure, -settings.early_deg, -late)


def log_pressure_ratio(spec: EngineSpec, grid: np.ndarray, pressure: np.ndarray, first_deg: float,
                       second_deg: float) -> np.ndarray:
    """(z,) ln(p(second) / p(first)) of each cylinder at two angles [deg] from its firing TDC (NaN where a pressure
    is not positive): linear interpolation on the uniform periodic grid, every cylinder at once (np.interp sorts per
    call)."""
    n = grid.shape[0]
    pos = np.mod(np.radians([first_deg, second_deg])[None, :] + spec.firing_angles[:, None] - grid[0],
                 FOUR_PI) * (n / FOUR_PI)
    i = np.floor(pos)
    frac = pos - i
    i = i.astype(np.int64) % n
    rows = np.arange(spec.n_cyl)[:, None]
    p = pressure[rows, i] * (1.0 - frac) + pressure[rows, (i + 1) % n] * frac  # (z, 2): first, second
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((p[:, 0] > 0) & (p[:, 1] > 0), np.log(p[:, 1] / p[:, 0]), np.nan)


def burn_ratio(spec: EngineSpec, grid: np.ndarray, pressure: np.ndarray, half_deg: float) -> np.ndarray:
    """(z,) ln(p(TDC + half_deg) / p(TDC - half_deg)) of each cylinder about its firing TDC: a pressure ratio at
    mirrored crank angles (the volumes are equal, so a gain error cancels). Without a burn the expansion side is
    lower (heat loss, blow-by): slightly negative; any burn raises it. NaN where a pressure is not positive."""
    return log_pressure_ratio(spec, grid, pressure, -half_deg, half_deg)


def combustion_flags_reference(burn: np.ndarray, work: np.ndarray, reference: np.ndarray, cycles: np.ndarray,
                               settings: ConditionSettings) -> tuple[list[str], np.ndarray, np.ndarray]:
    """This cycle's ``motored`` / ``misfire_cyl<k>`` flags (module docstring) from each cylinder's burn ratio (z,)
    and indicated torque (z,) [N m], and the burn reference (z,) [N m] with its cycle counts carried on (updated by
    the cylinders that burned fully): the plain reference of ``combustion_flags``."""
    z = burn.shape[0]
    judged = np.isfinite(burn)
    burned = judged & (burn > settings.burn_log_ratio)
    if not burned.any():
        return (["motored"] if judged.any() else []), reference, cycles
    flags: list[str] = []
    full = np.zeros(z, dtype=np.bool_)
    for k in range(z):
        if judged[k] and not burned[k]:
            flags.append(f"misfire_cyl{k + 1}")
            continue
        if not burned[k]:
            continue
        others = [work[j] for j in range(z) if j != k and burned[j]]
        ref = float(np.median(others)) if others else float(reference[k])
        if math.isfinite(ref) and ref > 0 and work[k] < settings.partial_fraction * ref:
            flags.append(f"misfire_cyl{k + 1}")
        else:
            full[k] = True
    cycles = cycles + full
    g = np.maximum(1.0 / settings.burn_window, 1.0 / np.maximum(cycles, 1))
    reference = np.where(full, np.where(np.isfinite(reference), reference + g * (work - reference), work), reference)
    return flags, reference, cycles


def sibling_deviation(x: np.ndarray) -> np.ndarray:
    """(z,) x_k against its siblings: minus the median of all cylinders (z >= 3: one faulty cylinder leaves the
    median on the healthy ones, so they read 0), minus the other cylinder (z = 2), 0 for a single cylinder."""
    z = x.shape[0]
    if z < 2:
        return np.zeros(z)
    return x - x[::-1] if z == 2 else x - np.median(x)


def _ewma(mean: np.ndarray, var: np.ndarray, x: np.ndarray, g: float, first: bool) -> tuple[np.ndarray, np.ndarray]:
    """EWMA mean and variance about it (the first value starts both); NaN inputs leave the entry unchanged."""
    if first:
        return np.where(np.isfinite(x), x, 0.0), np.zeros_like(x)
    d = np.where(np.isfinite(x), x - mean, 0.0)
    return mean + g * d, (1.0 - g) * (var + g * d * d)


def _after_alarm(alarm: np.ndarray, settled: bool, accumulator, settings: ConditionSettings, flags: list[str]):
    """The accumulator after the change detector's ``alarm`` (z,) bool, discounted when any cylinder alarmed, and its
    flags appended to ``flags``: the estimate follows either way; a change right after an operating-point change
    (not ``settled``) is not named as the engine's (the per-cylinder scales of a model of another shape move with
    the load, too)."""
    if not alarm.any():
        return accumulator
    if settled:
        flags += [f"condition_change_cyl{k + 1}" for k in np.flatnonzero(alarm)]
    flags.append("estimate_reset")
    return accumulator.discounted(min(1.0, settings.change.reset_weight / max(accumulator.weight, 1e-9)))


def assess_condition(spec: EngineSpec, state: ConditionState | None, grid: np.ndarray, pressure: np.ndarray,
                     indicated: np.ndarray, pmax: np.ndarray, ident: Identification, cylinder_rows: np.ndarray,
                     op_changed: bool, settings: ConditionSettings = DEFAULT_SETTINGS,
                     motion: ThrowMotion | None = None) -> ConditionStep:
    """This cycle's condition flags from its pressure (z, n) on ``grid``, indicated torques (z,) [N m], peak
    pressures (z,), the cycle's identification (firing mask, the cycle's and the smoothed posteriors and estimate,
    the accumulator just folded, returned discounted when a change is detected), the cylinder rows (z, p_f) that
    turn the friction parameters into per-cylinder torques, and whether the operating point changed this cycle;
    ``motion``: the throws' motion against the flywheel this cycle (the ring indicators read each cylinder at its
    own throw's angle; None: at the flywheel's). ``assess_condition_reference``'s numbers by one kernel
    (``condition_kernel``: the levels, window, combustion flags, the cycle's chi^2, blow-by and worn-ring tests,
    the change detector's step and the ring indicators); here only its inputs gathered and its flags named
    (tests/core/test_condition_kernels.py: flags equal, numbers within rtol 1e-9 over simulated logs)."""
    fired, cycle, smoothed = ident.fire, ident.cycle, ident.smoothed
    estimate, accumulator, terms = ident.smoothed_estimate, ident.accumulator, ident.cycle_terms
    z = spec.n_cyl
    st = ConditionState.empty(z) if state is None else state
    tab = st.tables
    if tab is None or not tab.fits(grid, _table_key(settings)):
        tab = condition_tables(spec, grid, settings)
    p = np.ascontiguousarray(pressure, dtype=np.float64)
    if p.shape != (z, tab.size):
        raise ValueError(f"pressure must have shape ({z}, {tab.size}) on the cycle's grid; got {p.shape}")
    g = max(1.0 / settings.window, 1.0 / (st.count + 1))
    first = st.count == 0
    # a misfiring cycle is a known, flagged event: it would read as a step in every sibling statistic
    use = bool(fired.all())
    count = st.count + 1 if use else st.count
    # an operating-point change (a load step) is a transient the noise model has not learnt yet: the innovations
    # move for a while without anything wrong with the engine
    since_op = 0 if op_changed else st.since_op_change + 1
    det = follow_smoothed(st.detector, smoothed.params, cylinder_rows)
    ref0 = st.burn_reference if st.burn_reference is not None else np.full(z, np.nan)
    n0 = st.burn_cycles if st.burn_cycles is not None else np.zeros(z, dtype=np.int64)
    ring_tab = tab.ring
    ring_on = ring_tab is not None
    moved = ring_on and motion is not None and ring_tab.local is not None
    if not ring_on:  # the kernel's one signature: the ring arguments stand in, unread
        ring_tab = RingTables(0.0, 0, np.zeros((z, 1), dtype=np.int64), np.zeros((z, 1)), np.zeros(1), 1, 1)
    with_terms = terms is not None
    out = condition_kernel(
        (p, tab.cols, tab.frac, _c(pmax), _c(indicated)),
        (st.window, ref0, n0, det.mean, det.var, det.sums),
        (_c(estimate.friction_torque_mean), _c(estimate.friction_torque_mean_sigma),
         np.ascontiguousarray(estimate.resolved, dtype=np.bool_)),
        (_c(cycle.params), _c(smoothed.params), _c(cylinder_rows), _c(terms.rhs if with_terms else cycle.params),
         _c(terms.info if with_terms else cycle.cov_statistical), _c(cycle.cov_statistical)),
        (_c(grid), ring_tab.cols, ring_tab.frac, ring_tab.local if moved else ring_tab.neg_log_volume,
         ring_tab.neg_log_volume, np.array([ring_tab.n_comp, ring_tab.edge], dtype=np.int64), _c(spec.firing_angles),
         _c(motion.static) if moved else np.zeros(z),
         np.ascontiguousarray(motion.relative, dtype=np.complex128) if moved else np.zeros((z, 1), np.complex128)),
        settings.kernel_limits,
        np.array([use, first, count >= settings.warmup, with_terms, det.count, det.quiet, ring_on, moved],
                 dtype=np.int64),
        np.array([g, settings.z_flag, settings.ring_sigmas, settings.misfit_cap,
                  float(terms.yty) if with_terms else 0.0, float(terms.rows) if with_terms else 0.0,
                  float(cycle.chi2_reduced), settings.change.rel_floor,
                  float(motion.theta_start) if moved else 0.0]))
    window, status, misfire, burn_ref, burn_n, chi2, wear, change, mean, var, sums, alarm, ring_out = out
    g_misfit = max(1.0 / settings.misfit_window, 1.0 / (st.count + 1))
    misfit = chi2 if first else st.misfit + g_misfit * (chi2 - st.misfit)
    # the flags named off Python lists (np.flatnonzero's dispatch was ~3 us a call)
    if status == FIRED:
        flags = [f"misfire_cyl{k + 1}" for k, m in enumerate(misfire.tolist()) if m]
    else:
        flags = ["motored"] if status == MOTORED else []
    for k, w in enumerate(wear.tolist()):
        if w:
            flags.append(f"blow_by_cyl{k + 1}")
            if w == 2:
                flags.append(f"ring_wear_cyl{k + 1}")
    if st.count >= settings.warmup and misfit > 1.0 + settings.misfit_excess:
        flags.append("model_misfit")
    detector = detector_after(det, change, mean, var, sums, settings.change)
    acc = _after_alarm(alarm, since_op > settings.settle, accumulator, settings, flags)
    new = ConditionState(count=count, window=window, misfit=misfit, detector=detector, since_op_change=since_op,
                         burn_reference=burn_ref, burn_cycles=burn_n, tables=tab)
    ring = None
    if ring_on:
        ring = RingIndicators(compression_pa=ring_out[0], compression_ratio=ring_out[1], n_compression=ring_out[2],
                              n_expansion=ring_out[3], n_compression_dev=ring_out[4], n_expansion_dev=ring_out[5],
                              expansion_deficit=ring_out[6])
    return ConditionStep(new, tuple(flags), acc, ring)


def assess_condition_reference(spec: EngineSpec, state: ConditionState | None, grid: np.ndarray,
                               pressure: np.ndarray, indicated: np.ndarray, pmax: np.ndarray, ident: Identification,
                               cylinder_rows: np.ndarray, op_changed: bool,
                               settings: ConditionSettings = DEFAULT_SETTINGS,
                               motion: ThrowMotion | None = None) -> ConditionStep:
    """The plain reference of ``assess_condition`` (the same arguments and result): each number by the numpy function
    the module names, one step after another."""
    fired, cycle, smoothed = ident.fire, ident.cycle, ident.smoothed
    estimate, accumulator = ident.smoothed_estimate, ident.accumulator
    z = spec.n_cyl
    st = ConditionState.empty(z) if state is None else state
    tab = st.tables
    if tab is None or not tab.fits(grid, _table_key(settings)):
        tab = condition_tables(spec, grid, settings)
    g = max(1.0 / settings.window, 1.0 / (st.count + 1))
    first = st.count == 0
    work = np.ascontiguousarray(indicated, dtype=np.float64)
    # ln compression rise, ln pmax, ln indicated torque and the burn ratio of each cylinder: (4, z)
    levels = np.array([compression_rise(spec, grid, pressure, settings), np.log(np.maximum(pmax, 1.0)),
                       np.log(np.maximum(work, 1e-9)), burn_ratio(spec, grid, pressure, settings.burn_half_deg)])
    # a misfiring cycle is a known, flagged event: it would read as a step in every sibling statistic
    use = fired.all()
    if use:
        rows = [_ewma(st.window[0, r], st.window[1, r], sibling_deviation(levels[r]), g, first) for r in range(3)]
        window = np.stack([np.stack([m for m, _ in rows]), np.stack([v for _, v in rows])])
    else:
        window = st.window
    # an operating-point change (a load step) is a transient the noise model has not learnt yet: the innovations
    # move for a while without anything wrong with the engine
    since_op = 0 if op_changed else st.since_op_change + 1
    settled = since_op > settings.settle
    chi2 = min(cycle_chi2_reduced_reference(ident.cycle_terms, cycle), settings.misfit_cap)  # a few wild cycles cannot
    # make a window's misfit
    g_misfit = max(1.0 / settings.misfit_window, 1.0 / (st.count + 1))
    misfit = chi2 if first else st.misfit + g_misfit * (chi2 - st.misfit)
    ref0 = st.burn_reference if st.burn_reference is not None else np.full(z, np.nan)
    n0 = st.burn_cycles if st.burn_cycles is not None else np.zeros(z, dtype=np.int64)
    flags, burn_ref, burn_n = combustion_flags_reference(levels[3], work, ref0, n0, settings)
    count = st.count + 1 if use else st.count
    if count >= settings.warmup and z > 1:
        se = np.sqrt(g / (2.0 - g))  # standard error of an EWMA mean per unit of scatter
        floors = np.array([[settings.compression_floor], [settings.peak_floor], [settings.indicated_floor]])
        low = window[0] < -(floors + settings.z_flag * se * np.sqrt(window[1]))  # (3, z); blow-by: all three
        for k in np.flatnonzero(low.all(axis=0)):
            flags.append(f"blow_by_cyl{k + 1}")
            if _friction_up(estimate, k, settings.ring_sigmas):
                flags.append(f"ring_wear_cyl{k + 1}")
    if st.count >= settings.warmup and misfit > 1.0 + settings.misfit_excess:
        flags.append("model_misfit")

    detector, alarm = detect_change_reference(st.detector, cycle, smoothed, cylinder_rows, settings.change)
    acc = _after_alarm(alarm, settled, accumulator, settings, flags)
    new = ConditionState(count=count, window=window, misfit=misfit, detector=detector, since_op_change=since_op,
                         burn_reference=burn_ref, burn_cycles=burn_n, tables=tab)
    ring = None
    if tab.ring is not None:
        ring = ring_indicators_reference(spec, grid, pressure, motion=motion)
    return ConditionStep(new, tuple(flags), acc, ring)


class ConditionCheck:
    """The condition flags as one of the monitor's checks (core.monitor.checks.check): ``assess_condition`` with
    ``settings`` (the module's thresholds); the accumulator it discounts after a detected change goes on in the
    identification, the ring indicators into the result (``ring``).

    >>> ConditionCheck().name, ConditionCheck().settings.window
    ('condition', 50.0)
    """

    name = "condition"

    def __init__(self, settings: ConditionSettings = DEFAULT_SETTINGS):
        self.settings = settings

    def update(self, state: ConditionState | None, inp: CheckInput) -> CheckStep:
        ident = inp.ident
        step = assess_condition(inp.spec, state, inp.grid, inp.pressure, inp.balance.excitation.indicated_mean,
                                inp.pmax, ident, inp.cylinder_rows, inp.op_changed, self.settings, motion=inp.motion)
        # the identification as it was unless a change discounted its accumulator (a replace per cycle cost ~1 %)
        out = ident if step.accumulator is ident.accumulator else replace(ident, accumulator=step.accumulator)
        return CheckStep(step.state, step.flags, out, {"ring": step.ring})


def condition_tables(spec: EngineSpec, grid: np.ndarray, settings: ConditionSettings = DEFAULT_SETTINGS
                     ) -> ConditionTables:
    """The columns and fractions of the four angles on ``grid`` (n,) [rad], ``log_pressure_ratio``'s arithmetic."""
    late = min(settings.late_max_deg, settings.late_margin_deg - spec.combustion.start_deg)
    deg = np.array([-settings.early_deg, -late, -settings.burn_half_deg, settings.burn_half_deg])
    n = grid.shape[0]
    pos = np.mod(np.radians(deg)[None, :] + spec.firing_angles[:, None] - grid[0], FOUR_PI) * (n / FOUR_PI)
    i = np.floor(pos)
    frac = np.ascontiguousarray(pos - i)
    try:
        ring = ring_tables(spec, grid, ring_windows(spec))
    except ValueError:
        ring = None  # the engine's valve timing leaves no room for the ring indicators' windows
    return ConditionTables(float(grid[0]), int(n), _table_key(settings), i.astype(np.int64) % n, frac, ring)


def _c(a: np.ndarray) -> np.ndarray:
    """``a`` as a C-ordered float64 array (itself when it is one): the condition kernel's one signature."""
    return np.ascontiguousarray(a, dtype=np.float64)


def _table_key(settings: ConditionSettings) -> tuple[float, ...]:
    """The settings the tables depend on."""
    return (settings.early_deg, settings.late_margin_deg, settings.late_max_deg, settings.burn_half_deg)


def combustion_flags(burn: np.ndarray, work: np.ndarray, reference: np.ndarray, cycles: np.ndarray,
                     settings: ConditionSettings) -> tuple[list[str], np.ndarray, np.ndarray]:
    """This cycle's ``motored`` / ``misfire_cyl<k>`` flags (module docstring) from each cylinder's burn ratio (z,)
    and indicated torque (z,) [N m], and the burn reference (z,) [N m] with its cycle counts carried on (updated by
    the cylinders that burned fully): ``combustion_flags_reference``'s numbers by one kernel (``combustion_kernel``;
    its siblings' medians and masks were ~15 numpy calls, 23 us per genset-v20 cycle)."""
    status, misfire, new_reference, new_cycles = combustion_kernel(
        np.ascontiguousarray(burn, dtype=np.float64), np.ascontiguousarray(work, dtype=np.float64),
        np.ascontiguousarray(reference, dtype=np.float64), np.ascontiguousarray(cycles, dtype=np.int64),
        np.array([settings.burn_log_ratio, settings.partial_fraction, settings.burn_window]))
    if status != FIRED:
        return (["motored"] if status == MOTORED else []), reference, cycles
    return [f"misfire_cyl{k + 1}" for k in np.flatnonzero(misfire)], new_reference, new_cycles


def cycle_chi2_reduced(terms: Accumulator | None, post: Posterior) -> float:
    """This cycle's chi^2 at its posterior over its effective degrees of freedom rows - tr(H), H the hat matrix:
    tr(H) = tr(info_data cov) counts only the parameters the cycle's data determine, not those its priors hold.
    The posterior's own chi2_reduced divides by rows - P: on genset-v20 (49 rows, 47 parameters, most held by the
    priors) that is 2 and a healthy cycle read 5..19 (the false model_misfit of the demo log, cycles 30-39); over
    rows - tr(H) the same residuals read below 1. Without the terms: the posterior's own value.
    ``cycle_chi2_reduced_reference``'s numbers by one kernel (its six numpy calls were ~14 us a genset-v20 cycle)."""
    if terms is None:
        return float(post.chi2_reduced)
    return float(cycle_chi2_kernel(float(terms.yty), float(terms.rows), post.params, terms.rhs, terms.info,
                                    post.cov_statistical, float(post.chi2_reduced)))


def cycle_chi2_reduced_reference(terms: Accumulator | None, post: Posterior) -> float:
    """``cycle_chi2_reduced`` by numpy."""
    if terms is None:
        return float(post.chi2_reduced)
    p = post.params
    chi2 = float(terms.yty - 2.0 * p @ terms.rhs + p @ terms.info @ p)
    unscaled = post.cov_statistical / max(1.0, post.chi2_reduced)  # the posterior scales it by chi2_reduced
    dof = terms.rows - float(np.sum(terms.info * unscaled.T))
    return chi2 / dof if dof > 0 else 1.0


def _friction_up(est: FrictionEstimate, k: int, sigmas: float) -> bool:
    """Cylinder k's smoothed friction resolved and above its siblings' mean by ``sigmas`` combined sigmas."""
    t, s = est.friction_torque_mean, est.friction_torque_mean_sigma
    if not est.resolved[k]:
        return False
    others = [j for j in range(t.shape[0]) if j != k and est.resolved[j]]
    if not others:
        return False
    excess = t[k] - float(np.mean(t[others]))
    return bool(excess > sigmas * math.sqrt(s[k] ** 2 + float(np.mean(s[others] ** 2)) / len(others)))
