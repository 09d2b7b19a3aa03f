"""Pressure-trace plausibility (design note 144): does each cylinder's trace look like a cylinder's pressure at all?

The calibration watches (../calibration/: TDC, gain, pegging) and the sensor-health stage correct a channel that is
right in kind and off in degree. A channel can also be wrong in kind, and then every figure made from it is a
confident wrong number: an amplifier's polarity (the trace negated), a dead or frozen channel, a saturated one, a
channel one crank revolution off or wired to another cylinder, a sample clock that disagrees with the crank. Each
cylinder's trace is read once at angles from its own firing TDC into a few features (below) and must be

    alive       swinging at least ``dead_swing_pa`` over the cycle                              else  dead
    not railed  its maximum held over at most ``flat_deg`` (a real peak is rounded)             else  clipped
    upright     its maximum further from zero than its minimum (absolute pressure; a pegging
                offset within +-10 bar leaves a firing trace upright)                          else  negated
    smooth      its maximum at most ``spike_fraction`` of its swing above both neighbours     else  spikes
    in phase    its peak in ``peak_window_deg`` after its firing TDC, within ``sibling_deg`` of
                its siblings' median peak (three or more cylinders), and (a trace above zero:
                one that reads 0 is floored or pegged low, core.monitor.monitor.nonpositive_flags)
                its late compression above its intake BDC by ``rise_fraction`` of its swing,
                its gas-exchange revolution below ``gas_exchange_fraction`` of the peak's rise else  phase

A cylinder that fails is flagged ``sensor_pressure_<kind>_cyl<k>`` (the ``sensor_`` prefix withholds its friction
figure: core.monitor.report.figure_status) and stays flagged ``hold_cycles`` cycles after its last failure (its own
recent history: a trace that fails now and then is not trusted in between). Its trace is then kept out of what it
would falsify: ``substitute`` puts the mean of its healthy siblings' traces, each moved to its firing angle, in its
place, so the engine's indicated work and friction stay measured; the cylinder's own IMEP and peak pressure are
then its siblings', which no report shows as its own (``stood_in``; design note 153). Without a healthy sibling (one cylinder, or all failing) the cycle is refused
(``pressure_implausible``): there is nothing to put in the trace's place.

The features, per cylinder k (a row of ``trace_features``), with ``rel`` the sample's angle after cylinder k's firing
TDC in [-360, 360) deg:
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
valid sample (a cylinder without a sensor) reads NaN throughout. The features and the verdict are each a numba
kernel beside its numpy reference: ``trace_features_kernel`` and ``trace_features_reference``, ``trace_verdict_kernel``
and ``failures``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from functools import cached_property

import numba
import numpy as np
from frictionwatch.core.monitor.report.figure_status import split_flag

MIN, MAX, PEAK_DEG, FLAT, BDC, LATE, GASX_MAX, SPIKE = range(8)
N_FEATURES = 8
BDC_DEG, LATE_DEG = (-190.0, -170.0), (-20.0, -5.0)
DEG = 180.0 / np.pi
# the verdict's thresholds as its kernel takes them (PressureTraceConfig.limits, in this order)
DEAD_SWING, FLAT_DEG, PEAK_LO, PEAK_HI, SIBLING_DEG, SPIKE_FRACTION, RISE_FRACTION, GASX_FRACTION = range(8)

KINDS = ("dead", "clipped", "negated", "spikes", "phase")


@dataclass(frozen=True)
class PressureTraceConfig:
    """The verdict's thresholds (module doc). Tuned on seed 3 of k9k-4cyl, maruti-3cyl, deutz-1cyl and genset-v20 at
    bench/pressure_lies.py's two operating points each (healthy: swing >= 23.6 bar, rise >= 0.30, peak 4..16 deg,
    <= 2 samples at the peak, gas-exchange rise <= 0.03, sibling peaks within 2 deg); validated on seeds 5 and 7 and
    the measured traces of ../shared/realdata (tests/core/test_pressure_trace.py)."""

    dead_swing_pa: float = 3e5  # healthy >= 23.6 bar; a dead channel's noise, a stuck one's 0
    # healthy <= 2 deg (two samples of a 1-deg grid); a rail at 60 % of the peak holds >= 33 deg. In degrees, not
    # samples: a 12-bit converter over 250 bar (0.06 bar a code) holds a rounded peak (~0.5 bar/deg^2) over ~1 deg,
    # i.e. ~10 samples of a 0.1-deg grid, which a count of 4 samples called clipped (a unit test; not tuned on it)
    flat_deg: float = 4.0
    flat_tol: float = 1e-6  # relative: a rail is one converter code
    peak_window_deg: tuple[float, float] = (-10.0, 40.0)  # healthy 4..16 deg after firing TDC (motored: ~ -1)
    sibling_deg: float = 20.0  # healthy within 2 deg of the siblings' median; a V20 swap of neighbours is 36
    spike_fraction: float = 0.1  # healthy peaks stand < 1 bar over their 1-deg neighbours: < 0.05 of the swing
    rise_fraction: float = 0.1  # healthy >= 0.30; a trace 360 deg off reads ~0, a negated or swapped one < 0
    gas_exchange_fraction: float = 0.5  # healthy <= 0.03; a halved sample clock puts a second peak there (>= 0.94)
    hold_cycles: int = 2

    @cached_property
    def limits(self) -> np.ndarray:
        """The thresholds as ``trace_verdict_kernel`` takes them (in DEAD_SWING ... GASX_FRACTION's order), made once
        per config, not once a cycle (writeable: a read-only array would be another type to numba, another compile)."""
        return np.array([self.dead_swing_pa, self.flat_deg, *self.peak_window_deg, self.sibling_deg,
                         self.spike_fraction, self.rise_fraction, self.gas_exchange_fraction])


@dataclass(frozen=True)
class PressureTraceState:
    """since (z,) int64: cycles since each cylinder's trace last failed (a large number: never); kind (z,) int64
    the index in KINDS of its last failure (-1: none); refused: the cycles refused so far."""

    since: np.ndarray
    kind: np.ndarray
    refused: int = 0

    @staticmethod
    def empty(n_cyl: int) -> PressureTraceState:
        return PressureTraceState(np.full(n_cyl, 1 << 30, np.int64), np.full(n_cyl, -1, np.int64))


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
    worked out as ``relative_angles`` does (so a sample on a window's edge falls on the same side). Two passes over a
    row (the extremes, then what needs MAX); never raises (a row without samples in a window
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


def trace_features(pressure: np.ndarray, grid: np.ndarray, firing: np.ndarray, flat_tol: float) -> np.ndarray:
    """(z, N_FEATURES) the features of the module doc: pressure (z, n) [Pa] on grid (n,) [rad]
    uniform over 720 deg, cylinder k firing at firing[k] [rad]."""
    p = np.ascontiguousarray(pressure, dtype=np.float64)
    g = np.ascontiguousarray(grid, dtype=np.float64)
    f = np.ascontiguousarray(firing, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != g.shape[0] or p.shape[0] != f.shape[0]:
        raise ValueError(f"pressure {p.shape} must be (cylinders {f.shape[0]}, grid samples {g.shape[0]})")
    return trace_features_kernel(p, g, f, float(flat_tol), np.empty((p.shape[0], N_FEATURES)))


def failures(cfg: PressureTraceConfig, feat: np.ndarray) -> np.ndarray:
    """(z,) int64 each cylinder's failure this cycle as its index in KINDS, -1 where its trace passes (module doc:
    the first test it fails, in the table's order). The numpy reference of ``trace_verdict_kernel``, which
    ``check_traces`` runs (these ~15 small numpy calls were ~45 us a V20 cycle at load 14, the kernel ~1)."""
    lo, hi, peak = feat[:, MIN], feat[:, MAX], feat[:, PEAK_DEG]
    swing = hi - lo
    rise = feat[:, LATE] - feat[:, BDC]
    lift = hi - feat[:, BDC]
    with np.errstate(invalid="ignore"):
        # a trace at or below zero somewhere is floored or pegged low (maruti at part load with -10 bar reads 0 from
        # intake to mid-compression): its BDC says nothing, the nonpositive flag and the pegging watch have it
        floored = lo <= 0.0
        phase = ((peak < cfg.peak_window_deg[0]) | (peak > cfg.peak_window_deg[1])
                 | (~floored & (rise < cfg.rise_fraction * swing))
                 | (~floored & (feat[:, GASX_MAX] - feat[:, BDC] > cfg.gas_exchange_fraction * lift)))
    sensed = peak[np.isfinite(peak)]
    if sensed.size >= 3:  # a peak far from its siblings' (a cylinder without a sensor has none)
        phase |= np.abs(peak - np.median(sensed)) > cfg.sibling_deg
    out = np.where(phase, 4, -1)  # (a row without a valid sample: no sensor, not judged; NaN passes every test)
    out = np.where(feat[:, SPIKE] > cfg.spike_fraction * swing, 3, out)
    out = np.where(hi + lo < 0.0, 2, out)
    out = np.where(feat[:, FLAT] > cfg.flat_deg, 1, out)
    return np.where(swing < cfg.dead_swing_pa, 0, out)


@numba.njit(cache=True)
def trace_verdict_kernel(feat, limits, fail):
    """``failures`` (its numpy reference) into ``fail`` (z,) int64 from ``feat`` (z, N_FEATURES) and
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


def substitute(pressure: np.ndarray, grid: np.ndarray, firing: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """``pressure`` (z, n) with each ``bad`` cylinder's row the mean of the good rows, each moved from its own firing
    angle to the bad cylinder's (periodic over the 720 deg grid; ``np.interp`` where the shift is not whole
    samples). Needs a good row."""
    out = pressure.copy()
    n = grid.shape[0]
    step = (grid[-1] - grid[0]) / (n - 1)
    good = np.flatnonzero(~bad & np.isfinite(pressure).all(axis=1))
    for k in np.flatnonzero(bad):
        acc = np.zeros(n)
        for j in good:
            shift = (firing[k] - firing[j]) / step
            whole = round(shift)
            if abs(shift - whole) < 1e-6:
                acc += np.roll(pressure[j], whole)
            else:
                acc += np.interp(np.arange(n) - shift, np.arange(n), pressure[j], period=n)
        out[k] = acc / good.size
    return out


TRACE_FLAG_KINDS = frozenset(f"sensor_pressure_{k}" for k in KINDS)  # the flags' kinds (split_flag's) of this check


def stood_in(flags: Iterable[str], n_cyl: int) -> np.ndarray:
    """(n_cyl,) bool: the cylinders whose trace ``check_traces`` replaced by its siblings' mean (a
    ``sensor_pressure_<kind>_cyl<k>`` flag of a kind in KINDS). Their IMEP, peak pressure and its angle are then
    the siblings' stand-in, not a measurement: the reports show them as such (core.monitor.report.results)."""
    out = np.zeros(n_cyl, dtype=bool)
    for f in flags:
        kind, cyl = split_flag(f)
        if kind in TRACE_FLAG_KINDS and cyl is not None and cyl <= n_cyl:
            out[cyl - 1] = True
    return out


def check_traces(cfg: PressureTraceConfig, state: PressureTraceState, pressure: np.ndarray, grid: np.ndarray,
                 firing: np.ndarray) -> tuple[PressureTraceState, np.ndarray, tuple[str, ...], bool]:
    """One cycle: (the new state, the pressure to analyse (the input itself where nothing is flagged), the flags,
    whether the cycle must be refused: a flagged cylinder and no healthy sibling to stand in for it)."""
    fail = trace_verdict_kernel(trace_features(pressure, grid, firing, cfg.flat_tol), cfg.limits,
                                np.empty(len(firing), np.int64))
    failed = fail >= 0
    since = np.where(failed, 0, state.since + 1)
    kind = np.where(failed, fail, state.kind)
    state = PressureTraceState(since, kind, state.refused)
    flagged = since <= cfg.hold_cycles
    if not flagged.any():
        return state, pressure, (), False
    flags = tuple(f"sensor_pressure_{KINDS[kind[k]]}_cyl{k + 1}" for k in np.flatnonzero(flagged))
    p = np.asarray(pressure, dtype=np.float64)
    if not (~flagged & np.isfinite(p).all(axis=1)).any():  # no healthy sibling to stand in
        return PressureTraceState(since, kind, state.refused + 1), pressure, flags, True
    return state, substitute(p, grid, firing, flagged), flags, False
