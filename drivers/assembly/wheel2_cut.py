"""The second (free-end) wheel's edges cut into the flywheel's cycles (issue 29 item 1).

The flywheel wheel defines the cycles (drivers/assembly/cycles.py). The second wheel has its own teeth, its own gap
at its own angle and its own sensor; its edges are synced on their own by the same missing-tooth state machine
(``WheelTracker``), so a dropped or extra tooth ends a segment there and sync is regained at its next gaps, and are
placed on the crank angle through the flywheel: an edge at wheel position ``pos`` of a segment has the nominal angle
phi = first2 + pos 2 pi / N2 + 2 pi m, the whole revolutions m (and the 4-stroke phase with them) chosen per cycle so
that phi is nearest the flywheel's nominal angle at the edge's time (the shaft twists by far less than half a turn).

For one cycle (flywheel edges from tick ``ta`` to ``tb``), ``cut`` gives a ``WheelTeeth`` bracketing [0, 4 pi] in the
second wheel's nominal angle as ``Cycle`` brackets its own (the last edge at or before 0 through the first at or
after 4 pi), or the reason there is none: 'wait' (its edges may still come), 'second_wheel_absent' (no edges over the
cycle), 'second_wheel_sync' (the cycle is not covered by one synced run of its edges: a dropped or extra tooth, a
gap in the data), 'second_wheel_angle' (its edges do not sit where the stated wheel puts them: the stated angle is
off by more than ``ANGLE_TOL`` or the wheel description is wrong).
"""

from __future__ import annotations

import math

import numpy as np
from frictionwatch.core.types import WheelInfo, WheelTeeth
from frictionwatch.drivers.assembly.wheel_sync import EV_END, EV_SEGMENT, WheelTracker

TWO_PI = 2.0 * math.pi
ANGLE_TOL = math.radians(20.0)  # stated against measured angle of the free end: twist ~0.1 deg, mounting errors
MARGIN_PITCHES = 3  # edges looked at beyond the cycle's own span, in pitches of the second wheel


