"""Missing-tooth sync of a crank wheel on a stream of edge ticks (physics.md §14.2), as a numba state machine.

The wheel has ``N`` tooth positions of which ``k`` are missing, so ``T = N - k`` edges per revolution; tooth 0 is the
first edge after the gap. Positions are counted in pitches: edge ``pos`` sits at wheel index ``pos mod N`` (< T).

Search. The ratio r_i = dt_i / median(dt_{i-2}, dt_{i-1}, dt_{i+1}, dt_{i+2}) is about k+1 at the gap. A gap
candidate needs r_i > k + 1/2: between a single dropped tooth (r = 2) and the gap (r = k+1; 3.3-3.6 seen on the
TU/e 60-2 wheel, whose tooth after the gap is late). For k = 1 this is physics.md's (k+2)/2 = 1.5.

Confirmation. A candidate opens a *tentative* segment (anchor = tooth 0, pos 0). It is confirmed only when the
next gap arrives exactly where expected, i.e. exactly T - 1 normal intervals and then one gap interval, every one
passing the interval test below. Otherwise the candidate is dropped (counted) and the search goes on after it.
On confirmation the segment is extended backwards over the edges seen before the candidate (same tests), so sync
regained just after a disturbance still covers the cycle that follows it.

Interval test (tentative and synced). With ``ref`` the median of the last three per-pitch intervals and ``m`` the
expected pitches of the interval (k+1 into tooth 0, else 1), the interval q = dt/ref must satisfy |q - m| <= tol1
(0.7), and the pair with the previous interval |q_prev + q - (m_prev + m)| <= tol2 (0.3). The loose single test
lets a distorted edge (late tooth after the gap) pass; the tight pair test does not care where the edge between two
intervals sits but catches any extra edge (the pair sums to 1 instead of 2 pitches) and any missing edge (+1). An
edge counts as good once the interval after it has passed too (one edge of look-ahead).

A failed interval i (edges i -> i+1) ends a synced segment: its last good edge is i - 1, edges i and i+1 are
suspect, the search restarts at edge i + 2. The failure is classified:
``spurious_tooth`` (too short), ``missing_tooth`` (one pitch too long), ``sync_lost`` (a gap where none was expected
or none where one was: the count of teeth between gaps is wrong), ``data_gap`` (8 or more pitches of silence).

Events (rows of ``ev``): ``(EV_SEGMENT, first_seq, first_pos, anchor_seq)`` a confirmed segment,
``(EV_END, last_good_seq, reason, failed_interval_seq)`` a synced segment ended,
``(EV_REJECT, candidate_seq, reason, failed_interval_seq)`` a tentative segment failed.
Positions are relative to the segment's anchor (tooth 0 = pos 0); the caller maps them onto its own count.
"""

from __future__ import annotations

import numba
import numpy as np

EV_SEGMENT, EV_END, EV_REJECT = 1, 2, 3
OK, SPURIOUS, MISSING, SYNC_LOST, DATA_GAP = 0, 1, 2, 3, 4
REASONS = {SPURIOUS: "spurious_tooth", MISSING: "missing_tooth", SYNC_LOST: "sync_lost", DATA_GAP: "data_gap"}

MODE_SEARCH, MODE_TENTATIVE, MODE_SYNCED = 0, 1, 2
# integer state
I_MODE, I_CUR, I_FROM, I_SCAN, I_POS, I_ANCHOR, I_GOOD, I_HAVE_PREV, I_PREV_M = range(9)
N_ISTATE = 9
# float state: three per-pitch history values, previous interval
F_H0, F_H1, F_H2, F_PREV_DT, F_REF0 = range(5)
N_FSTATE = 5
# parameters
P_N, P_K, P_TOL1, P_TOL2, P_GAP_RATIO, P_DATA_GAP = range(6)
_NO_EVENTS: tuple = ()  # advance's answer for a batch without events (shared: nothing to allocate)


