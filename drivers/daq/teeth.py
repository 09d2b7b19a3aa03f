"""Crank-wheel tooth edges from a sampled analog wheel signal, and missing-tooth sync (physics.md §14.1–14.2).

The TU/e 4GB10 wheel signal (``../shared/realdata/tue-4gb10-si-encoder-pressure``) is an amplified, clipped VR-type
signal: a low rail near -0.75 V, tooth pulses up to about +4 V, steep rising flanks (2–3 samples at 100 kHz). The
tooth just after the 60-2 gap rides on the long negative lobe that the gap produces, so its pulse is weak: in the
E0NOLOAD files its peak lies between -0.27 V and +0.36 V, i.e. a fixed 0 V (or mid-rail) threshold sees it in only
15–85 % of the revolutions, which is the "57/58 crossings" noted in the README.

Detector (one pass, a Schmitt trigger whose timing level adapts to weak pulses):

1. *arm* when the signal falls below ``arm`` (near the low rail), remembering the lowest value ``v_min`` since then;
2. a pulse *fires* when the signal then rises above ``fire`` (> arm: the hysteresis band, so floor noise of a few
   tens of mV can never make an edge) and lasts until it falls below ``arm`` again; its peak ``v_pk`` is recorded;
3. the edge time is the rising crossing of ``min(level, v_min + weak_frac * (v_pk - v_min))``, linearly interpolated
   between the two samples around it. Full pulses are thus timed at the zero crossing (``level`` = 0 V, physics.md
   §14.1: amplitude-independent); a weak pulse that never reaches 0 V is timed at its half height instead, and
   flagged ``weak`` (its angle is distorted anyway and must be learned per tooth, physics.md §14.2).

Sync: interval ratio r_i = dt_i / median(two intervals either side) is about k+1 at a gap of k missing teeth; a gap is
declared at r_i > k + 1/2 (2.5 for 60-2: between a single dropped tooth, r = 2, and the gap, r = 3.3–3.6 measured
with the distorted neighbours). A revolution counts only if exactly N-k edges lie between two gaps and no interval in
it looks like a dropped (r > 1.6) or spurious (r < 0.45) tooth; otherwise it is skipped with a counted reason and
sync is regained at the next gap.
"""

from __future__ import annotations

import itertools
from collections import Counter
from dataclasses import dataclass, field

import numba
import numpy as np

TURN_BREAK = 1000  # turn-number jump across a signal dropout (the number of lost revolutions is unknown)


@numba.njit(cache=True)
def _hysteresis_edges(w, thresholds, out_pos, out_peak, out_lev):
    """Rising pulse edges of ``w``. thresholds = [arm, fire, level, weak_frac]. Writes fractional sample positions
    pulse peaks and timing levels; returns the number of edges. A pulse cut by the start or end of the record
    is dropped."""
    arm = thresholds[0]
    fire = thresholds[1]
    level = thresholds[2]
    frac = thresholds[3]
    n = w.shape[0]
    k = 0
    i = 0
    while i < n and w[i] >= arm:  # a pulse already under way at the start has no known flank
        i += 1
    while i < n:
        imin = i
        vmin = w[i]
        while i < n and w[i] <= fire:
            if w[i] < vmin:
                vmin = w[i]
                imin = i
            i += 1
        if i >= n:
            break
        ipk = i
        vpk = w[i]
        while i < n and w[i] >= arm:
            if w[i] > vpk:
                vpk = w[i]
                ipk = i
            i += 1
        if i >= n:
            break  # the last pulse's peak is unknown
        lev = min(vmin + frac * (vpk - vmin), level)
        j = imin + 1
        while j < ipk and w[j] < lev:
            j += 1
        d = w[j] - w[j - 1]
        pos = float(j - 1)
        if d > 0.0:
            pos += (lev - w[j - 1]) / d
        out_pos[k] = pos
        out_peak[k] = vpk
        out_lev[k] = lev
        k += 1
    return k


