"""Watching TDC while the engine runs, the window's reading: each cylinder's TDC from its own pressure, window by
window, against what the model's calibration says (issue 25 items 2-3: a hidden TDC error is flagged, never a
confident figure).

Every cycle adds each cylinder's pressure about its firing TDC to one of ``BLOCKS`` running block sums
(core.monitor.calibration.tdc_watch.watch_cycle, the per-cycle step, and the watch's state); every
``window`` cycles (100) the thermodynamic fit (core.monitor.calibration.tdc.tdc_from_pressure) runs on the block
means (the fit is on a mean cycle anyway; the blocks give its statistical sigma) and the sums start again: on every
cylinder of a small engine, on four in turn of a large one (each keeps its newest estimate). The cost is one fit of
BLOCKS traces per cylinder fitted, not a fit per cycle.

What is flagged (flags ``sensor_tdc_offset`` for the wheel, ``sensor_tdc_offset_cyl<k>`` for a cylinder's own; the
``sensor_`` prefix withholds the figures they touch, core.monitor.report.figure_status):
- uncalibrated model: the wheel's TDC found beyond ``UNCALIBRATED_SIGMAS`` of the found sigma and the assumed
  installation's (core.model.calibration) together: the data contradict what the sigma assumes;
- commissioned model (its TDC corrections applied, so the expected reading is 0): the wheel found beyond
  ``DRIFT_SIGMAS`` of the window's statistical sigma and ``OPERATING_POINT_DEG``, the method's systematic part being
  the same as at commissioning except for what a change of operating point moves (healthy simulated engines read
  -0.17 to +0.05 deg at different points: k9k, genset-v20);
- a cylinder's own offset (its TDC less the median of all) beyond ``DRIFT_SIGMAS`` of its statistical sigma and the
  calibration's per-cylinder sigma, and beyond ``MIN_FLAG_DEG``; on a commissioned model that kept what it read of
  each cylinder (core.model.calibration ``tdc_cylinder_reading_deg``), its own offset less that reading, beyond
  ``DRIFT_SIGMAS`` of both readings' statistical sigmas and ``OPERATING_POINT_DEG``, and beyond ``MIN_FLAG_DEG``:
  the pressure method's own bias on a cylinder is the same at commissioning and while running.
- commissioned model, also: a cylinder's own offset changed since the run's first reading of it (``own_offsets``)
  beyond ``DRIFT_SIGMAS`` of both windows' statistical sigmas and ``OPERATING_POINT_DEG``, and beyond
  ``MIN_FLAG_DEG``: the method's own bias on that cylinder is the same then and now and cancels, where the absolute
  rule above must allow the commissioning's per-cylinder sigma (genset-v20: 0.14 deg, so 3 sigma = 0.42 deg, and a
  0.5 deg drift from cycle 300 read +0.40 to +0.44; bench/sensor_drift.py).
A flag holds until a window says otherwise. Three or more cylinders are needed for a cylinder's own flag.

A large engine's cylinders take turns after the first window, which on a commissioned model fits all (below), so a
cylinder's TDC was fitted up to z / CYLINDERS_PER_WINDOW windows ago (genset-v20: 500 cycles; a 0.5 deg drift from cycle
300 went unfitted to cycle 599, a wheel slip was judged on a median of mostly old estimates to cycle 599 and meanwhile
named the freshly fitted cylinders). So every window also screens the cylinders out of turn: the shift of its mean
compression stroke against the cylinder's trace at its last fit (``screen_shift``, the static twist's change added
back), and a cylinder that moved by more than ``SCREEN_DEG`` is fitted in this window too; one that moved less keeps its
last fit moved by the screen's shift, so every estimate refers to the newest window (a wheel slipping mid-window, half
of it in the window, screened some cylinders and not others: the stale ones beside the fresh read as own offsets,
genset-v20 cylinder 15 flagged). The screen costs a small least-squares solve per cylinder; a screen that fires costs a
fit, never a flag. Where the screens of most cylinders fire at once (the wheel moved), every cylinder is fitted: a
screen is a trigger, and reads a shift short (its scale column and the shift are nearly collinear over the compression
stroke). A second trigger (``own_drift``) sums each cylinder's shift against the last window's trace, without a scale
column, less the median of all cylinders' (a load change's charge pressure reads as a shift alike on every cylinder),
from its last fit on: one cylinder's step fires it in the window it shows in.

The static twist of the drive train (the monitor's model of it, MonitorState.static) puts a loaded throw ahead of the
flywheel the pressure is sampled against: its thermodynamic TDC reads early by that twist (healthy k9k at full load:
-0.29 to -0.08 deg on a flexible crank, -0.05 on a rigid one; genset-v20 to -0.52). The monitor already models it,
so the watch adds the window's mean twist back before judging: a twist is not a sensor error.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.calibration.tdc import BLOCKS, TdcEstimate, tdc_from_pressure
from frictionwatch.core.monitor.calibration.tdc_smoothing import smoothing
from frictionwatch.core.monitor.calibration.tdc_watch import CYLINDERS_PER_WINDOW, TdcWatchState
from frictionwatch.core.tuned import MONITOR_RECORD, read_tuned

# 1.5: chosen on bench/calibration_coverage.py's k9k 1700 rpm / 1.0 and maruti 3000 rpm / 0.8 rows (seed 5): at 2.0
# the maruti's +-1.5 deg wheels read at 2.0-2.1 sigma unflagged; at 1.5 they are flagged and no healthy row is.
# Tested on the other rows (k9k 2500 / 0.5, maruti 2000 / 0.4, deutz, genset-v20) and in tests/core/test_tdc_watch.py
UNCALIBRATED_SIGMAS = read_tuned(MONITOR_RECORD)["TDC_UNCALIBRATED_SIGMAS"].value  # hand-set (core.tuned)
DRIFT_SIGMAS = 3.0
OPERATING_POINT_DEG = 0.1
MIN_FLAG_DEG = 0.3  # SensorHealthConfig.tdc_deg: a smaller TDC error is carried in the sigma, not flagged
# the screen of a large engine's cylinders that are not fitted in a window: a shift of the compression stroke against
# the cylinder's trace at its last fit beyond this (half the smallest flagged error, so a change that can be flagged
# is fitted at once; a screen that fires only costs a fit: the flag rule is the fit's, unchanged)
SCREEN_DEG = 0.5 * MIN_FLAG_DEG
SCREEN_FROM_DEG = -70.0  # the screen's stretch of the compression stroke: from here to BEFORE_SOC_DEG before the SOC
SCREEN_BEFORE_SOC_DEG = 10.0


def close_window(spec: EngineSpec, cal: Calibration, state: TdcWatchState, angle: np.ndarray | None = None,
                 per_window: int = CYLINDERS_PER_WINDOW, fit: Callable[..., TdcEstimate] | None = None
                 ) -> TdcWatchState:
    """The window's fits and flags on what ``state`` has gathered (the pipeline's TdcWatch stage calls it when a window
    is full; a run that ends mid-window may call it to read what it has): a new state, the sums started again. ``angle``
    the traces' local angle (None: the state's cut's); ``fit`` gives tdc_from_pressure's answers (an offline caller's
    memo, core.monitor.calibration.tdc_memo; None: tdc_from_pressure itself). Fewer than BLOCKS pairs gathered:
    ``state`` as it is."""
    if state.sums is None or state.cycles < BLOCKS:
        return state
    if angle is None:
        if state.cut is None or state.cut.angle.shape[0] != state.sums[0].shape[-1]:
            return state
        angle = state.cut.angle
    sums, counts, n, omega, twist_sum, cycle = (state.sums, state.counts, state.cycles, state.omega_sum,
                                                state.twist_sum, state.previous)
    block_sums = np.stack(sums)  # (BLOCKS, z, n_local)
    means = block_sums / np.maximum(counts, 1)[:, None, None]
    twist_mean = np.broadcast_to(twist_sum / n, (spec.n_cyl,))
    z = spec.n_cyl
    # this window's cylinders: all of a small engine, CYLINDERS_PER_WINDOW in turn on a large one (each keeps its
    # newest estimate; the wheel, their median, is known after the first window), and on a large one any other
    # cylinder whose compression stroke moved against its trace at its last fit (``screen_shift``): a TDC that
    # drifts is fitted in the window it shows in, not up to z / CYLINDERS_PER_WINDOW windows later
    mean_trace = np.sum(block_sums, axis=0) / max(float(np.sum(counts)), 1.0)
    # A commissioned model's first window fits every cylinder, also of a large engine (once a run, ~40 ms on
    # genset-v20): its own offsets and the change rule's first readings are then against the median of all, not of
    # the four fitted so far (genset-v20 cylinder 8 read -0.18 deg against four and -0.36 against twenty, design note
    # 40), and every cylinder has a trace for the screen from the second window on. An uncalibrated model's limits
    # (3 x the assumed 0.2 deg per cylinder and more) are wide beside that bias, and there it would cost a 400-cycle
    # run 0.1 ms per cycle (genset-v20, design note 45)
    first_window = state.fitted is None and cal.commissioned
    turn = list(range(z)) if z <= per_window or first_window \
        else [(state.next_cylinder + i) % z for i in range(per_window)]
    screened: list[int] = []
    moved = np.zeros(z)  # each unfitted cylinder's shift since its last fit [rad] (the screen's; 0: none read)
    moved_sigma = np.zeros(z)  # and its 1 sigma [rad]
    ref, ref_twist = state.reference, state.reference_twist
    drift = own_drift(state, mean_trace, twist_mean, angle, spec) if z > per_window else np.zeros(z)
    if z > per_window and ref is not None and ref.shape == mean_trace.shape and ref_twist is not None:
        for k in range(z):
            if k in turn or not np.all(np.isfinite(ref[k])):
                continue
            shift, shift_sigma = screen_shift(ref[k], mean_trace[k], angle, spec)
            shift += float(twist_mean[k] - ref_twist[k])
            if abs(shift) > math.radians(SCREEN_DEG) or abs(drift[k]) > math.radians(SCREEN_DEG):
                screened.append(k)
            elif math.isfinite(shift):
                moved[k], moved_sigma[k] = shift, shift_sigma if math.isfinite(shift_sigma) else 0.0
    others = [k for k in range(z) if k not in turn]
    if others and 2 * len(screened) > len(others):
        # most cylinders moved at once: the wheel moved (a common cause), and a screen that stayed under SCREEN_DEG
        # is not a reading of how far: the screen reads a shift short (its reference's noise in its own gradient;
        # genset-v20, a 0.5 deg wheel step: 15 of 16 screens fired, cylinder 20's read 0.13 and 0.12 deg, and its
        # moved estimate stood 0.3 deg behind the others' fresh fits, read as its own offset and flagged). So every
        # cylinder is fitted in this window (~55 ms on genset-v20, once per such event)
        screened = others
        moved[:], moved_sigma[:] = 0.0, 0.0
    if ref is None or ref.shape != mean_trace.shape:
        ref, ref_twist = np.full(mean_trace.shape, np.nan), np.zeros(z)
    ref, ref_twist = ref.copy(), np.array(ref_twist, dtype=np.float64)
    fitted = list(state.fitted) if state.fitted is not None else [None] * z
    # the smoothing operator once a close, not once a fitted cylinder (its step as tdc_from_pressure reads it)
    operator = smoothing(float(np.diff(np.asarray(angle, dtype=np.float64).ravel()).mean())) \
        if np.size(angle) > 1 else None
    for k in turn + screened:
        ref[k], ref_twist[k], drift[k] = mean_trace[k], float(twist_mean[k]), 0.0
        try:
            e = (fit or tdc_from_pressure)(means[:, k, :], angle, spec, omega / n, operator=operator)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            fitted[k] = None
            continue
        fitted[k] = dataclasses.replace(e, offset_rad=e.offset_rad + float(twist_mean[k]))
    # an unfitted cylinder's estimate is its last fit moved by the screen's shift since: every estimate refers to
    # this window (a wheel that slipped mid-window, half of it in the window, moves the screened cylinders' fits and
    # the unscreened ones' alike; a stale estimate beside fresh ones read as that cylinder's own offset)
    estimates = [None if e is None else moved_by(e, float(moved[k]), float(moved_sigma[k]))
                 for k, e in enumerate(fitted)]
    nxt = state.next_cylinder if first_window else (state.next_cylinder + len(turn)) % z
    first = own_offsets(estimates) if state.first_own is None else state.first_own.copy()
    if state.first_own is not None:  # a cylinder read for the first time keeps that reading
        now = own_offsets(estimates)
        new = ~np.isfinite(first[0]) & np.isfinite(now[0])
        first[:, new] = now[:, new]
    return TdcWatchState(None, np.zeros(BLOCKS), 0, cycle, tuple(estimates), tdc_flags(cal, estimates, first), 0.0,
                         0.0, nxt, first, ref, ref_twist, tuple(screened), tuple(fitted), mean_trace,
                         np.array(twist_mean, dtype=np.float64), drift, state.cut)


def moved_by(fit: TdcEstimate, shift: float, sigma: float) -> TdcEstimate:
    """A cylinder's last fit moved by the screen's ``shift`` since [rad] and carrying the screen's ``sigma`` [rad]
    in its statistical part (and so in its whole sigma); the fit itself where nothing was moved."""
    if shift == 0.0 and sigma == 0.0:
        return fit
    stat_deg = math.hypot(float(fit.evidence.get("statistical_deg", 0.0)), math.degrees(sigma))
    return dataclasses.replace(fit, offset_rad=fit.offset_rad + shift, sigma_rad=math.hypot(fit.sigma_rad, sigma),
                               evidence={**fit.evidence, "statistical_deg": stat_deg,
                                         "screen_sigma_deg": math.degrees(sigma)})


def own_offsets(estimates: list[TdcEstimate | None]) -> np.ndarray:
    """(2, z): each cylinder's own offset (its offset less the median of all found) and its statistical sigma [rad];
    NaN where not found or fewer than three cylinders are."""
    z = len(estimates)
    out = np.full((2, z), np.nan)
    found = [k for k, e in enumerate(estimates) if e is not None]
    if len(found) < 3:
        return out
    offsets = np.array([estimates[k].offset_rad for k in found])
    out[0, found] = offsets - float(np.median(offsets))
    out[1, found] = [math.radians(estimates[k].evidence.get("statistical_deg", 0.0)) for k in found]
    return out


def _stretch(angle: np.ndarray, spec: EngineSpec) -> np.ndarray | None:
    """The screens' stretch of the local grid ``angle`` [rad]: the compression stroke from SCREEN_FROM_DEG (or the
    IVC, if later) to SCREEN_BEFORE_SOC_DEG before the combustion's start, as a mask; None where it has < 8 samples."""
    deg = np.degrees(angle)
    hi = min(spec.combustion.start_deg - SCREEN_BEFORE_SOC_DEG, -SCREEN_BEFORE_SOC_DEG)
    sel = (deg >= max(SCREEN_FROM_DEG, spec.combustion.ivc_deg)) & (deg <= hi)
    return sel if np.count_nonzero(sel) >= 8 else None


