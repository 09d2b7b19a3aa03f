"""In-cylinder pressure from raw sensor volts: crank angle of every sample, 4-stroke phase, pegging and gain.

The TU/e pressure channel is a linear sensor with unknown gain and a zero that drifts between and within files
(README of ``tue-4gb10-si-encoder-pressure``). Per firing TDC k (physics.md §14.5–14.6):

- **phase** — the wheel fixes 360 deg only; of two candidate TDCs one revolution apart the one with the higher mean
  signal within +-30 deg is firing TDC (true for motored cycles too: compression beats gas exchange). Voted per run
  of contiguous revolutions, then checked per cycle.
- **zero (polytropic pegging)** — over the compression window (default -100..-60 deg) the pressure follows
  p V^n = C, so the volts follow u = a V^-n + u0 with n fixed (default 1.32); a linear least-squares fit gives
  u0_k, the output at zero absolute pressure. This needs no knowledge of the manifold pressure, which matters for a
  throttled SI engine (the TU/e engine is governed: at no load p(intake BDC) is about 0.3 bar, not 1 bar).
- **gain** — the fit fixes only the shape; the scale needs one absolute pressure. With p(intake BDC) = ``peg_pa``
  (true at wide-open throttle: motored coast-downs with the governor open) each cycle implies
  g_k = peg_pa / (u_BDC,k - u0_k); the file's gain is their median. For fired, throttled files pass the gain
  measured on the motored files instead (``gain_pa_per_v``).
- **bdc pegging** (``peg="bdc"``) — alternative zero: u0_k = u_BDC,k - peg_pa / g (p at intake BDC = manifold).

The calibration of TDC k applies to the samples in [TDC_k - 360, TDC_k + 360) deg: the whole intake–compression–
expansion–exhaust sequence around one combustion uses one zero. Samples outside every calibrated span are NaN.

V(theta) is the slider-crank volume of physics.md §1 (no pin offset), written out here because drivers/ may import
only core.types and core.model.engine; tests check it against core.model.kinematics.cylinder_volume.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.drivers.daq.teeth import TURN_BREAK


def cylinder_volume(theta_deg: np.ndarray, engine: EngineSpec) -> np.ndarray:
    """V(theta) [m^3] of a centred slider-crank, theta in deg from TDC (physics.md §1)."""
    th = np.radians(np.asarray(theta_deg, dtype=np.float64))
    r, rod = engine.crank_radius, engine.conrod
    x = r * (1.0 - np.cos(th)) + rod - np.sqrt(rod * rod - (r * np.sin(th)) ** 2)
    return engine.clearance_volume + engine.piston_area * x


def wheel_angle_of_samples(
    sample_ticks: np.ndarray,
    edge_ticks: np.ndarray,
    rev_start: np.ndarray,
    rev_end: np.ndarray,
    rev_turn: np.ndarray,
    wheel_teeth: int,
    wheel_missing: int,
) -> np.ndarray:
    """Unwrapped wheel angle [deg] of each sample: 360 * turn + nominal angle of the teeth around it, linearly
    interpolated in time between edges (tooth 0 = 0 deg, tooth j = j * 360/N deg). NaN outside verified revolutions."""
    phi = np.full(sample_ticks.shape[0], np.nan)
    present = wheel_teeth - wheel_missing
    ang = np.append(np.arange(present) * (360.0 / wheel_teeth), 360.0)
    for a, b, turn in zip(rev_start, rev_end, rev_turn, strict=True):
        tk = np.append(edge_ticks[a : a + present], edge_ticks[b])
        i0, i1 = np.searchsorted(sample_ticks, [tk[0], tk[-1]])
        phi[i0:i1] = 360.0 * turn + np.interp(sample_ticks[i0:i1], tk, ang)
    return phi


def firing_turns(
    phi: np.ndarray, volts: np.ndarray, rev_turn: np.ndarray, tdc_deg: float, window_deg: float = 30.0
) -> tuple[np.ndarray, Counter]:
    """Turns (wheel revolutions) whose TDC candidate is firing TDC (physics.md §14.5), and counted doubts.

    Parity is voted separately over each run of turns whose count is known (turn numbers jump by >= ``TURN_BREAK``
    across a signal dropout, where the number of lost revolutions is unknown). A firing turn whose candidate is not
    above both neighbours is still returned but counted under ``phase_doubtful``.
    """
    damage: Counter = Counter()
    turns = np.asarray(rev_turn, dtype=np.int64)
    if turns.size == 0:
        return turns, damage
    key = sortable_angle(phi)
    mean_v = np.full(turns.shape[0], np.nan)
    for i, c in enumerate(360.0 * turns + tdc_deg):
        lo, hi = np.searchsorted(key, [c - window_deg, c + window_deg])
        if hi - lo > 3 and np.all(np.isfinite(phi[lo:hi])):
            mean_v[i] = volts[lo:hi].mean()
    run = np.concatenate([[0], np.cumsum(np.diff(turns) >= TURN_BREAK)])
    fire = np.zeros(turns.shape[0], dtype=bool)
    for r in np.unique(run):
        sel = run == r
        t, m = turns[sel], mean_v[sel]
        even, odd = np.isfinite(m) & (t % 2 == 0), np.isfinite(m) & (t % 2 == 1)
        if not even.any() or not odd.any():
            damage["phase_unknown"] += 1
            continue
        parity = 0 if m[even].mean() > m[odd].mean() else 1
        fire[sel] = t % 2 == parity
    by_turn = dict(zip(turns.tolist(), mean_v.tolist(), strict=True))
    for t, m in zip(turns[fire], mean_v[fire], strict=True):
        nb = [by_turn.get(t - 1, np.nan), by_turn.get(t + 1, np.nan)]
        if not np.isfinite(m) or any(np.isfinite(x) and x >= m for x in nb):
            damage["phase_doubtful"] += 1
    return turns[fire], damage


def sortable_angle(phi: np.ndarray) -> np.ndarray:
    """phi with NaN replaced by the last finite value before it (or -inf), so np.searchsorted works on it."""
    out = phi.copy()
    bad = ~np.isfinite(out)
    if bad.any():
        idx = np.where(~bad, np.arange(out.shape[0]), 0)
        np.maximum.accumulate(idx, out=idx)
        out = out[idx]
        out[~np.isfinite(out)] = -np.inf
    return out


@dataclass(frozen=True)
class CycleCalibration:
    """Calibration around one firing TDC. Volts -> Pa: p = gain * (u - zero_v)."""

    tdc_phi: float  # unwrapped wheel angle of this firing TDC [deg]
    zero_v: float  # sensor output at zero absolute pressure [V]
    gain_pa_per_v: float  # gain applied [Pa/V]
    bdc_v: float  # mean output within +-5 deg of intake BDC [V]
    implied_gain_pa_per_v: float  # peg_pa / (bdc_v - poly_zero_v): the gain this cycle implies if p(BDC) = peg_pa
    fit_rms_v: float  # rms residual of the polytropic fit [V]


def polytropic_zero(
    theta_deg: np.ndarray, volts: np.ndarray, engine: EngineSpec, n_poly: float
) -> tuple[float, float, float]:
    """Least-squares fit u = a V(theta)^-n + u0 over the given compression samples; returns (u0, a, rms) [V]."""
    v = cylinder_volume(theta_deg, engine)
    a_mat = np.column_stack([(v / engine.clearance_volume) ** -n_poly, np.ones_like(v)])
    sol, *_ = np.linalg.lstsq(a_mat, volts, rcond=None)
    rms = float(np.sqrt(np.mean((a_mat @ sol - volts) ** 2)))
    return float(sol[1]), float(sol[0]), rms


def calibrate_cycles(
    phi: np.ndarray,
    volts: np.ndarray,
    tdc_phis: np.ndarray,
    engine: EngineSpec,
    *,
    n_poly: float = 1.32,
    window_deg: tuple[float, float] = (-100.0, -60.0),
    peg: str = "polytropic",
    peg_pa: float = 1.0e5,
    gain_pa_per_v: float | None = None,
    peak_window_deg: tuple[float, float] = (20.0, 50.0),
) -> tuple[list[CycleCalibration], Counter]:
    """Zero and gain per firing TDC (module docstring). ``phi`` from ``wheel_angle_of_samples`` (NaN allowed).

    A cycle is skipped (counted) when its compression window is incomplete, the fit is implausible, or its pressure
    peak lies outside [-peak_window_deg[0], +peak_window_deg[1]] deg of TDC (wrong ``tdc_deg`` or phase).
    """
    if peg not in ("polytropic", "bdc"):
        raise ValueError(f"peg must be 'polytropic' or 'bdc', got {peg!r}")
    if not window_deg[0] < window_deg[1] < 0:
        raise ValueError(f"compression window {window_deg} must be increasing and before TDC (deg < 0)")
    damage: Counter = Counter()
    key = sortable_angle(phi)
    fits = []
    for tp in tdc_phis:
        lo, hi = np.searchsorted(key, [tp + window_deg[0], tp + window_deg[1]])
        b0, b1 = np.searchsorted(key, [tp - 185.0, tp - 175.0])
        th = phi[lo:hi] - tp
        if hi - lo < 10 or b1 - b0 < 3 or not np.all(np.isfinite(th)) or not np.all(np.isfinite(phi[b0:b1])):
            damage["no_compression_window"] += 1
            continue
        u0, a, rms = polytropic_zero(th, volts[lo:hi], engine, n_poly)
        ubdc = float(volts[b0:b1].mean())
        implied = peg_pa / (ubdc - u0) if ubdc > u0 else np.nan
        if not (a > 0 and np.isfinite(implied)):
            damage["implausible_compression"] += 1
            continue
        # the signal peak must lie near this TDC (motored: just before it; fired: up to ~45 deg after); elsewhere
        # the TDC angle or the phase is wrong and every number of this cycle would be silently wrong
        k0, k1 = np.searchsorted(key, [tp - 90.0, tp + 90.0])
        if k1 - k0 < 10 or not -peak_window_deg[0] <= phi[k0 + int(np.argmax(volts[k0:k1]))] - tp <= peak_window_deg[1]:
            damage["peak_far_from_tdc"] += 1
            continue
        fits.append((tp, u0, ubdc, implied, rms))
    if not fits:
        return [], damage
    implied = np.array([f[3] for f in fits])
    gain = float(np.median(implied)) if gain_pa_per_v is None else float(gain_pa_per_v)
    if not gain > 0:
        raise ValueError(f"gain must be > 0 Pa/V, got {gain}")
    if gain_pa_per_v is None:  # cycles whose p(BDC) was clearly not peg_pa (throttle moving): counted, still used
        n_out = int(np.count_nonzero(np.abs(implied / gain - 1.0) > 0.25))
        if n_out:
            damage["implied_gain_outlier"] += n_out
    out = []
    for tp, u0, ubdc, implied, rms in fits:
        zero = u0 if peg == "polytropic" else ubdc - peg_pa / gain
        out.append(CycleCalibration(tp, zero, gain, ubdc, implied, rms))
    return out, damage


def apply_calibration(phi: np.ndarray, volts: np.ndarray, cals: list[CycleCalibration]) -> np.ndarray:
    """Absolute pressure [Pa] of each sample; calibration k covers [TDC_k - 360, TDC_k + 360) deg, else NaN."""
    p = np.full(volts.shape[0], np.nan)
    key = sortable_angle(phi)
    for c in cals:
        lo, hi = np.searchsorted(key, [c.tdc_phi - 360.0, c.tdc_phi + 360.0])
        seg = np.isfinite(phi[lo:hi])
        p[lo:hi][seg] = c.gain_pa_per_v * (volts[lo:hi][seg] - c.zero_v)
    return p
