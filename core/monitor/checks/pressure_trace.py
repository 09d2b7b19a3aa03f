"""Pressure-trace plausibility (design note 144): does each cylinder's trace look like a cylinder's pressure at all?

The calibration watches (../calibration/: TDC, gain, pegging) and the sensor-health stage correct a channel that is
right in kind and off in degree. A channel can also be wrong in kind, and then every figure made from it is a
confident wrong number: an amplifier's polarity (the trace negated), a dead or frozen channel, a saturated one, a
channel one crank revolution off or wired to another cylinder, a sample clock that disagrees with the crank. Each
cylinder's trace is read at angles from its own firing TDC (``pressure_trace_kernels``) and must be

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
place, so the engine's indicated work and friction stay measured and the cylinder's own IMEP is its siblings'
(said by the flag). Without a healthy sibling (one cylinder, or all failing) the cycle is refused
(``pressure_implausible``): there is nothing to put in the trace's place.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from frictionwatch.core.monitor.checks.pressure_trace_kernels import (
    BDC,
    FLAT,
    GASX_MAX,
    LATE,
    MAX,
    MIN,
    N_FEATURES,
    PEAK_DEG,
    SPIKE,
    trace_features_kernel,
    trace_verdict_kernel,
)

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
        """The thresholds as ``trace_verdict_kernel`` takes them (pressure_trace_kernels' order), made once per
        config, not once a cycle (writeable: a read-only array would be another type to numba, another compile)."""
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


def trace_features(pressure: np.ndarray, grid: np.ndarray, firing: np.ndarray, flat_tol: float) -> np.ndarray:
    """(z, N_FEATURES) the features of pressure_trace_kernels' module doc: pressure (z, n) [Pa] on grid (n,) [rad]
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