def screen_shift(reference: np.ndarray, trace: np.ndarray, angle: np.ndarray, spec: EngineSpec
                 ) -> tuple[float, float]:
    """(shift, its 1 sigma) [rad]: the angle by which ``trace`` lies later than ``reference`` (one cylinder's mean
    pressure on the local grid ``angle``, 0 = its assumed firing TDC) over the compression stroke before the
    combustion, where the trace's shape is the volume's: least squares of trace = a reference + b + c reference' (a,
    b: the charge pressure and a pegging move with the load; c = -a shift for a small shift). NaN where the stretch
    is too short."""
    sel = _stretch(angle, spec)
    if sel is None:
        return math.nan, math.nan
    d_ref = np.gradient(reference, angle)
    cols = np.column_stack([reference[sel], np.ones(np.count_nonzero(sel)), d_ref[sel]])
    coef, *_ = np.linalg.lstsq(cols, trace[sel], rcond=None)
    a, c = float(coef[0]), float(coef[2])
    if not a > 0:
        return math.nan, math.nan
    # the shift's standard error from the fit's own residual (delta method on -c / a): a screened cylinder's estimate
    # is its last fit moved by this shift, and carries this error too (genset-v20 seed 7, healthy, commissioned:
    # shifts of rms 0.057 deg where nothing moved, their standard errors median 0.060 deg; the fits' own statistical
    # sigma 0.003-0.012 deg, so without it a healthy cylinder's own offset wandered 0.2 -> 0.38 deg over windows at
    # "3 sigma" and was flagged)
    r = trace[sel] - cols @ coef
    dof = max(int(np.count_nonzero(sel)) - 3, 1)
    try:
        cov = np.linalg.inv(cols.T @ cols) * float(r @ r) / dof
    except np.linalg.LinAlgError:
        return -c / a, math.nan
    g = np.array([c / a**2, 0.0, -1.0 / a])
    return -c / a, float(np.sqrt(max(float(g @ cov @ g), 0.0)))


