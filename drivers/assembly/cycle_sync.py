"""Sync, epochs and 4-stroke phase of the cycle assembler (drivers/assembly/cycles.py): the ``CycleAssembler`` methods that
turn tracker events into segments and epochs and find each epoch's phase.

Phase. With a cam (``info.cam_deg``) each cam edge, placed between its two tooth edges, votes for the phase bit; the
first vote fixes the epoch's phase and every cycle is checked against the votes inside it. Without a cam (or when
no cam edge came within the wait) the pressure of the first instrumented cylinder decides (physics.md §14.5: the
mean pressure within +-30 deg of its firing TDC beats that at its gas-exchange TDC, motored or fired).

Resync without losing the next cycle. A disturbance ends the verified segment one edge before it; the tracker finds
the next gap, confirms a full revolution and extends the new segment backwards to just after the disturbance. If the
silence between the two segments is short (< 3 revolutions) and their positions fit the wheel within a quarter turn,
the new segment joins the same epoch, so position count, phase and cycle index carry on.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from frictionwatch.drivers.assembly.cycle_parts import (
    Epoch,
    Segment,
    bridge_offset,
    grid_times,
    nominal_angle,
    pressure_on_grid,
    window_status,
)
from frictionwatch.drivers.assembly.cycle_phase import firing_verdict, place_cams
from frictionwatch.drivers.assembly.wheel_sync import EV_END, EV_SEGMENT, REASONS

log = logging.getLogger(__name__)

# undecided probe windows in a row before they count as cycles lost (``phase_undecided``): a healthy channel, fired
# or motored, decides at its first window; an engine coasting to a stop leaves up to two undecided windows in its
# last epoch (the measured TU/e coast-downs, tests/realdata/test_tue_pipeline.py: counting from the second window
# added one cycle beyond the reader's exact count there); a dead or negated channel never decides. Four windows (two
# cycles of wheel signal, both phases tried twice) are past both; counted from then on, the backlog included.
UNDECIDED_WINDOWS = 4


class EpochSync:
    """Mixin of ``drivers.assembly.cycles.CycleAssembler``: tracker events -> segments / epochs, and the phase of an epoch.
    It uses the assembler's attributes (buf, tracker, wheel, info, stats, _epoch, ...); it has no state of its own."""

    # ---- sync ---------------------------------------------------------------------------------------------------
    def _run_tracker(self) -> None:
        ring = self.buf.teeth
        tracker = self.tracker
        need = tracker.oldest_needed()
        if need < ring.start:  # edges the tracker still needed were overwritten
            self._end_segment(ring.start - 1, "buffer_overflow")
            tracker.reset(ring.start)
            self.stats["tracker_reset"] += 1
            need = ring.start
        if need >= ring.end:
            return
        events = tracker.advance_from(ring.view("t", need, ring.end), need)  # need: just read from the tracker
        for typ, a, b, _c in events:
            if typ == EV_SEGMENT:
                self._new_segment(a, b)
            elif typ == EV_END:
                self._end_segment(a, REASONS[b])
            else:
                self.stats["candidate_rejected"] += 1
        ep = self._epoch
        if ep is not None:
            seg = ep.segments[-1]
            if seg.reason is None:
                good = tracker.good_if_synced()  # (-1: not synced)
                if good >= 0:
                    seg.good = good

    def _end_segment(self, last_good: int, reason: str) -> None:
        self.stats[f"tooth:{reason}"] += 1
        ep = self._epoch
        if ep is None or ep.segments[-1].reason is not None:
            return
        seg = ep.segments[-1]
        seg.good = last_good
        if seg.good >= seg.first_seq and self.buf.teeth.start <= seg.good:
            seg.t_good = int(self.buf.teeth.get("t", seg.good))
        seg.reason = reason
        self._advance_epoch(ep, flushing=False)  # cycles cut by the end are skipped now

    def _new_segment(self, first_seq: int, first_pos_rel: int) -> None:
        self.stats["segments"] += 1
        w = self.wheel
        t_first = int(self.buf.teeth.get("t", first_seq))
        ep = self._epoch
        off = None if ep is None else bridge_offset(ep.segments[-1], first_pos_rel, t_first)
        if off is not None:
            ep.segments.append(Segment(w, first_seq, first_pos_rel + off, t_first, first_seq))
            self.stats["bridged"] += 1
            return
        # a new epoch: position count, phase and cycle numbering start afresh
        self.stats["epochs"] += 1
        self._epoch = Epoch([Segment(w, first_seq, first_pos_rel, t_first, first_seq)], t_start=t_first)

    # ---- phase --------------------------------------------------------------------------------------------------
    def _place_cams(self, ep: Epoch) -> None:
        if self._cam_next >= self.buf.cam.end:  # no cam row since the last call: place_cams would change nothing
            return
        self._cam_next, bit = place_cams(ep, self.buf.cam, self.buf.teeth, self._cam_next, self.wheel, self.a0,
                                         self._cam_rad, self.stats)
        if ep.phase is None and bit is not None:
            self._set_phase(ep, bit, "cam")

    def _set_phase(self, ep: Epoch, bit: int, source: str, from_pos: int | None = None) -> None:
        ep.phase, ep.phase_source = bit, source
        self.stats[f"phase_{source}"] += 1
        lo = ep.segments[0].first_pos if from_pos is None else from_pos
        w = self.wheel
        c = math.floor((lo + w.a0_pitch + w.n * bit) / (2 * w.n)) - 1
        while self._window(ep, c)[0] < lo:
            c += 1
        ep.next_c, ep.c0, ep.index_base = c, c, self._next_index
        if self._index_clock is not None:  # the first epoch after a hole: numbered by the clock (number_by_clock)
            ep.index_base = self._clocked_index(ep, c)

    def _clocked_index(self, ep: Epoch, c: int) -> int:
        """Cycle c's index from ``number_by_clock``'s reference: its window's start, placed on the tooth clock from
        the epoch's first edge at the reference's cycle length (2 N positions a cycle), rounded."""
        index_at, tick, period = self._index_clock
        self._index_clock = None
        seg = ep.segments[0]
        t_c = seg.t_first + (self._window(ep, c)[0] - seg.first_pos) * period / (2 * self.wheel.n)
        return max(self._next_index, round(index_at + (t_c - tick) / period))

    def _window(self, ep: Epoch, c: int) -> tuple[int, int]:
        h2 = 2 * c - int(ep.phase or 0)
        if h2 != self._win_h2:  # asked ~3 times per tooth batch for the same cycle: the last answer is kept
            self._win = self.wheel.window(h2)
            self._win_h2 = h2
        return self._win

    def _count_undecided(self, ep: Epoch) -> None:
        """A probe window without a verdict. From the ``UNDECIDED_WINDOWS``-th in a row on, every second one (the
        windows step one revolution, a cycle is two) is a cycle skipped as ``phase_undecided``, logged at the first:
        a channel that shows no firing TDC (dead, negated, on another clock) with no cam to decide the phase would
        otherwise leave no cycle and no reason (design note 144's gap)."""
        ep.undecided += 1
        if ep.undecided < UNDECIDED_WINDOWS:
            return
        cycles = ep.undecided // 2 if ep.undecided == UNDECIDED_WINDOWS else int(ep.undecided % 2 == 0)
        if cycles == 0:
            return
        if self.skipped["phase_undecided"] == 0:
            log.warning("no 4-stroke phase: cylinder %d's pressure shows no firing TDC and no cam edge decides it; its "
                        "cycles are skipped (phase_undecided) until it does", self.phase_cyl)
        self.skipped["phase_undecided"] += cycles
        self.lost += cycles

    def _probe_pressure(self, ep: Epoch, flushing: bool) -> None:
        """Decide the phase from the phase cylinder's pressure on rev-aligned 720 deg windows."""
        if self.phase_cyl is None:
            return
        w = self.wheel
        if ep.probe is None:
            h = math.floor((ep.segments[0].first_pos + w.a0_pitch) / w.n) - 1
            while w.window(h)[0] < ep.segments[0].first_pos:
                h += 1
            ep.probe = h
        tdc = float(self.firing[self.phase_cyl - 1])
        while ep.phase is None:
            ps, pe = w.window(ep.probe)
            status, seg = window_status(ep, ps, pe)
            if status in ("wait", "before"):
                return
            if status == "broken":
                ep.probe += 1
                continue
            pos = np.arange(ps, pe + 1)
            pos = pos[pos % w.n < w.t]
            ticks = self.buf.teeth.view("t", seg.seq_of(ps), seg.seq_of(pe) + 1)
            theta = nominal_angle(w.n, self.a0_deg, pos, 0, -ep.probe)
            ring = self.buf.pressure.get(self.phase_cyl)
            t_grid = grid_times(theta, ticks, self.grid)
            if ring is None or len(ring) == 0 or ring.last("t") < t_grid[-1]:
                if not flushing and self._now - ticks[-1] <= self.wait_ticks:
                    return
                ep.probe += 1
                self.stats["phase_probe_no_pressure"] += 1
                continue
            row, _ = pressure_on_grid(ring, t_grid)
            verdict = firing_verdict(row, self.grid, tdc)
            if verdict == 0:
                ep.probe += 1
                self._count_undecided(ep)
            else:  # +1: this window starts at firing TDC, i.e. it is a cycle: 2 c - P = probe
                self._set_phase(ep, (ep.probe + (0 if verdict > 0 else 1)) % 2, "pressure", from_pos=ps)
