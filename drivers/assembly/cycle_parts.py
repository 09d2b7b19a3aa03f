"""Pieces of the cycle assembler (drivers/assembly/cycles.py): wheel positions, synced segments, epochs, pressure and load.

Positions. Every edge of a synced segment has a position in pitches, ``pos``; its wheel index is ``pos mod N``
(teeth 0..T-1 exist, T..N-1 are the gap). Within one epoch positions continue across resyncs, so the nominal crank
angle of an edge is theta = pos * 2 pi / N + a0 + 2 pi P (a0 = angle of tooth 0 mod 2 pi, P = 4-stroke phase bit)
and cycle c spans theta in [4 pi c, 4 pi (c + 1)].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numba
import numpy as np
from frictionwatch.drivers.assembly.engine_buffers import EngineBuffers
from frictionwatch.drivers.assembly.frame_store import FrameChannel, FrameGroup
from frictionwatch.drivers.assembly.pressure_kernels import ROW_NAN, ROW_OK, pressure_row
from frictionwatch.drivers.assembly.pressure_ring import PressureGroup
from frictionwatch.drivers.assembly.resample import pchip_eval
from frictionwatch.drivers.assembly.ringbuffer import RingBuffer, search_sorted


@dataclass(frozen=True)
class Wheel:
    """N positions, k missing, T = N - k teeth; ``a0_pitch`` = angle of tooth 0 (mod 2 pi) in pitches."""

    n: int
    k: int
    a0_pitch: float
    # derived, stored once: read ~40 times per cycle on the assembly's hot path (a property costs a call each)
    t: int = field(init=False, repr=False, compare=False)
    pitch: float = field(init=False, repr=False, compare=False)


    def __post_init__(self) -> None:
        object.__setattr__(self, "t", self.n - self.k)
        object.__setattr__(self, "pitch", 2.0 * math.pi / self.n)

    def ordinal(self, pos: int) -> int:
        """Running count of existing teeth up to ``pos`` (pos must be a tooth)."""
        return (pos // self.n) * self.t + pos % self.n

    def pos_of_ordinal(self, o: np.ndarray | int):
        return (o // self.t) * self.n + o % self.t

    def tooth_at_or_before(self, x: float) -> int:
        p = math.floor(x + 1e-9)
        j = p % self.n
        return p - (j - (self.t - 1)) if j >= self.t else p

    def tooth_at_or_after(self, x: float) -> int:
        p = math.ceil(x - 1e-9)
        j = p % self.n
        return p + (self.n - j) if j >= self.t else p

    def window(self, h2: int) -> tuple[int, int]:
        """Start and closing tooth of the 720 deg window whose start is 2 pi * h2 in tooth-0 angle (a0 included)."""
        lo = self.n * h2 - self.a0_pitch
        return self.tooth_at_or_before(lo), self.tooth_at_or_after(lo + 2 * self.n)


@dataclass
class Segment:
    """A run of verified edges: edge ``first_seq`` is at epoch position ``first_pos``; ``good`` is its last good edge."""

    wheel: Wheel
    first_seq: int
    first_pos: int
    t_first: int
    good: int
    t_good: int = 0
    reason: str | None = None  # why it ended (None while running)
    # first_seq - ordinal(first_pos), fixed at creation: seq_of runs ~10 times per cycle on the hot path
    _base: int = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._base = self.first_seq - self.wheel.ordinal(self.first_pos)

    def seq_of(self, pos: int) -> int:
        w = self.wheel  # = first_seq + ordinal(pos) - ordinal(first_pos), the same integers
        return self._base + (pos // w.n) * w.t + pos % w.n

    def pos_of(self, seq: np.ndarray | int):
        return self.wheel.pos_of_ordinal(seq - self._base)  # ordinal(first_pos) + (seq - first_seq): same integers

    @property
    def good_pos(self) -> int:
        return int(self.pos_of(self.good))


@dataclass
class Epoch:
    """Segments that share one position count (bridged across short disturbances) and one 4-stroke phase."""

    segments: list[Segment]
    t_start: int
    phase: int | None = None
    phase_source: str = ""
    next_c: int = 0
    c0: int = 0
    index_base: int = 0
    probe: int | None = None  # next rev-aligned window tried for the pressure phase test
    undecided: int = 0  # windows in a row the pressure phase test could not decide (one revolution apart)
    cam_votes: list[tuple[int, int]] = field(default_factory=list)  # (tick, phase bit)
    mismatch_run: int = 0

    def segment_at(self, pos: int) -> Segment | None:
        for seg in reversed(self.segments):
            if seg.first_pos <= pos:
                return seg
        return None

    def index_of(self, c: int) -> int:
        return self.index_base + (c - self.c0)


def nominal_angle(n: int, a0_deg: float, pos: np.ndarray, c: int, phase: int) -> np.ndarray:
    """Crank angle [rad] of edges at ``pos`` within cycle c (wheel of n positions, tooth 0 at ``a0_deg``), built in
    degrees from integers so that edges on 0 and 720 deg land exactly there (360/N is exact for the usual wheels)."""
    deg = a0_deg + (pos - 2 * n * c + n * phase) * (360.0 / n)
    return np.radians(deg)


def grid_times(theta: np.ndarray, ticks: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Timer ticks (float) at the ``grid`` angles from the monotone t(theta) through the tooth edges."""
    t0 = ticks[0]
    return pchip_eval(theta, (ticks - t0).astype(np.float64), grid) + float(t0)


