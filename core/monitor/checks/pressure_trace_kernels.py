"""The pressure-trace plausibility check's kernel (core.monitor.checks.pressure_trace): each cylinder's trace read
once, at angles from its own firing TDC, into the few numbers its verdict needs; ``trace_features_reference`` is
the same in numpy, from the definitions below.

Features, per cylinder k (row of ``out``), with ``rel`` the sample's angle after cylinder k's firing TDC in
[-360, 360) deg:
    MIN, MAX         the trace's extremes [Pa]
    PEAK_DEG         ``rel`` of the first sample at MAX [deg]
    FLAT             the crank angle [deg] the samples within ``flat_tol`` (relative) of MAX span, as their count times
                     the grid's step (an angle, not a count: a converter's coarse codes hold a rounded peak on a
                     fine grid over more samples, not over more degrees): a rail (saturation) or a frozen
                     channel holds many, a real peak one or two
    BDC, LATE        the mean pressure over [-190, -170) deg (intake BDC) and [-20, -5) deg (late compression) [Pa]
    GASX_MAX         the maximum over the gas-exchange revolution, |rel| >= 180 deg [Pa]
    SPIKE            how far MAX stands above the higher of its two neighbouring samples (the grid periodic) [Pa]:
                     a real peak is rounded (< 1 bar at 1 deg), a spike one sample high
Invalid samples (NaN: a repairable gap, core.monitor.monitor.checked_pressure) are passed over; a row without a
valid sample (a cylinder without a sensor) reads NaN throughout.
"""

from __future__ import annotations

import numba
import numpy as np

MIN, MAX, PEAK_DEG, FLAT, BDC, LATE, GASX_MAX, SPIKE = range(8)
N_FEATURES = 8
BDC_DEG, LATE_DEG = (-190.0, -170.0), (-20.0, -5.0)
DEG = 180.0 / np.pi


def relative_angles(grid: np.ndarray, firing: np.ndarray) -> np.ndarray:
    """(z, n) [deg] each sample's angle after each cylinder's firing TDC, wrapped to [-360, 360)."""
    rel = (grid[None, :] - firing[:, None]) * DEG  # in (-720, 720): grid and firing angles are in [0, 720) deg
    rel = np.where(rel >= 360.0, rel - 720.0, rel)
    return np.where(rel < -360.0, rel + 720.0, rel)


def trace_features_reference(pressure: np.ndarray, grid: np.ndarray, firing: np.ndarray,
                             flat_tol: float) -> np.ndarray:
    """(z, N_FEATURES) the module doc's features of ``pressure`` (z, n) [Pa] on ``grid`` (n,) [rad, uniform over
    720 deg], cylinder k firing at ``firing[k]`` [rad]; the readable definition the kernel is tested against."""
    z = pressure.shape[0]
    rel = relative_angles(grid, firing)
    step_deg = (grid[-1] - grid[0]) / (grid.shape[0] - 1) * DEG
    out = np.full((z, N_FEATURES), np.nan)
    for k in range(z):
        ok = np.isfinite(pressure[k])
        if not ok.any():
            continue
        p, r = pressure[k][ok], rel[k][ok]
        top = p.max()
        out[k, MIN], out[k, MAX] = p.min(), top
        out[k, PEAK_DEG] = r[np.argmax(p)]
        at = np.flatnonzero(ok)[np.argmax(p)]
        beside = pressure[k][[(at - 1) % ok.size, (at + 1) % ok.size]]
        out[k, SPIKE] = top - np.max(np.where(np.isfinite(beside), beside, top))
        out[k, FLAT] = np.count_nonzero(p >= top - flat_tol * abs(top)) * step_deg
        out[k, BDC] = p[(r >= BDC_DEG[0]) & (r < BDC_DEG[1])].mean()
        out[k, LATE] = p[(r >= LATE_DEG[0]) & (r < LATE_DEG[1])].mean()
        out[k, GASX_MAX] = p[np.abs(r) >= 180.0].max()
    return out