def own_drift(state: TdcWatchState, mean_trace: np.ndarray, twist_mean: np.ndarray, angle: np.ndarray,
              spec: EngineSpec) -> np.ndarray:
    """(z,) each cylinder's own shift since its last fit [rad], summed window by window: ``state.drift`` plus this
    window's ``window_shift`` against the last window's trace (the twist's change added back) less the median of all
    cylinders' (their common part: a wheel step, and a charge-pressure change, which this fit without a scale column
    reads as a shift alike on every cylinder). A second trigger of the screen beside ``screen_shift``, whose scale
    column leaves a shift and a scale nearly collinear over the compression stroke and read a single cylinder's step
    short (genset-v20, cylinder 20's 0.5 deg: 0.14 and 0.17 deg; this fit read 0.500 and 0.492 there and 0.005 deg
    rms where nothing moved; design note 49). Zeros where there is no last window or too few cylinders read."""
    z = mean_trace.shape[0]
    drift = np.zeros(z) if state.drift is None or state.drift.shape != (z,) else state.drift.copy()
    prev, prev_twist = state.window_trace, state.window_twist
    if prev is None or prev.shape != mean_trace.shape or prev_twist is None:
        return drift
    step = np.array([window_shift(prev[k], mean_trace[k], angle, spec) for k in range(z)])
    step += twist_mean - prev_twist
    ok = np.isfinite(step)
    if np.count_nonzero(ok) < 3:
        return drift
    return drift + np.where(ok, step - np.median(step[ok]), 0.0)