class SecondWheelCut:
    """Edge store, sync and cutting of the second wheel.

    Parameters
    ----------
    wheel : the stated second wheel (teeth incl. missing, missing >= 1, first_tooth_deg at its own shaft section)
    """

    def __init__(self, wheel: WheelInfo) -> None:
        if wheel.missing < 1:
            raise ValueError(f"second wheel {wheel.teeth}-{wheel.missing}: without a missing-tooth gap its teeth "
                             "cannot be indexed")
        self.n, self.k = int(wheel.teeth), int(wheel.missing)
        self.t_per_rev = self.n - self.k
        self.first = math.radians(wheel.first_tooth_deg)
        self.tracker = WheelTracker(self.n, self.k)
        self.ticks = np.zeros(0, np.int64)
        self.base = 0  # sequence number of ticks[0]
        self.segments: list[list[int]] = []  # [first_seq, first_pos, last_good_seq (-1 while running)]
        self.rejected = 0  # edges not later than the last one (dropped)

    # ---- input --------------------------------------------------------------------------------------------------
    def add(self, ticks: np.ndarray) -> None:
        t = np.asarray(ticks, dtype=np.int64).ravel()
        if t.size == 0:
            return
        last = int(self.ticks[-1]) if self.ticks.size else None
        keep = np.ones(t.size, bool)
        keep[1:] = np.diff(t) > 0
        if last is not None:
            keep[0] = t[0] > last
        if not keep.all():
            top = np.maximum.accumulate(np.concatenate([[last if last is not None else -1], t]))[:-1]
            keep = t > top
            self.rejected += int(t.size - keep.sum())
            t = t[keep]
        if t.size == 0:
            return
        self.ticks = np.concatenate([self.ticks, t])
        need = self.tracker.oldest_needed()
        for ev, a, b, _ in self.tracker.advance(self.ticks[need - self.base:], need):
            if ev == EV_SEGMENT:
                self.segments.append([a, b, -1])
            elif ev == EV_END and self.segments and self.segments[-1][2] < 0:
                self.segments[-1][2] = a

    @property
    def newest(self) -> int | None:
        return int(self.ticks[-1]) if self.ticks.size else None

    def discard_before(self, tick: int) -> None:
        """Forget edges (and ended segments) before ``tick`` that the tracker no longer needs."""
        if self.ticks.size == 0:
            return
        cut = min(int(np.searchsorted(self.ticks, tick)) + self.base, self.tracker.oldest_needed())
        if cut - self.base > 4 * self.t_per_rev:  # in pieces: the copy stays small against what it keeps
            self.ticks = self.ticks[cut - self.base:]
            self.base = cut
            self.segments = [s for s in self.segments if s[2] < 0 or s[2] >= cut]

    # ---- cutting ------------------------------------------------------------------------------------------------
    def cut(self, tooth_ticks: np.ndarray, tooth_angle: np.ndarray, final: bool) -> WheelTeeth | str:
        """The second wheel's edges of the cycle whose flywheel edges are ``tooth_ticks`` at the nominal angles
        ``tooth_angle`` [rad]; or a reason (module docstring). ``final``: no more edges will come."""
        ta, tb = int(tooth_ticks[0]), int(tooth_ticks[-1])
        pitch = (tb - ta) / (tooth_angle[-1] - tooth_angle[0]) * TWO_PI / self.n  # ticks per pitch of this wheel
        lo, hi = ta - MARGIN_PITCHES * pitch, tb + MARGIN_PITCHES * pitch
        newest = self.newest
        if not final and (newest is None or newest < hi):
            return "wait"  # the caller gives up waiting (and asks with final=True) once the stream is far past tb
        i0 = int(np.searchsorted(self.ticks, lo)) + self.base
        i1 = int(np.searchsorted(self.ticks, hi, side="right")) + self.base
        if i1 - i0 < 2:
            return "second_wheel_absent"
        running_end = (self.tracker.good_through if self.tracker.synced else -1) if not final else \
            self.base + self.ticks.size - 1  # at the end every edge that arrived counts (none comes to verify it)
        seg = next((s for s in self.segments if s[0] <= i0 and (s[2] if s[2] >= 0 else running_end) >= i1 - 1),
                   None)
        if seg is None:
            running = bool(self.segments) and self.segments[-1][2] < 0 and self.segments[-1][0] <= i0
            return "wait" if running and not final else "second_wheel_sync"
        seqs = np.arange(i0, i1)
        ordinal = (seg[1] // self.n) * self.t_per_rev + seg[1] % self.n + (seqs - seg[0])
        pos = (ordinal // self.t_per_rev) * self.n + ordinal % self.t_per_rev
        ticks = self.ticks[i0 - self.base:i1 - self.base]
        phi = self.first + pos * (TWO_PI / self.n)
        theta_f = np.interp(ticks.astype(np.float64), tooth_ticks.astype(np.float64), tooth_angle)  # ends: held
        inside = (ticks >= ta) & (ticks <= tb)
        turns = np.round((theta_f[inside] - phi[inside]) / TWO_PI)
        if turns.size == 0:
            return "second_wheel_absent"
        m = float(np.median(turns))
        phi = phi + TWO_PI * m
        if np.max(np.abs(theta_f[inside] - phi[inside])) > ANGLE_TOL:
            return "second_wheel_angle"
        a = np.flatnonzero(phi <= 0.0)
        b = np.flatnonzero(phi >= 2 * TWO_PI)
        if a.size == 0 or b.size == 0:  # the margin holds both ends: an end missing is a gap in the edges
            return "second_wheel_sync"
        s, e = int(a[-1]), int(b[0]) + 1
        return WheelTeeth(ticks=ticks[s:e].copy(), angle=phi[s:e], index=(pos[s:e] % self.n).astype(np.int64),
                          teeth=self.n)