@numba.njit(cache=True)
def _median3(a, b, c):
    if a > b:
        a, b = b, a
    return max(a, min(b, c))


@numba.njit(cache=True)
def _classify(q, m, prm):
    """Reason code of an interval of q pitches where m were expected (single test failed)."""
    k = prm[P_K]
    tol = prm[P_TOL1]
    if q > m + prm[P_DATA_GAP]:
        return DATA_GAP
    if q < m:
        if m > 1.5 and abs(q - 1.0) <= tol:
            return SYNC_LOST  # no gap where one was expected
        return SPURIOUS
    if m < 1.5 and abs(q - (k + 1.0)) <= tol:
        return SYNC_LOST  # a gap where a tooth was expected
    return MISSING


@numba.njit(cache=True)
def _interval_code(dt, m, prev_dt, prev_m, have_prev, ref, prm):
    q = dt / ref
    if abs(q - m) > prm[P_TOL1]:
        return _classify(q, m, prm)
    if have_prev and abs((prev_dt + dt) / ref - (prev_m + m)) > prm[P_TOL2]:
        return SPURIOUS if (prev_dt + dt) / ref < prev_m + m else MISSING
    return OK


@numba.njit(cache=True)
def _expected_pitches(pos, n, t):
    """Pitches of the interval that starts at an edge at ``pos`` (into tooth 0 across the gap: k+1)."""
    j = pos % n
    if j < 0:
        j += n
    return n - t + 1 if j == t - 1 else 1


@numba.njit(cache=True)
def _back_extend(ticks, base, prm, ist, ref0):
    """Extend a just-confirmed segment backwards from its anchor; returns (first_seq, first_pos)."""
    n = np.int64(prm[P_N])
    t = n - np.int64(prm[P_K])
    anchor = ist[I_ANCHOR]
    h0 = ref0
    h1 = ref0
    h2 = ref0
    # the interval after the anchor is the later partner of the first pair test
    nxt_dt = float(ticks[anchor + 1 - base] - ticks[anchor - base])
    nxt_m = np.int64(1)  # not a literal: _interval_code compiles once, for the types _track passes
    pos_e1 = np.int64(0)  # pos of edge j+1 (first the anchor)
    pos_e2 = np.int64(1)  # pos of edge j+2
    first = anchor
    first_pos = np.int64(0)
    j = anchor - 1
    while j >= ist[I_FROM]:
        # interval j runs from edge j to edge j+1; k+1 pitches if edge j+1 is tooth 0
        jj = pos_e1 % n
        if jj < 0:
            jj += n
        m = n - t + 1 if jj == 0 else 1
        dt = float(ticks[j + 1 - base] - ticks[j - base])
        ref = _median3(h0, h1, h2)
        if _interval_code(dt, m, nxt_dt, nxt_m, np.bool_(True), ref, prm) != OK:
            first = j + 2  # edges j and j+1 are suspect
            first_pos = pos_e2
            break
        pos_e2 = pos_e1
        pos_e1 = pos_e1 - m
        first = j
        first_pos = pos_e1
        h0, h1, h2 = h1, h2, dt / m
        nxt_dt = dt
        nxt_m = m
        j -= 1
    return first, first_pos