def hysteresis_edges(
    signal: np.ndarray,
    arm: float,
    fire: float,
    level: float = 0.0,
    weak_frac: float = 0.5,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rising tooth edges of a sampled wheel signal (module docstring gives the rule).

    Parameters
    ----------
    signal : (n,) wheel sensor voltage [V], uniformly sampled
    arm, fire : hysteresis thresholds [V], arm < fire
    level : timing level of full pulses [V] (0 V = the VR zero crossing)
    weak_frac : timing level of weak pulses as a fraction of their height above the preceding minimum

    Returns
    -------
    position : (m,) float64 edge times in fractional samples (0 = first sample)
    peak : (m,) float64 peak voltage of each pulse [V]
    timing_level : (m,) float64 level at which each edge was timed [V] (< ``level`` for a weak pulse)
    """
    w = np.ascontiguousarray(signal, dtype=np.float64).ravel()
    if not arm < fire:
        raise ValueError(f"arm ({arm} V) must be below fire ({fire} V)")
    if not 0.0 < weak_frac < 1.0:
        raise ValueError(f"weak_frac must be in (0, 1), got {weak_frac}")
    if not np.all(np.isfinite(w)):
        raise ValueError("wheel signal has NaN or inf samples")
    pos = np.empty(w.shape[0] // 2 + 1)
    peak = np.empty_like(pos)
    lev = np.empty_like(pos)
    m = _hysteresis_edges(w, np.array([arm, fire, level, weak_frac], dtype=np.float64), pos, peak, lev)
    return pos[:m].copy(), peak[:m].copy(), lev[:m].copy()


@dataclass(frozen=True)
class ToothEdges:
    """Rising wheel edges and their sync.

    ticks        (m,) int64 edge times of the virtual timer (``tick_hz``), strictly increasing
    peak_v       (m,) float64 pulse peak [V]
    weak         (m,) bool: pulse too low for the zero crossing, timed at half height
    tooth_index  (m,) int64 index on the wheel (0 = first edge after the gap), -1 where not in a verified revolution
    revolution   (m,) int64 running number of the verified revolution, -1 elsewhere
    rev_start    (r,) int64 edge index of tooth 0 of each verified revolution; ``rev_end`` the next tooth 0 (closing)
    rev_turn     (r,) int64 turn number of each verified revolution (counts skipped ones; see ``sync_wheel``)
    damage       reason -> count of skipped revolutions (``teeth_per_rev_57``, ``dropped_tooth`` ...)
    """

    tick_hz: float
    wheel_teeth: int
    wheel_missing: int
    ticks: np.ndarray
    peak_v: np.ndarray
    weak: np.ndarray
    tooth_index: np.ndarray
    revolution: np.ndarray
    rev_start: np.ndarray
    rev_end: np.ndarray
    rev_turn: np.ndarray
    damage: Counter = field(default_factory=Counter)

    @property
    def revs_ok(self) -> int:
        return int(self.rev_start.shape[0])

    @property
    def revs_skipped(self) -> int:
        return int(sum(self.damage.values()))

    def rev_speed_rpm(self) -> np.ndarray:
        """Mean speed of each verified revolution [rpm] from tooth 0 to the next tooth 0 (same tooth: exact)."""
        dt = (self.ticks[self.rev_end] - self.ticks[self.rev_start]) / self.tick_hz
        return 60.0 / dt


def sync_wheel(
    ticks: np.ndarray, wheel_teeth: int, wheel_missing: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, Counter]:
    """Find missing-tooth gaps and verified revolutions in a sequence of edge ticks.

    Returns (rev_start, rev_end, rev_turn, damage): edge indices of tooth 0 of each verified revolution and of the
    tooth 0 that closes it; the turn number of each (counted through skipped revolutions, so the 4-stroke parity
    survives them; it jumps by ``TURN_BREAK`` across a dropout, after which the count is unknown); counted reasons.
    """
    t = np.asarray(ticks, dtype=np.int64)
    present = wheel_teeth - wheel_missing
    damage: Counter = Counter()
    if wheel_missing < 1:
        raise ValueError("sync needs a wheel with missing teeth (wheel_missing >= 1)")
    if t.shape[0] < 6:
        e = np.zeros(0, np.int64)
        return e, e.copy(), e.copy(), damage
    d = np.diff(t).astype(np.float64)
    pad = np.full(2, np.nan)
    dp = np.concatenate([pad, d, pad])
    n = d.shape[0]
    neigh = np.stack([dp[0:n], dp[1 : n + 1], dp[3 : n + 3], dp[4 : n + 4]])
    ref = np.nanmedian(neigh, axis=0)
    r = d / ref
    gap = (r > wheel_missing + 0.5) & (r < wheel_missing + 2.5)
    odd = ~gap & ((r > 1.6) | (r < 0.45))
    dropout = r >= wheel_missing + 2.5  # far longer than a gap: lost signal, unknown number of revolutions
    starts = np.flatnonzero(gap) + 1  # edge index of the first tooth after each gap
    breaks = np.cumsum(dropout)  # dropouts up to and including each interval
    rs, re, turns = [], [], []
    for i, (a, b) in enumerate(itertools.pairwise(starts)):
        count = b - a
        if breaks[b - 1] != breaks[a - 1]:
            damage["signal_dropout"] += 1
        elif count != present:
            damage[f"teeth_per_rev_{count}"] += 1
        elif odd[a : b - 1].any():
            damage["dropped_or_spurious_tooth"] += 1
        else:
            rs.append(a)
            re.append(b)
            turns.append(i + TURN_BREAK * int(breaks[a - 1]))
    i64 = np.int64
    return np.asarray(rs, dtype=i64), np.asarray(re, dtype=i64), np.asarray(turns, dtype=i64), damage


def edge_ticks(
    signal: np.ndarray,
    sample_rate_hz: float,
    tick_hz: float = 10e6,
    t0_ticks: int = 0,
    level: float = 0.0,
    arm_frac: float = 0.05,
    fire_frac: float = 0.08,
    weak_frac: float = 0.5,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ticks, peak_v, timing_level) of every rising edge of a sampled wheel signal, before any sync
    (``detect_teeth`` gives the thresholds)."""
    w = np.ascontiguousarray(signal, dtype=np.float64).ravel()
    if sample_rate_hz <= 0 or tick_hz < sample_rate_hz:
        raise ValueError(f"need tick_hz ({tick_hz}) >= sample_rate_hz ({sample_rate_hz}) > 0")
    if not 0.0 < arm_frac < fire_frac < 0.5:
        raise ValueError(f"need 0 < arm_frac ({arm_frac}) < fire_frac ({fire_frac}) < 0.5")
    if w.shape[0] < 16:
        raise ValueError(f"wheel signal too short ({w.shape[0]} samples)")
    lo, hi = np.percentile(w, [1.0, 99.0])
    span = hi - lo
    if not span > 0:
        raise ValueError("wheel signal is flat: no teeth")
    arm, fire = lo + arm_frac * span, lo + fire_frac * span
    pos, peak, lev = hysteresis_edges(w, arm, fire, level, weak_frac)
    ticks = int(t0_ticks) + np.rint(pos * (tick_hz / sample_rate_hz)).astype(np.int64)
    keep = np.concatenate([[True], np.diff(ticks) > 0])  # two edges in one tick cannot happen; guard anyway
    return ticks[keep], peak[keep], lev[keep]


@dataclass(frozen=True)
class WheelPattern:
    """What a record's edges say about its wheel: ``present`` edges per revolution between two gaps (the most
    common count), a gap of ``missing`` teeth (its interval is about missing + 1 pitches), ``revolutions`` complete
    revolutions counted and ``agree`` of them with exactly ``present`` edges."""

    present: int
    missing: int
    revolutions: int
    agree: int

    @property
    def teeth(self) -> int:
        return self.present + self.missing

    def __str__(self) -> str:
        return (f"{self.present} teeth and a {self.missing}-tooth gap per revolution ({self.teeth}-{self.missing}; "
                f"{self.agree} of {self.revolutions} revolutions)")


def wheel_pattern(ticks: np.ndarray) -> WheelPattern | None:
    """The tooth pattern of a record from its edge ticks alone (no wheel assumed), or None when no gap repeats.

    An interval is a gap when it is >= 1.5x the median of the two intervals either side (a single missing tooth
    gives 2x, the TU/e 60-2 gap 3.3-3.6x with its distorted neighbours); ``present`` is the most common count of
    edges from one gap to the next, ``missing`` the gap's width in pitches less one (comment below). Needs at least
    two complete revolutions (three gaps)."""
    t = np.asarray(ticks, dtype=np.int64)
    if t.shape[0] < 12:
        return None
    d = np.diff(t).astype(np.float64)
    dp = np.concatenate([np.full(2, np.nan), d, np.full(2, np.nan)])
    n = d.shape[0]
    ref = np.nanmedian(np.stack([dp[0:n], dp[1 : n + 1], dp[3 : n + 3], dp[4 : n + 4]]), axis=0)
    r = d / ref
    gaps = np.flatnonzero(r >= 1.5)
    if gaps.shape[0] < 3:
        return None
    counts = np.diff(gaps)  # edges from the first tooth after one gap to the first after the next
    values, freq = np.unique(counts, return_counts=True)
    present = int(values[np.argmax(freq)])
    # the gap in pitches: the teeth beside a VR gap are timed early or late (the TU/e 60-2 gap alone reads 3.3-3.6
    # pitches), which moves time between neighbouring intervals but not out of their sum; so the gap and its two
    # neighbours over the local pitch (median of the five intervals beyond them on either side) is missing + 3
    span = []
    for g in gaps[(gaps >= 6) & (gaps < n - 6)]:
        pitch = np.median(np.concatenate([d[g - 6 : g - 1], d[g + 2 : g + 7]]))
        span.append(d[g - 1 : g + 2].sum() / pitch)
    if not span:
        return None
    missing = int(np.rint(np.median(span))) - 3
    if present < 3 or missing < 1:
        return None
    return WheelPattern(present, missing, int(counts.shape[0]), int(freq.max()))


def detect_teeth(
    signal: np.ndarray,
    sample_rate_hz: float,
    tick_hz: float = 10e6,
    t0_ticks: int = 0,
    wheel_teeth: int = 60,
    wheel_missing: int = 2,
    level: float = 0.0,
    arm_frac: float = 0.05,
    fire_frac: float = 0.08,
    weak_frac: float = 0.5,
) -> ToothEdges:
    """Edges, integer ticks and sync of a sampled wheel signal.

    ``arm`` and ``fire`` sit at ``arm_frac`` and ``fire_frac`` of the rail-to-rail span above the low rail (1st and
    99th percentile of the record); with the TU/e rails (-0.74 / +4.05 V) that is -0.50 V and -0.36 V, 0.09 V below
    the weakest first-after-gap pulse seen (-0.27 V, E0NOLOAD1) and 6x the largest sample-to-sample floor noise.
    Ticks are ``t0_ticks + rint(position * tick_hz / sample_rate_hz)`` (0.1 us at 10 MHz, well below the
    interpolation error of about 1 us).
    """
    ticks, peak, lev = edge_ticks(signal, sample_rate_hz, tick_hz, t0_ticks, level, arm_frac, fire_frac, weak_frac)
    rs, re, turns, damage = sync_wheel(ticks, wheel_teeth, wheel_missing)
    tooth = np.full(ticks.shape[0], -1, dtype=np.int64)
    rev = np.full(ticks.shape[0], -1, dtype=np.int64)
    present = wheel_teeth - wheel_missing
    for k, a in enumerate(rs):
        tooth[a : a + present] = np.arange(present)
        rev[a : a + present] = k
    return ToothEdges(
        tick_hz=float(tick_hz),
        wheel_teeth=wheel_teeth,
        wheel_missing=wheel_missing,
        ticks=ticks,
        peak_v=peak,
        weak=lev < level,
        tooth_index=tooth,
        revolution=rev,
        rev_start=rs,
        rev_end=re,
        rev_turn=turns,
        damage=damage,
    )