def window_shift(previous: np.ndarray, trace: np.ndarray, angle: np.ndarray, spec: EngineSpec) -> float:
    """The angle [rad] by which ``trace`` lies later than ``previous`` (one cylinder's mean pressure on the local grid
    ``angle``) over ``screen_shift``'s stretch: least squares of trace - previous = b + c previous', shift -c (b: a
    pegging). No scale column: a change of the charge pressure reads as a shift (``own_drift`` takes the cylinders'
    common part out). NaN where the stretch is too short."""
    sel = _stretch(angle, spec)
    if sel is None:
        return math.nan
    d_prev = np.gradient(previous, angle)[sel]
    if not (np.all(np.isfinite(d_prev)) and np.all(np.isfinite(trace[sel])) and np.all(np.isfinite(previous[sel]))):
        return math.nan
    cols = np.column_stack([np.ones(d_prev.shape[0]), d_prev])
    coef, *_ = np.linalg.lstsq(cols, (trace - previous)[sel], rcond=None)
    return -float(coef[1])


def tdc_flags(cal: Calibration, estimates: list[TdcEstimate | None],
              first_own: np.ndarray | None = None) -> tuple[str, ...]:
    """The flags one window's estimates raise against the calibration (module doc); ``first_own`` (2, z): each
    cylinder's first own offset in this run and its statistical sigma [rad] (``own_offsets``), for a commissioned
    model's change rule."""
    found = [(k, e) for k, e in enumerate(estimates) if e is not None]
    if not found:
        return ()
    offsets = np.array([e.offset_rad for _, e in found])
    sigmas = np.array([e.sigma_rad for _, e in found])
    stats = np.array([math.radians(e.evidence.get("statistical_deg", 0.0)) for _, e in found])
    wheel = float(np.median(offsets))
    if cal.commissioned:
        limit = DRIFT_SIGMAS * math.hypot(float(np.median(stats)), math.radians(OPERATING_POINT_DEG))
    else:
        limit = UNCALIBRATED_SIGMAS * math.hypot(float(np.median(sigmas)), cal.tdc_wheel_sigma_rad)
    flags = []
    if abs(wheel) > max(limit, math.radians(MIN_FLAG_DEG)):
        flags.append("sensor_tdc_offset")
    if len(found) >= 3:
        idx = [k for k, _ in found]
        own = offsets - wheel
        own_limit = np.maximum(DRIFT_SIGMAS * np.hypot(stats, cal.tdc_cylinder_sigma_rad), math.radians(MIN_FLAG_DEG))
        expected = np.zeros(len(found))
        if cal.commissioned and len(cal.tdc_cylinder_reading_deg) == len(estimates):
            # the commissioning's own reading of each cylinder is what a healthy one reads (the pressure method's bias
            # on that cylinder, the same then and now: genset-v20 cylinder 8 -0.26 deg then, -0.30 to -0.37 while
            # running, flagged against 0 +- 3 x 0.14): judged as a change since that reading
            expected = np.radians(np.asarray(cal.tdc_cylinder_reading_deg, dtype=np.float64)[idx])
            own_limit = _change_limit(stats, np.radians(np.asarray(cal.tdc_cylinder_reading_sigma_deg,
                                                                   dtype=np.float64)[idx]))
        moved = np.zeros(len(found), dtype=bool)
        if cal.commissioned and first_own is not None:
            # a change since the run's first reading of the cylinder: the method's own bias on this engine (the
            # commissioning's per-cylinder sigma, 0.14 deg on genset-v20, against which a 0.5 deg drift read +0.40
            # to +0.44: bench/sensor_drift.py) is the same then and now and cancels
            then, then_stat = first_own[0, idx], first_own[1, idx]
            moved = np.isfinite(then) & (np.abs(own - then) > _change_limit(stats, then_stat))
        flags += [f"sensor_tdc_offset_cyl{k + 1}" for (k, _), o, lim, m in zip(found, own - expected, own_limit,
                                                                                 moved, strict=True)
                  if abs(o) > lim or m]
    return tuple(flags)


def _change_limit(stat_now: np.ndarray, stat_then: np.ndarray) -> np.ndarray:
    """The limit [rad] on a cylinder's own offset changed since an earlier reading of it (commissioning's, or the
    run's first): DRIFT_SIGMAS of both readings' statistical sigmas and what a change of operating point moves
    (OPERATING_POINT_DEG, as for the wheel), and at least MIN_FLAG_DEG."""
    return np.maximum(DRIFT_SIGMAS * np.sqrt(stat_now**2 + stat_then**2 + math.radians(OPERATING_POINT_DEG) ** 2),
                      math.radians(MIN_FLAG_DEG))



__all__ = ["DRIFT_SIGMAS", "SCREEN_DEG", "close_window", "own_drift", "own_offsets", "moved_by", "screen_shift",
           "tdc_flags", "window_shift"]
