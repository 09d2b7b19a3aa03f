"""Cycle assembly: stream records of one engine -> one typed ``Cycle`` per 720 deg (design.md §1; physics.md §14).

    records -> EngineBuffers (rings) -> WheelTracker (gap sync, per-interval checks; drivers/assembly/wheel_sync.py)
            -> segments of verified edges, bridged into epochs -> 4-stroke phase (cam, else pressure)
            -> cycle windows [0, 4 pi] -> wait for pressure (bounded) -> resample onto the grid -> Cycle

Phase (cam votes, else the pressure of one cylinder; a pressure-phased epoch flips after three clear
contradictions in a row) and resync across short disturbances (the next cycle comes out as in an undisturbed run):
drivers/assembly/cycle_sync.py.

Skips (``skipped``, cycles by reason): spurious_tooth, missing_tooth, sync_lost, data_gap, buffer_overflow,
speed_out_of_range, pressure_missing, pressure_nan, phase_mismatch, clock_reset. ``truncated``: the cycle the stream
ends in, counted (``log_ends_mid_cycle``) when the stream holds at least ``TAIL_COUNTED_DEG`` of it (cylinder 1's
compression and expansion: its burn is in the log but not analysed); a shorter tail is not a cycle, and a stream
cut off rather than ended (``flush(count_tail=False)``: a loop seam, a live session's drop or stop) counts none. At
the end of the stream (``flush``) a cycle whose every edge arrived is kept although the edge that would verify its
last one never comes.
``stats`` counts events (segments, bridges, rejected candidates, cam votes, ring overflows, ...).
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.types import (
    AcquisitionInfo,
    CamBatch,
    Cycle,
    FreeEndToothBatch,
    LoadSample,
    PressureBlock,
    PressureFrame,
    StreamRecord,
    ToothBatch,
)
from frictionwatch.drivers.assembly.cycle_kernels import cycle_edges
from frictionwatch.drivers.assembly.cycle_parts import (
    Epoch,
    GridPlan,
    Segment,
    Wheel,
    grid_plan,
    load_mean,
    plan_ready,
    pressure_matrix,
    window_status,
)
from frictionwatch.drivers.assembly.cycle_phase import cycle_votes, firing_verdict, phase_windows
from frictionwatch.drivers.assembly.cycle_sync import EpochSync
from frictionwatch.drivers.assembly.engine_buffers import EngineBuffers
from frictionwatch.drivers.assembly.wheel_sync import WheelTracker

log = logging.getLogger(__name__)
_LOAD = 0  # _waiting_for: the head cycle waits for a load sample (cylinders are numbered from 1)
FOUR_PI = 4.0 * math.pi


@dataclass(slots=True)
class _Pending:
    index: int
    epoch: Epoch
    c: int
    ticks: np.ndarray  # int64 edges start..close
    pos: np.ndarray  # int64 epoch positions
    theta: np.ndarray  # nominal crank angle of the edges [rad], first <= 0, last >= 4 pi
    t_grid: np.ndarray  # timer ticks at the grid angles
    tooth: np.ndarray  # int64 wheel index of the edges
    t_first: int  # ticks[0] and ticks[-1] as Python ints (read at every emit / discard / build)
    t_last: int


TAIL_COUNTED_DEG = 360.0  # a stream that ends this far into a cycle lost that cycle (counted, not silent)


class CycleAssembler(EpochSync):
    """Assemble ``Cycle`` values from the records of one engine.

    Parameters
    ----------
    info : acquisition metadata (tick clock, wheel, first tooth angle, cam angle, instrumented cylinders)
    n_cyl : number of cylinders z (rows of ``Cycle.pressure``; cylinder k is row k-1)
    firing_angles : (z,) firing TDC of each cylinder on cylinder 1's crank angle [rad]
    grid_points : samples of the uniform grid over [0, 4 pi)
    speed_range_rpm : cycles whose mean speed is outside are skipped
    max_wait_s : how long (stream time) a complete cycle waits for late pressure before 'pressure_missing'
    first_index : the index of the first cycle (an assembler restarted within one stream continues its numbering)
    """

    def __init__(self, info: AcquisitionInfo, n_cyl: int, firing_angles: np.ndarray, grid_points: int = 720,
                 speed_range_rpm: tuple[float, float] = (50.0, 25000.0), max_wait_s: float = 0.5,
                 buffers: EngineBuffers | None = None, first_index: int = 0):
        fa = np.asarray(firing_angles, dtype=np.float64).ravel()
        if fa.shape[0] != n_cyl or n_cyl < 1:
            raise ValueError(f"firing_angles has {fa.shape[0]} values for {n_cyl} cylinders")
        if grid_points < 16:
            raise ValueError(f"grid_points must be >= 16, got {grid_points}")
        if not 0 < speed_range_rpm[0] < speed_range_rpm[1]:
            raise ValueError(f"speed_range_rpm must be (lo, hi) with 0 < lo < hi, got {speed_range_rpm}")
        if not info.tick_hz > 0:
            raise ValueError(f"tick_hz must be > 0, got {info.tick_hz}")
        bad = [c for c in info.pressure_cylinders if not 1 <= c <= n_cyl]
        if bad:
            raise ValueError(f"pressure_cylinders {bad} outside 1..{n_cyl}")
        if info.cam_deg is None and not info.pressure_cylinders:
            raise ValueError("no cam signal and no cylinder pressure: the 4-stroke phase cannot be found "
                             "(state cam_deg or pressure_cylinders in the AcquisitionInfo)")
        self.info = info
        self.n_cyl = int(n_cyl)
        self.firing = fa
        self.grid = np.arange(grid_points) * (FOUR_PI / grid_points)
        self.speed_range_rpm = (float(speed_range_rpm[0]), float(speed_range_rpm[1]))
        a0 = math.radians(info.first_tooth_deg) % (2 * math.pi)
        self.wheel = Wheel(info.wheel_teeth, info.wheel_missing, a0 / (2 * math.pi / info.wheel_teeth))
        self.a0 = a0
        self.a0_deg = info.first_tooth_deg % 360.0
        self.tracker = WheelTracker(info.wheel_teeth, info.wheel_missing)
        self.buf = buffers or EngineBuffers()
        self.wait_ticks = max_wait_s * info.tick_hz
        slow_cycle = 120.0 / self.speed_range_rpm[0] * info.tick_hz
        self.cam_wait_ticks = max(self.wait_ticks, 2.5 * slow_cycle)
        self.phase_cyl = (1 if 1 in info.pressure_cylinders else min(info.pressure_cylinders)) \
            if info.pressure_cylinders else None
        self.skipped: Counter[str] = Counter()
        self.truncated: Counter[str] = Counter()  # the cycle the stream ended in (module docstring)
        self.lost = 0  # cycles counted in skipped or truncated so far (a reader checks it instead of their sums)
        self.stats: Counter[str] = Counter()
        self._epoch: Epoch | None = None
        self._pending: deque[_Pending] = deque()
        self._next_index = int(first_index)
        self._index_clock: tuple[float, int, float] | None = None  # number_by_clock's (index, tick, cycle ticks)
        self._now = 0  # latest stream time seen [ticks]
        self._cam_next = 0  # next cam row to place
        self._discarded_at = 0  # tooth ring end at the last discard
        self._waiting_for: int | None = None  # cylinder whose pressure the head cycle waits for (_LOAD: the load)
        last_load = self.buf.load.last("t")
        self._load_newest: int | None = None if last_load is None else int(last_load)  # newest accepted load time
        self._load_hold = float(info.tick_hz)  # load_mean's zero-order hold [ticks]: beyond it the load is absent
        self._plan: GridPlan | None = None  # how the pressure matrix is filled, for _plan_buf at _plan_version
        self._plan_buf: EngineBuffers | None = None
        self._plan_version = -1
        self._phase_windows = phase_windows(self.grid, float(self.firing[self.phase_cyl - 1])) \
            if self.phase_cyl is not None else None  # grid points of the phase cylinder's two TDC windows (and tdc)
        self._phase_expected = self.phase_cyl in info.pressure_cylinders  # else: ask expected_cylinders
        self._win_h2: int | None = None  # the last wheel window asked for (EpochSync._window) and its answer
        self._win = (0, 0)
        self._discard_every = 2 * self.wheel.t  # tooth edges between two discards: a cycle's (design note 64)
        self._cam_rad = math.radians(info.cam_deg) if info.cam_deg is not None else math.nan  # stated cam angle

    # ---- input ------------------------------------------------------------------------------------------------
    def number_from(self, first_index: int) -> None:
        """Number the cycles from ``first_index`` on (before the first record): a service restarting on a store
        continues the engine's numbering (service.data_dir). Only neighbours are compared downstream (index ==
        previous + 1), so an offset changes nothing else."""
        if self._epoch is not None or self._pending:
            raise RuntimeError("the cycle numbering is set before the first record")
        if first_index < 0:
            raise ValueError(f"first_index must be >= 0, got {first_index}")
        self._next_index = int(first_index)

    def number_by_clock(self, index_at: float, tick: int, period_ticks: float) -> None:
        """Number the first cycle from the tooth clock (before the first record): the engine was at (fractional)
        cycle ``index_at`` at ``tick``, a cycle lasts ``period_ticks``. A restart after a hole where a live session
        dropped data numbers on over the cycles the engine turned meanwhile, not from the last cycle it met, so a
        stored run shows the hole in its indices (design note 124). Never below ``next_index``."""
        if self._epoch is not None or self._pending:
            raise RuntimeError("the cycle numbering is set before the first record")
        if not period_ticks > 0:
            raise ValueError(f"period_ticks must be > 0, got {period_ticks}")
        self._index_clock = (float(index_at), int(tick), float(period_ticks))

    def feed(self, record: StreamRecord) -> list[Cycle]:
        """File one record and return the cycles it completed (possibly none)."""
        filer = self._FILERS.get(type(record))  # one look-up instead of a chain of isinstance (~19 records a cycle)
        if filer is None:
            filer = self._filer_of(record)
        return filer(self, record)

    def _filer_of(self, record: StreamRecord):
        """The filer of a record whose type is not one of the six itself (a subclass), or TypeError."""
        for kind, filer in self._FILERS.items():
            if isinstance(record, kind):
                return filer
        raise TypeError(f"not a stream record: {type(record).__name__}")

    def _feed_teeth(self, record: ToothBatch) -> list[Cycle]:
        t = record.ticks
        if len(t) == 0:
            return []
        last = self.buf.teeth.last("t")
        if last is not None and int(t[0]) < last - self.wait_ticks:
            self._clock_reset()
        self.buf.add(record)
        self._now = max(self._now, int(t[-1]))
        self._run_tracker()
        return self._advance(flushing=False)

    def _feed_load(self, record: LoadSample) -> list[Cycle]:
        """~8 a cycle: only a cycle waiting for its load can move."""
        accepted = self.buf.add_load(record)
        t = int(record.ticks)
        if t > self._now:
            self._now = t
        if accepted:
            self._load_newest = t
            if self._waiting_for == _LOAD and self._pending:
                return self._emit(flushing=False)
        return []

    def _feed_frame(self, record: PressureFrame) -> list[Cycle]:
        """An indicating system: all cylinders in one record."""
        if self.buf.add_frame(record):
            v = record.values
            n = v.shape[-1] if type(v) is np.ndarray else np.shape(v)[-1]
            self._pressure_until(record.t0_ticks, int(record.t0_ticks + record.period_ticks * (n - 1)))
        if self._epoch is not None and self._epoch.phase is None:  # a waiting phase decision can move
            return self._advance(flushing=False)
        cyls = record.cylinders
        if self._pending and self._waiting_for in (cyls if type(cyls) is tuple else tuple(cyls)):
            return self._emit(flushing=False)
        return []  # the head cycle waits for another cylinder's pressure

    def _feed_block(self, record: PressureBlock) -> list[Cycle]:
        """CAN / DAQ: tens of blocks a cycle."""
        if self.buf.add_pressure(record):
            self._pressure_until(record.t0_ticks, int(record.t0_ticks + record.period_ticks * (len(record.values) - 1)))
        if self._epoch is not None and self._epoch.phase is None:
            return self._advance(flushing=False)
        if self._pending and record.cylinder == self._waiting_for:
            return self._emit(flushing=False)
        return []

    def _feed_cam(self, record: CamBatch) -> list[Cycle]:
        self.buf.add(record)
        if self._epoch is not None and self._epoch.phase is None:
            return self._advance(flushing=False)
        return self._emit(flushing=False) if self._pending else []

    def _feed_second_wheel(self, record: FreeEndToothBatch) -> list[Cycle]:
        """A second wheel: TwoWheelAssembler cuts it, not this one."""
        self.stats["second_wheel_ignored"] += 1
        return []

    # the filer of each record type (functions, not bound methods: a table of bound methods on the instance would be
    # a reference cycle, leaving every finished assembler with its rings to the cyclic garbage collector)
    _FILERS = {ToothBatch: _feed_teeth, PressureFrame: _feed_frame, LoadSample: _feed_load, PressureBlock: _feed_block,
               CamBatch: _feed_cam, FreeEndToothBatch: _feed_second_wheel}

    def _pressure_until(self, t0: float, end: int) -> None:
        """A pressure record's span filed: the newest time moved on, and a record spanning more than the pressure
        wait counted (it comes, keyed by its last sample, after the teeth have gone past its first samples: their
        cycles may already have been given up as pressure_missing); said once, so that the skips are not read as a
        sensor's fault (docs/replay-format.md, Batching)."""
        if end - t0 > self.wait_ticks:
            if not self.stats["pressure_record_longer_than_wait"]:
                log.warning("a pressure record spans %.2f s, more than the %.2f s a cycle waits for its pressure: "
                            "cycles before its end may be skipped as pressure_missing (write shorter records)",
                            (end - t0) / self.info.tick_hz, self.wait_ticks / self.info.tick_hz)
            self.stats["pressure_record_longer_than_wait"] += 1
        if end > self._now:
            self._now = end

    @property
    def next_index(self) -> int:
        """The index the next cycle gets (every cycle met so far, assembled or skipped, has a lower one)."""
        return self._next_index

    def flush(self, count_tail: bool = True) -> list[Cycle]:
        """End of stream: emit every complete cycle now, without waiting for more pressure. ``count_tail`` False:
        the stream was cut off rather than ended (a replay's loop seam, a hole where a live session dropped data, a
        stop), so the cycle it is cut in is not counted (nor logged) as ``log_ends_mid_cycle``: its loss is the cut's,
        said where the cut is said."""
        return self._advance(flushing=True, count_tail=count_tail)

    @property
    def expected_cylinders(self) -> tuple[int, ...]:
        if self.info.pressure_cylinders:
            return tuple(self.info.pressure_cylinders)
        return tuple(sorted(c for c in self.buf.pressure if 1 <= c <= self.n_cyl))

    # ---- cycles -------------------------------------------------------------------------------------------------
    def _advance(self, flushing: bool, count_tail: bool = True) -> list[Cycle]:
        if self._epoch is not None:
            self._advance_epoch(self._epoch, flushing, count_tail)
        out = self._emit(flushing) if self._pending else []
        self._discard(force=flushing)
        return out

    def _advance_epoch(self, ep: Epoch, flushing: bool, count_tail: bool = True) -> None:
        if ep.phase is None and self.info.cam_deg is not None:
            self._place_cams(ep)
        if ep.phase is None:
            cam_late = self.info.cam_deg is None or flushing or self._now - ep.t_start > self.cam_wait_ticks
            if not cam_late:
                return
            self._probe_pressure(ep, flushing)
            if ep.phase is None:
                return
        elif self.info.cam_deg is not None and self._cam_next < self.buf.cam.end:  # (else nothing to place)
            self._place_cams(ep)
        lo_rpm, hi_rpm = self.speed_range_rpm
        w = self.wheel
        while True:
            c = ep.next_c
            ps, pe = self._window(ep, c)
            status, seg = window_status(ep, ps, pe)
            if flushing and status == "wait" and self._arrived_whole(seg, ps, pe):
                status = "complete"  # the stream ended right after it: no edge will come to verify its last
            if status in ("wait", "before"):
                if flushing and status == "wait" and count_tail:
                    self._count_tail(ep, c, seg, ps, pe)
                return
            index = ep.index_of(c)
            ep.next_c = c + 1
            if index >= self._next_index:
                self._next_index = index + 1
            if status == "broken":
                self._skip(seg.reason or "sync_lost", index)
                continue
            s0, s1 = seg.seq_of(ps), seg.seq_of(pe)
            teeth = self.buf.teeth
            if not teeth.start <= s0 <= s1 < teeth.end:  # its edges were overwritten (a batch beyond the ring)
                self._skip("buffer_overflow", index)
                continue
            col = teeth.cols["t"]
            i0 = s0 % teeth.capacity
            t_first, t_last = int(col[i0]), int(col[i0 + s1 - s0])
            rpm = (pe - ps) * w.pitch / ((t_last - t_first) / self.info.tick_hz) * 30.0 / math.pi
            if not lo_rpm <= rpm <= hi_rpm:
                self._skip("speed_out_of_range", index)
                continue
            m = s1 - s0 + 1  # edges, their positions and angles, the grid times: one kernel (drivers/assembly/cycle_kernels.py)
            ticks, pos, tooth, theta = (np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m, np.int64),
                                        np.empty(m))
            t_grid = np.empty(self.grid.shape[0])
            cycle_edges(col, i0, m, w.ordinal(seg.first_pos) + (s0 - seg.first_seq), w.n, w.t,
                         -2 * w.n * c + w.n * int(ep.phase), self.a0_deg, self.grid, ticks, pos, tooth, theta, t_grid)
            self._pending.append(_Pending(index, ep, c, ticks, pos, theta, t_grid, tooth, t_first, t_last))

    def _arrived_whole(self, seg, ps: int, pe: int) -> bool:
        """Every edge of window ps..pe is in the ring and verified but its last (which waits for the next)."""
        return seg is not None and seg.reason is None and seg.seq_of(pe) <= min(seg.good + 1, self.buf.teeth.end - 1)

    def _count_tail(self, ep: Epoch, c: int, seg, ps: int, pe: int) -> None:
        """The stream ended inside cycle c's window: count it when it holds >= TAIL_COUNTED_DEG of it."""
        if seg is None:
            return
        held_deg = 720.0 * (min(seg.good_pos, pe) - ps) / (pe - ps)
        if held_deg >= TAIL_COUNTED_DEG:
            ep.next_c = c + 1
            self.truncated["log_ends_mid_cycle"] += 1
            self.lost += 1
            log.warning("cycle %d skipped: the stream ends %.0f deg into it (a cycle is 720 deg)", ep.index_of(c),
                        held_deg)

    def _skip(self, reason: str, index: int) -> None:
        if self.skipped[reason] == 0:
            log.warning("cycle %d skipped: %s", index, reason)
        self.skipped[reason] += 1
        self.lost += 1

    def _grid_plan(self) -> GridPlan:
        """The pressure plan of the current buffers (remade when a pressure group appears or buffers reset)."""
        buf = self.buf
        if self._plan is None or self._plan_buf is not buf or self._plan_version != buf.groups_version:
            self._plan = grid_plan(buf, self.expected_cylinders, self.n_cyl)
            self._plan_buf, self._plan_version = buf, buf.groups_version
        return self._plan

    def _ready(self, p: _Pending) -> bool:
        """Every instrumented cylinder has a sample at or after the cycle's last grid time, and the load stream
        (if it is present: a sample within load_mean's hold) one at or after its last edge, so the cycle's load mean
        does not depend on whether the load reading came before or after the pressure (serial vs CAN arrival
        order). Else remember what is awaited (a cylinder, or _LOAD), so that only records carrying it wake the
        queue up; the wait is bounded by wait_ticks, as for pressure."""
        waiting = plan_ready(self._grid_plan(), p.t_grid[-1])
        newest = self._load_newest
        if waiting is None and newest is not None and newest < p.t_last and p.t_last - newest <= self._load_hold:
            waiting = _LOAD
        self._waiting_for = waiting
        return waiting is None

    def _emit(self, flushing: bool) -> list[Cycle]:
        out: list[Cycle] = []
        pending = self._pending
        while pending:
            p = pending[0]
            if not (flushing or self._now - p.t_last > self.wait_ticks or self._ready(p)):
                break  # not timed out: wait for its pressure and load
            pending.popleft()
            cyc = self._build(p)
            if cyc is not None:
                out.append(cyc)
        return out

    def _build(self, p: _Pending) -> Cycle | None:
        ep = p.epoch
        t_grid = p.t_grid
        if ep.phase_source == "cam" and ep is self._epoch and self._cam_next < self.buf.cam.end \
                and self.info.cam_deg is not None:
            self._place_cams(ep)  # a cam edge that came after the teeth (an older epoch has all it will get)
        t_first, t_last = p.t_first, p.t_last
        n_votes = cycle_votes(ep.cam_votes, t_first, t_last, ep.phase)
        if n_votes < 0:  # a vote against the epoch's phase
            self._skip("phase_mismatch", p.index)
            return None
        flags: list[str] = []
        if self.info.cam_deg is not None and not n_votes:
            flags.append("no_cam_edge")
        pressure, reason = pressure_matrix(self.buf, self._grid_plan(), t_grid, self.n_cyl)
        if pressure is None:
            self._skip(reason, p.index)
            return None
        if self.phase_cyl is not None and (self._phase_expected or self.phase_cyl in self.expected_cylinders):
            verdict = firing_verdict(pressure[self.phase_cyl - 1], self.grid, self._phase_windows[2], self._phase_windows)
            if verdict < 0:
                ep.mismatch_run += 1
                self._skip("phase_mismatch", p.index)
                if ep.phase_source == "pressure" and ep.mismatch_run >= 3:
                    self.stats["phase_flipped"] += 1
                    self._set_phase(ep, 1 - int(ep.phase), "pressure", from_pos=int(p.pos[-1]))
                    for q in [q for q in self._pending if q.epoch is ep]:
                        self._pending.remove(q)
                        self._skip("phase_mismatch", q.index)
                return None
            ep.mismatch_run = 0
            if verdict == 0:
                flags.append("phase_unchecked")
        load = load_mean(self.buf.load, p.ticks, p.theta, self.info.tick_hz)
        self.stats["cycles"] += 1
        return Cycle(index=p.index, tick_hz=self.info.tick_hz, tooth_ticks=p.ticks, tooth_angle=p.theta,
                     tooth_index=p.tooth, grid=self.grid.copy(), pressure=pressure,
                     load_torque=load.torque, load_power=load.power, phase_source=ep.phase_source, flags=tuple(flags),
                     load_early=load.torque_early, load_late=load.torque_late)

    # ---- housekeeping -------------------------------------------------------------------------------------------
    def _discard(self, force: bool = False) -> None:
        """Release ring rows nothing can need any more (so overflow counts only real losses). Runs when the
        tooth ring has grown by a cycle's edges since the last time (it costs a few searches per ring: once a cycle,
        not once a tooth batch; the rings hold many cycles, so the later release loses nothing)."""
        teeth = self.buf.teeth
        start, end = teeth.start, teeth.end
        if not force and end - self._discarded_at < self._discard_every:
            return
        self._discarded_at = end
        # teeth within the pressure wait of now stay, so a late cam edge can still be placed between two of them
        keep = teeth.searchsorted("t", self._now - self.wait_ticks)
        need = self.tracker.oldest_needed()
        if need < keep:
            keep = need
        ep = self._epoch
        if ep is not None:
            seg = ep.segments[-1]
            if ep.phase is not None:  # the next cycle's window start (or the running segment's first edge)
                ps = self._window(ep, ep.next_c)[0]
                k_ep = seg.seq_of(ps) if ps >= seg.first_pos else seg.first_seq
                if k_ep < seg.first_seq:
                    k_ep = seg.first_seq
            elif ep.probe is None:
                k_ep = ep.segments[0].first_seq
            else:
                k_ep = max(seg.first_seq, self._seq_or(seg, self.wheel.window(ep.probe)[0]))
            if k_ep < keep:
                keep = k_ep
        keep = max(start, min(keep, end))
        t_keep = float(teeth.get("t", keep)) if keep < end else float(self._now)
        if self._pending:
            t_keep = min(t_keep, float(self._pending[0].t_first))
        teeth.discard_before(keep - 2)
        self.buf.release_before(t_keep, self.info.tick_hz, self._cam_next)
        if ep is not None and len(ep.cam_votes) > 64:
            ep.cam_votes = [v for v in ep.cam_votes if v[0] >= t_keep]

    @staticmethod
    def _seq_or(seg: Segment, pos: int) -> int:
        return seg.seq_of(pos) if pos >= seg.first_pos else seg.first_seq

    def _clock_reset(self) -> None:
        """The timer went backwards by more than the pressure wait: a new acquisition. Forget everything."""
        self.stats["clock_reset"] += 1
        for _ in self._pending:
            self._skip("clock_reset", -1)
        self._pending.clear()
        self.buf = EngineBuffers(self.buf.teeth.capacity, self.buf.cam.capacity, self.buf.pressure_capacity,
                                 self.buf.load.capacity)
        self.tracker = WheelTracker(self.info.wheel_teeth, self.info.wheel_missing)
        self._epoch = None
        self._cam_next = 0
        self._now = 0
        self._discarded_at = 0
        self._load_newest = None

    def dropped(self) -> Counter[str]:
        """Rows lost to ring overflow and refused out-of-order input, by stream."""
        return self.buf.dropped() + Counter({f"rejected_{k}": v for k, v in self.buf.rejected.items()})