@numba.njit(cache=True)
def trace_features_kernel(pressure, grid, firing, flat_tol, out):
    """``trace_features_reference`` into ``out`` (z, N_FEATURES), its arguments as there, each sample's angle
    worked out as ``relative_angles`` does (so a sample on a window's edge falls on the same side). Two passes over a row (the extremes, then what needs MAX); never raises (a row without samples in a window
    gives NaN there)."""
    z, n = pressure.shape
    step_deg = (grid[n - 1] - grid[0]) / (n - 1) * DEG
    for k in range(z):
        row = pressure[k]
        lo, hi, at = np.inf, -np.inf, -1
        for i in range(n):
            v = row[i]
            if v < lo:
                lo = v
            if v > hi:
                hi, at = v, i
        if at < 0:  # no valid sample (NaN compares false)
            out[k, :] = np.nan
            continue
        thr = hi - flat_tol * abs(hi)
        flat, s_bdc, n_bdc, s_late, n_late, gasx = 0, 0.0, 0, 0.0, 0, -np.inf
        f = firing[k]
        for i in range(n):
            v = row[i]
            if v != v:
                continue
            r = (grid[i] - f) * DEG  # relative_angles' wrap (a float modulo per sample was ~0.2 ms a V20 cycle)
            if r >= 360.0:
                r -= 720.0
            elif r < -360.0:
                r += 720.0
            if v >= thr:
                flat += 1
            if BDC_DEG[0] <= r < BDC_DEG[1]:
                s_bdc += v
                n_bdc += 1
            elif LATE_DEG[0] <= r < LATE_DEG[1]:
                s_late += v
                n_late += 1
            if (r >= 180.0 or r <= -180.0) and v > gasx:
                gasx = v
        out[k, MIN], out[k, MAX] = lo, hi
        rp = (grid[at] - f) * DEG
        out[k, PEAK_DEG] = rp - 720.0 if rp >= 360.0 else (rp + 720.0 if rp < -360.0 else rp)
        out[k, FLAT] = flat * step_deg
        out[k, BDC] = s_bdc / n_bdc if n_bdc else np.nan
        out[k, LATE] = s_late / n_late if n_late else np.nan
        out[k, GASX_MAX] = gasx
        before, after = row[(at - 1) % n], row[(at + 1) % n]
        beside = max(before if before == before else hi, after if after == after else hi)
        out[k, SPIKE] = hi - beside
    return out


# the verdict's thresholds as the kernel takes them (pressure_trace.PressureTraceConfig's, in this order)
DEAD_SWING, FLAT_DEG, PEAK_LO, PEAK_HI, SIBLING_DEG, SPIKE_FRACTION, RISE_FRACTION, GASX_FRACTION = range(8)


@numba.njit(cache=True)
def trace_verdict_kernel(feat, limits, fail):
    """pressure_trace.failures (its numpy reference) into ``fail`` (z,) int64 from ``feat`` (z, N_FEATURES) and
    ``limits`` (the thresholds, in the order above): the test order and the NaN manners the same (a comparison with
    NaN is false, so a row without a sensor passes)."""
    z = feat.shape[0]
    peaks = np.empty(z)
    m = 0
    for k in range(z):
        if feat[k, PEAK_DEG] == feat[k, PEAK_DEG]:
            peaks[m] = feat[k, PEAK_DEG]
            m += 1
    median = np.median(peaks[:m]) if m >= 3 else np.nan
    for k in range(z):
        lo, hi, peak = feat[k, MIN], feat[k, MAX], feat[k, PEAK_DEG]
        swing = hi - lo
        floored = lo <= 0.0
        phase = (peak < limits[PEAK_LO]) or (peak > limits[PEAK_HI]) or (
            not floored and feat[k, LATE] - feat[k, BDC] < limits[RISE_FRACTION] * swing) or (
            not floored and feat[k, GASX_MAX] - feat[k, BDC] > limits[GASX_FRACTION] * (hi - feat[k, BDC])) or (
            m >= 3 and abs(peak - median) > limits[SIBLING_DEG])
        if swing < limits[DEAD_SWING]:
            fail[k] = 0
        elif feat[k, FLAT] > limits[FLAT_DEG]:
            fail[k] = 1
        elif hi + lo < 0.0:
            fail[k] = 2
        elif feat[k, SPIKE] > limits[SPIKE_FRACTION] * swing:
            fail[k] = 3
        elif phase:
            fail[k] = 4
        else:
            fail[k] = -1
    return fail