@numba.njit(cache=True)
def _track(ticks, base, prm, ist, fst, ev):
    """Advance the sync state machine over the edges ``ticks`` (element 0 has sequence number ``base``).

    Writes events into ``ev`` (rows [type, a, b, c]) and returns how many; stops early when ``ev`` is full."""
    n_edges = base + ticks.shape[0]
    n = np.int64(prm[P_N])
    k = np.int64(prm[P_K])
    t = n - k
    ne = 0
    cap = ev.shape[0]
    while ne < cap:
        mode = ist[I_MODE]
        if mode == MODE_SEARCH:
            i = ist[I_SCAN]
            if i + 3 >= n_edges:
                break
            ist[I_FROM] = max(ist[I_FROM], i - 3 * n)  # back-extension never reaches beyond three revolutions
            li = i - base
            dt = float(ticks[li + 1] - ticks[li])
            nb = np.empty(4)
            c = 0
            for d in (-2, -1, 1, 2):
                if i + d >= ist[I_FROM]:
                    nb[c] = float(ticks[li + d + 1] - ticks[li + d])
                    c += 1
            if c < 2:
                ist[I_SCAN] = i + 1
                continue
            nbs = np.sort(nb[:c])
            med = 0.5 * (nbs[(c - 1) // 2] + nbs[c // 2])
            r = dt / med
            if prm[P_GAP_RATIO] < r < k + 2.5:
                ist[I_MODE] = MODE_TENTATIVE
                ist[I_ANCHOR] = i + 1
                ist[I_CUR] = i + 1
                ist[I_POS] = 0
                ist[I_HAVE_PREV] = 1
                ist[I_PREV_M] = k + 1
                fst[F_PREV_DT] = dt
                fst[F_H0] = med
                fst[F_H1] = med
                fst[F_H2] = med
                fst[F_REF0] = med
            else:
                ist[I_SCAN] = i + 1
            continue
        # tentative or synced: test interval CUR -> CUR+1
        i = ist[I_CUR]
        if i + 1 >= n_edges:
            break
        li = i - base
        dt = float(ticks[li + 1] - ticks[li])
        pos = ist[I_POS]
        m = _expected_pitches(pos, n, t)
        ref = _median3(fst[F_H0], fst[F_H1], fst[F_H2])
        code = _interval_code(dt, m, fst[F_PREV_DT], ist[I_PREV_M], ist[I_HAVE_PREV] == 1, ref, prm)
        if code == OK:
            fst[F_H0] = fst[F_H1]
            fst[F_H1] = fst[F_H2]
            fst[F_H2] = dt / m
            fst[F_PREV_DT] = dt
            ist[I_PREV_M] = m
            ist[I_HAVE_PREV] = 1
            ist[I_POS] = pos + m
            ist[I_CUR] = i + 1
            if mode == MODE_SYNCED:
                ist[I_GOOD] = i
            elif m > 1:  # tentative segment reached its second gap exactly on time: confirmed
                first, first_pos = _back_extend(ticks, base, prm, ist, fst[F_REF0])
                ist[I_MODE] = MODE_SYNCED
                ist[I_GOOD] = i
                ev[ne, 0] = EV_SEGMENT
                ev[ne, 1] = first
                ev[ne, 2] = first_pos
                ev[ne, 3] = ist[I_ANCHOR]
                ne += 1
            continue
        if mode == MODE_SYNCED:
            ev[ne, 0] = EV_END
            ev[ne, 1] = i - 1
            ev[ne, 2] = code
            ev[ne, 3] = i
            ne += 1
            ist[I_FROM] = i + 2
            ist[I_SCAN] = i + 2
        else:
            ev[ne, 0] = EV_REJECT
            ev[ne, 1] = ist[I_ANCHOR] - 1
            ev[ne, 2] = code
            ev[ne, 3] = i
            ne += 1
            ist[I_SCAN] = ist[I_ANCHOR]  # go on searching just after the false candidate
        ist[I_MODE] = MODE_SEARCH
        ist[I_HAVE_PREV] = 0
    return ne


class WheelTracker:
    """Typed front of the sync kernel: keeps its state arrays and the oldest edge it may still need.

    Parameters
    ----------
    wheel_teeth, wheel_missing : N tooth positions including k missing ones (k >= 1: the gap is the index)
    tol_single, tol_pair : interval tolerances in pitches (module docstring)
    """

    def __init__(self, wheel_teeth: int, wheel_missing: int, tol_single: float = 0.75, tol_pair: float = 0.65):
        n, k = int(wheel_teeth), int(wheel_missing)
        if k < 1:
            raise ValueError(f"a wheel without missing teeth (k = {k}) has no index gap to sync on")
        if n - k < 4 or k >= n // 2:
            raise ValueError(f"wheel {n}-{k}: need at least 4 teeth and fewer than half missing")
        if not 0 < tol_pair < tol_single < 1.0:
            raise ValueError("need 0 < tol_pair < tol_single < 1 (pitches)")
        self.n, self.k = n, k
        self.prm = np.array([n, k, tol_single, tol_pair, k + 0.5, 8.0], dtype=np.float64)
        self.ist = np.zeros(N_ISTATE, dtype=np.int64)
        self.fst = np.zeros(N_FSTATE, dtype=np.float64)
        self._ev = np.zeros((64, 4), dtype=np.int64)
        self._need: int | None = None  # oldest_needed() and good_if_synced() of the current state (None: not read)
        self._good = -1

    @property
    def synced(self) -> bool:
        return int(self.ist[I_MODE]) == MODE_SYNCED

    @property
    def good_through(self) -> int:
        """Last edge of the current synced segment that passed every test (meaningful while ``synced``)."""
        return int(self.ist[I_GOOD])

    def oldest_needed(self) -> int:
        """Earliest edge sequence number the tracker may still read."""
        if self._need is None:
            self._read_state()
        return self._need

    def _read_state(self) -> None:
        """Derive oldest_needed and good_if_synced from the state arrays (kept until the state changes: they are
        asked ~3 times per tooth batch, the state changes once)."""
        ist = self.ist.tolist()  # Python ints: one conversion instead of a numpy scalar per read
        mode = ist[I_MODE]
        if mode == MODE_SEARCH:  # the scan reads edge I_SCAN on and its neighbours back to I_FROM, never before
            self._need = min(ist[I_FROM], ist[I_SCAN])
        elif mode == MODE_TENTATIVE:
            self._need = min(ist[I_FROM], ist[I_ANCHOR] - 3)
        else:
            self._need = max(ist[I_CUR] - 1, 0)
        self._good = ist[I_GOOD] if mode == MODE_SYNCED else -1

    def reset(self, from_seq: int) -> None:
        """Forget everything and search again from edge ``from_seq``."""
        self.ist[:] = 0
        self.fst[:] = 0.0
        self.ist[I_FROM] = from_seq
        self.ist[I_SCAN] = from_seq
        self._need = None

    def good_if_synced(self) -> int:
        """``good_through`` while ``synced``, else -1 (one call for the two reads after every batch)."""
        if self._need is None:
            self._read_state()
        return self._good

    def advance(self, ticks: np.ndarray, base: int) -> list[tuple[int, int, int, int]]:
        """Run over the edges ``ticks`` (``ticks[0]`` has sequence number ``base`` <= ``oldest_needed()``)."""
        if base > self.oldest_needed():
            raise ValueError(f"edges from {self.oldest_needed()} are needed; the view starts at {base}")
        return list(self.advance_from(ticks, base))

    def advance_from(self, ticks: np.ndarray, base: int) -> list[tuple[int, int, int, int]]:
        """``advance`` for a caller that has just checked ``base <= oldest_needed()`` itself."""
        tk = ticks
        if not (type(tk) is np.ndarray and tk.dtype == np.int64 and tk.flags.c_contiguous):
            tk = np.ascontiguousarray(ticks, dtype=np.int64)
        self._need = None  # the state changes
        ne = _track(tk, int(base), self.prm, self.ist, self.fst, self._ev)
        if ne == 0:  # most batches bring no event
            return _NO_EVENTS
        out: list[tuple[int, int, int, int]] = []
        while True:
            out.extend(tuple(row) for row in self._ev[:ne].tolist())
            if ne < self._ev.shape[0]:
                return out
            ne = _track(tk, int(base), self.prm, self.ist, self.fst, self._ev)
            if ne == 0:
                return out