def bridge_offset(prev: Segment, first_pos_rel: int, t_first: int, max_revs: float = 3.0) -> int | None:
    """Offset (a multiple of N) that puts a new segment's anchor-relative positions on the count of the epoch whose
    last segment is ``prev``, or None. The pitches between the two are estimated from the elapsed time at the mean
    pitch time of ``prev``; the new segment's wheel index fixes the rest. Accepted only if the silence is shorter
    than ``max_revs`` revolutions and the estimate lands within a quarter turn of a consistent position."""
    w = prev.wheel
    if not (prev.good > prev.first_seq and prev.t_good > prev.t_first and t_first > prev.t_good):
        return None
    p_last = prev.good_pos
    tau = (prev.t_good - prev.t_first) / (p_last - prev.first_pos)
    est = p_last + (t_first - prev.t_good) / tau
    off = w.n * round((est - first_pos_rel) / w.n)
    if abs(first_pos_rel + off - est) <= w.n / 4 and est - p_last <= max_revs * w.n and first_pos_rel + off > p_last:
        return int(off)
    return None


def window_status(epoch: Epoch, ps: int, pe: int) -> tuple[str, Segment | None]:
    """'complete' (all edges ps..pe plus one look-ahead verified), 'wait', 'broken' (a segment ended inside) or
    'hole' (starts after its segment's end: broken if a later segment exists, else wait)."""
    seg = epoch.segments[-1]  # the usual answer of segment_at: the running segment
    if seg.first_pos > ps:
        seg = epoch.segment_at(ps)
        if seg is None:
            return "before", None
    s_end = seg.seq_of(pe)
    if s_end <= seg.good:
        return "complete", seg
    if seg.reason is None:
        return "wait", seg
    s_start = seg.seq_of(ps)
    if s_start > seg.good:
        return ("broken" if seg is not epoch.segments[-1] else "wait"), seg
    return "broken", seg


def cycle_grid_times(t_grid: np.ndarray) -> np.ndarray:
    """``t_grid`` as a C-contiguous float64 vector of increasing times (>= 2 points: a cycle's grid), or ValueError."""
    q = t_grid if type(t_grid) is np.ndarray and t_grid.dtype == np.float64 and t_grid.flags.c_contiguous \
        else np.ascontiguousarray(t_grid, dtype=np.float64)
    if q.ndim != 1 or q.shape[0] < 2 or not q[0] < q[-1]:
        raise ValueError(f"grid times must be 1-D, >= 2 points, first < last; got shape {q.shape}")
    return q


def pressure_on_grid(ring: RingBuffer, t_grid: np.ndarray) -> tuple[np.ndarray | None, str]:
    """Samples of one cylinder at the sorted grid times (linear in time). Returns (row, '') or (None, reason).

    Reasons: 'pressure_missing' (the ring does not cover the window, or a hole of more than 1.5 sample periods),
    'pressure_nan' (a NaN sample inside the window). The numpy reference is in tests/drivers/test_pressure_kernels.py."""
    q = cycle_grid_times(t_grid)
    if len(ring) < 2:
        return None, "pressure_missing"
    out = np.empty(q.shape[0])
    if isinstance(ring, FrameChannel):  # values kept in frames: the group kernel on this row alone
        code = ring.row_on_grid(q, out)
    else:
        code = pressure_row(ring.cols["t"], ring.cols["p"], ring.start, ring.end, q, out)
    if code == ROW_OK:
        return out, ""
    return None, ("pressure_nan" if code == ROW_NAN else "pressure_missing")


