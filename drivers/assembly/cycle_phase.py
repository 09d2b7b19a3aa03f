"""The 4-stroke phase of the cycle assembler: a cam edge placed on the wheel, or the pressure of one cylinder.

A crank wheel fixes 360 deg only (physics.md §14.5). Positions on the wheel (drivers/assembly/cycle_parts.py) give the angle
theta0 = pos * 2 pi / N + a0 up to the phase bit P: theta = theta0 + 2 pi P.
"""

from __future__ import annotations

import math
from collections import Counter

import numba
import numpy as np
from frictionwatch.drivers.assembly.cycle_parts import Epoch, Segment, Wheel
from frictionwatch.drivers.assembly.ringbuffer import RingBuffer

FOUR_PI = 4.0 * math.pi
TWO_PI = 2 * math.pi
PHASE_RATIO = 1.15  # firing/exchange pressure ratio that counts as a clear decision
PHASE_HALF_WIDTH = math.radians(30.0)  # physics.md §14.5: mean pressure within +-30 deg of each candidate TDC
CAM_TOLERANCE = math.radians(30.0)


def cam_phase_bit(teeth: RingBuffer, seg: Segment, sb: int, tc: int, wheel: Wheel, a0: float,
                  cam: float) -> int | None:
    """Phase bit voted by a cam edge at tick ``tc`` between verified edges sb-1 and sb of ``seg``; None when the
    edge sits more than 30 deg from where the stated cam angle ``cam`` [rad] puts it (a wrong or noisy cam)."""
    ta, tb = teeth.get("t", sb - 1), teeth.get("t", sb)
    pa = seg.pos_of(sb - 1)
    pb = pa + 1 if (pa + 1) % wheel.n < wheel.t else seg.pos_of(sb)  # (the next tooth: = seg.pos_of(sb))
    pos = pa + (tc - ta) / (tb - ta) * (pb - pa)
    theta0 = pos * wheel.pitch + a0
    bit = round(((cam - theta0) % FOUR_PI) / TWO_PI) % 2
    resid = (cam - theta0 - TWO_PI * bit + TWO_PI) % FOUR_PI - TWO_PI
    return None if abs(resid) > CAM_TOLERANCE else bit


def phase_windows(grid: np.ndarray, tdc: float, half_width: float = PHASE_HALF_WIDTH
                  ) -> tuple[np.ndarray, np.ndarray, float]:
    """Indices of the grid points within +-half_width of ``tdc`` and of ``tdc + 2 pi`` (and ``tdc``, to check a
    reuse): they depend on the grid only, so the assembler finds them once."""
    d_fire = np.abs((grid - tdc + 2 * math.pi) % FOUR_PI - 2 * math.pi)
    d_exch = np.abs((grid - tdc) % FOUR_PI - 2 * math.pi)
    return np.flatnonzero(d_fire <= half_width), np.flatnonzero(d_exch <= half_width), tdc


def firing_ratio(row: np.ndarray, grid: np.ndarray, tdc: float, half_width: float = PHASE_HALF_WIDTH,
                 windows: tuple[np.ndarray, np.ndarray, float] | None = None) -> float:
    """Mean pressure within +-half_width of ``tdc`` over the mean within +-half_width of ``tdc + 2 pi``
    (physics.md §14.5: > 1 when ``tdc`` is the firing TDC, motored or fired). Angles in rad on a 4 pi grid.
    ``windows``: ``phase_windows(grid, tdc, half_width)`` if already known (the same numbers). One compiled call
    (``window_ratio``; its numpy reference: tests/drivers/test_cycle_parts.py ``firing_ratio_reference``)."""
    if windows is None or windows[2] != tdc or half_width != PHASE_HALF_WIDTH:
        windows = phase_windows(grid, tdc, half_width)
    return window_ratio(row, windows[0], windows[1])


@numba.njit(cache=True)
def window_ratio(row, fire, exch):
    """mean(row[fire]) / mean(row[exch]) (index vectors, int64), NaN when either window is empty or the second mean
    is not > 0 (``firing_ratio``; ~1 us against ~5 for numpy's fancy indexing and reductions). Sums in index order:
    numpy's pairwise order differs in the last bits (rtol 1e-13 in the test), for a ratio that is only held against
    PHASE_RATIO; numpy's order to the bit (an explicit-stack pairwise sum) cost ~1.8 s of compile events."""
    nf = fire.shape[0]
    ne = exch.shape[0]
    if nf == 0 or ne == 0:
        return np.nan
    den = 0.0
    for i in range(ne):
        den += row[exch[i]]
    den /= ne
    if not den > 0:
        return np.nan
    num = 0.0
    for i in range(nf):
        num += row[fire[i]]
    return num / nf / den


def firing_verdict(row: np.ndarray | None, grid: np.ndarray, tdc: float,
                   windows: tuple[np.ndarray, np.ndarray, float] | None = None) -> int:
    """+1: ``tdc`` is clearly the firing TDC; -1: clearly the gas-exchange TDC; 0: undecided (or no data)."""
    if row is None:
        return 0
    ratio = firing_ratio(row, grid, tdc, windows=windows)
    if ratio > PHASE_RATIO:
        return 1
    if ratio < 1.0 / PHASE_RATIO:
        return -1
    return 0


def cycle_votes(cam_votes: list[tuple[int, int]], t_first: int, t_last: int, phase: int | None) -> int:
    """How many cam votes (tick, bit) lie in [t_first, t_last], or -1 if one of them is not ``phase``.
    ``cam_votes`` is in time order (cam rows are strictly increasing) and the cycle asking is among the newest, so a
    scan from the end meets its votes after at most a few newer ones (a bisection costs more)."""
    n = 0
    for tc, bit in reversed(cam_votes):
        if tc > t_last:
            continue
        if tc < t_first:
            break
        if bit != phase:
            return -1
        n += 1
    return n


def place_cams(ep: Epoch, cams: RingBuffer, teeth: RingBuffer, cam_next: int, wheel: Wheel, a0: float, cam: float,
               stats: Counter[str]) -> tuple[int, int | None]:
    """Place the cam edges from row ``cam_next`` on the epoch's verified edges; each placed edge adds a vote
    (tick, bit) to ``ep.cam_votes``. Stops at the first edge whose teeth are not verified yet.

    Returns the next cam row to look at and the first bit voted (None if none)."""
    first = None
    cam_next = max(cam_next, cams.start)
    while cam_next < cams.end:
        tc = int(cams.get("t", cam_next))
        if tc < ep.t_start:  # before this epoch: of no use
            cam_next += 1
            continue
        sb = teeth.searchsorted("t", tc, side="left")
        last = ep.segments[-1]
        if sb > last.good and last.reason is None:
            break  # its teeth are not verified yet
        cam_next += 1
        seg = None
        for s in reversed(ep.segments):  # (a loop: a generator costs more than the usual single segment)
            if s.first_seq < sb <= s.good:
                seg = s
                break
        if seg is None or sb - 1 < teeth.start:
            stats["cam_unplaced"] += 1  # in a hole between segments
            continue
        bit = cam_phase_bit(teeth, seg, sb, tc, wheel, a0, cam)
        if bit is None:
            stats["cam_inconsistent"] += 1
            continue
        stats["cam_votes"] += 1
        ep.cam_votes.append((tc, bit))
        first = bit if first is None else first
    return cam_next, first