@dataclass
class GridPlan:
    """How a cycle's (z, n) pressure matrix is filled from the pressure groups: one kernel call per group.

    calls : (group, rows, codes) per group holding an expected cylinder; rows[r] = matrix row of the group's row r
        (cylinder - 1), -1 if that cylinder is not expected; codes (int64) receives each row's ROW_* code
    order : (cylinder, group or None) by first position in ``expected``: the readiness check (one per group, in
        the order that finds the same first unready cylinder as a per-cylinder loop)
    reasons : (cylinder, index into calls or -1 if no group, row) in ``expected`` order: the skip reason of a
        failed matrix is that of the first failing cylinder, as in a per-cylinder loop
    """

    expected: tuple[int, ...]
    calls: list[tuple[PressureGroup | FrameGroup, np.ndarray, np.ndarray]]
    order: list[tuple[int, PressureGroup | FrameGroup | None]]
    reasons: list[tuple[int, int, int]]
    missing: bool
    nan_rows: np.ndarray  # matrix rows of the cylinders not expected (NaN rows)


def grid_plan(buf: EngineBuffers, expected: tuple[int, ...], n_cyl: int) -> GridPlan:
    """The ``GridPlan`` of the expected cylinders (1..n_cyl) over the current groups of ``buf``."""
    want = set(expected)
    calls: list[tuple[PressureGroup | FrameGroup, np.ndarray, np.ndarray]] = []
    index: dict[int, int] = {}
    order: list[tuple[int, PressureGroup | FrameGroup | None]] = []
    reasons: list[tuple[int, int, int]] = []
    for cyl in expected:
        ch = buf.pressure.get(cyl)
        if ch is None:
            order.append((cyl, None))
            reasons.append((cyl, -1, 0))
            continue
        g = ch.group
        if id(g) not in index:
            index[id(g)] = len(calls)
            rows = np.array([c - 1 if c in want and 1 <= c <= n_cyl else -1 for c in g.cylinders], dtype=np.int64)
            calls.append((g, rows, np.zeros(len(g.cylinders), dtype=np.int64)))
            order.append((cyl, g))
        reasons.append((cyl, index[id(g)], ch.row))
    nan_rows = np.array([r for r in range(n_cyl) if r + 1 not in want], dtype=np.int64)
    return GridPlan(tuple(expected), calls, order, reasons, any(ci < 0 for _, ci, _ in reasons), nan_rows)


def plan_ready(plan: GridPlan, t_end: float) -> int | None:
    """None if every expected cylinder has a sample at or after ``t_end``, else the first one that has not."""
    for cyl, g in plan.order:
        if g is None or g.end == g.start or g.newest < t_end:
            return cyl
    return None


def pressure_matrix(buf: EngineBuffers, plan: GridPlan, t_grid: np.ndarray, n_cyl: int
                    ) -> tuple[np.ndarray | None, str]:
    """(z, n) pressure [Pa] of the expected cylinders at the grid times (NaN rows for the others), or (None,
    reason of the first failing expected cylinder): ``pressure_on_grid`` row by row, one kernel call per group."""
    q = cycle_grid_times(t_grid)
    out = np.empty((n_cyl, q.shape[0]))  # every expected row is written by the kernel
    if plan.nan_rows.shape[0]:
        out[plan.nan_rows] = np.nan
    bad = 0
    for g, rows, codes in plan.calls:
        bad += g.rows_on_grid(q, rows, out, codes)
    if bad == 0 and not plan.missing:
        return out, ""
    for _, ci, r in plan.reasons:
        if ci < 0:
            return None, "pressure_missing"
        code = plan.calls[ci][2][r]
        if code != ROW_OK:
            return None, ("pressure_nan" if code == ROW_NAN else "pressure_missing")
    return out, ""


class LoadMeans(NamedTuple):
    """A cycle's load readings weighted over its time fraction u in [0, 1] (``load_mean``): torque [N m] and power
    [W] means; torque_early, torque_late [N m] the torque's means under the weights 2 (1 - u) and 2 u (each the
    mean for a constant load), the two halves of the transient balance's triangle over two cycles
    (core.monitor.balance.mean_balance.transient_balance: the late one of the cycle before, the early one of
    this). NaN: not measured."""

    torque: float
    power: float
    torque_early: float
    torque_late: float


def load_mean(ring: RingBuffer, ticks: np.ndarray, angles: np.ndarray, hold_ticks: float) -> LoadMeans:
    """The load readings over the cycle whose edges are at ``ticks`` [ticks] and nominal ``angles`` [rad]
    (angles[0] <= 0 < angles[1], angles[-2] < 4 pi <= angles[-1]), each reading standing for its own span: from
    the reading before it (at most ``hold_ticks`` back) to its tick, the span a dyno or generator controller
    averages a reading over (the simulator's readings are exactly that: core.plant.sim_records). A reading's
    weight is its span's part of the cycle's time from theta = 0 to 4 pi (the edges' times interpolated linearly),
    so the first reading at or after the cycle's end counts for the cycle's last part: a load step late in the
    cycle, in the reading after its end, enters the cycle's mean (design note 76; the plain mean of the readings
    stamped inside lagged it by up to a reading's period: deutz two-point s9 cycle 145 read 31.4 N m for the
    truth's 141). In time, not in crank angle: a reading is a time mean, and the load's ripple work <T_L~ w_L~>
    is the monitor's to add (core.monitor.monitor, at the load's node, not the flywheel's; weighting the spans by
    the flywheel's angle moved maruti's settling 1500 rpm cycles' load a further -0.018 N m from the truth's).
    A reading with no reading before it retained stands for the cycle's part up to it. No reading after the
    cycle's first edge: the last one before it no older than ``hold_ticks`` (zero-order hold of a slow CAN
    reading), early and late the same; else NaN."""
    cols = ring.cols
    return LoadMeans(*load_means((cols["t"], cols["torque"], cols["power"]), ring.start, ring.end, ticks, angles,
                                 float(hold_ticks)))


@numba.njit(cache=True)
def load_means(cols, start, end, ticks, angles, hold_ticks):
    """``load_mean`` in one compiled call (its two searches, the spans' sums and the hold; ~2 us against ~7 for the
    Python around the sums): ``cols`` the load ring's mirrored columns (t int64, torque, power; 2 cap each), its
    retained rows [start, end). Returns (torque, power, torque early, torque late), NaN where not measured."""
    nan = np.nan
    if end == start:
        return nan, nan, nan, nan
    t_col, torque, power = cols
    cap = t_col.shape[0] // 2
    i0 = start % cap
    n = end - start
    t_lo = float(ticks[0])
    t_hi = float(ticks[ticks.shape[0] - 1])
    a = start + search_sorted(t_col, i0, n, t_lo, np.bool_(True))  # the first reading whose span reaches past t_lo
    b = min(start + search_sorted(t_col, i0, n, t_hi, np.bool_(False)) + 1, end)  # through the first at or after t_hi
    if b > a:
        first = max(a - 1, start)
        ia, ifirst = a % cap, first % cap
        w, w_torque, w_power, early, early_torque, late, late_torque = span_weighted_load(
            t_col[ifirst : ifirst + (b - first)], torque[ia : ia + (b - a)], power[ia : ia + (b - a)], first < a,
            t_lo, angles, ticks, hold_ticks)
        if w > 0.0:
            return w_torque / w, w_power / w, early_torque / early, late_torque / late
    if a > start and t_lo - t_col[(a - 1) % cap] <= hold_ticks:
        q = torque[(a - 1) % cap]
        return q, power[(a - 1) % cap], q, q
    return nan, nan, nan, nan


@numba.njit(cache=True)
def span_weighted_load(t, torque, power, has_previous, t_lo, angles, ticks, hold_ticks):
    """``load_mean``'s sums in one pass (a cycle holds a handful of readings: a dozen numpy calls on them cost ~30 us
    a cycle, this ~2). Reading k (torque[k], power[k], stamped t[k + 1] if ``has_previous`` else t[k]) stands for
    the span from the reading before it (t[k]; the first without one from t_lo), at most ``hold_ticks`` long; u_s,
    u_e its ends as fractions of the cycle's time from theta = 0 to 4 pi (``angles``, ``ticks`` interpolated
    linearly), clipped to [0, 1]. Returns (sum w, sum w torque, sum w power, sum e, sum e torque, sum l,
    sum l torque) with w = u_e - u_s, l = u_e^2 - u_s^2 (the integral of 2 u), e = 2 w - l (of 2 (1 - u)). The
    numpy reference: tests/drivers/test_cycle_parts.py ``load_mean_reference``."""
    t0 = np.interp(0.0, angles, ticks)
    span = np.interp(4.0 * np.pi, angles, ticks) - t0
    off = 1 if has_previous else 0
    sw = sw_torque = sw_power = se = se_torque = sl = sl_torque = 0.0
    for k in range(torque.shape[0]):
        end = float(t[k + off])
        start = float(t[k + off - 1]) if k + off >= 1 else t_lo
        start = max(start, end - hold_ticks)
        u_s = min(max((start - t0) / span, 0.0), 1.0)
        u_e = min(max((end - t0) / span, 0.0), 1.0)
        w = u_e - u_s
        sq = u_e * u_e - u_s * u_s
        sw += w
        sw_torque += w * torque[k]
        sw_power += w * power[k]
        se += 2.0 * w - sq
        se_torque += (2.0 * w - sq) * torque[k]
        sl += sq
        sl_torque += sq * torque[k]
    return sw, sw_torque, sw_power, se, se_torque, sl, sl_torque
