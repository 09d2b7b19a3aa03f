"""Watching TDC while the engine runs, the per-cycle step: each cylinder's pressure about its own firing TDC, cut from
two consecutive cycles, added to one of ``BLOCKS`` running block sums (``watch_cycle``); the watch's state
(``TdcWatchState``). Every ``WINDOW_CYCLES`` cycles the window is read: the thermodynamic fit on the block means,
the screens and the flags (core.monitor.calibration.tdc_window, whose doc says what is flagged and why).

The traces: ``trace_cut`` makes the take indices once per grid and firing phases; ``add_traces`` adds a pair's
traces to a block sum in one kernel (``add_traces_reference`` its numpy reference); ``local_traces`` is the plain
joining and indexing all of them are tested equal to.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numba
import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.calibration.tdc import BLOCKS, TdcEstimate
from frictionwatch.core.types import Cycle

WINDOW_CYCLES = 100
# cylinders fitted per window: the fit cost ~40 ms per cylinder and window when this was set (genset-v20: 0.8 s for
# all 20 under load, 4-8 ms per cycle over a 100-cycle window, more than the monitor itself); now ~2.6 ms of CPU per
# cylinder (k9k 4000 rpm, genset-v20 1500 rpm, full load), all 20 of genset-v20 would still be ~55 ms per window,
# ~0.55 ms per cycle, half the monitor; so a large engine's cylinders take turns, four per window (genset-v20: each
# cylinder every 500 cycles, the wheel from the first window on)
CYLINDERS_PER_WINDOW = 4


@dataclass(frozen=True)
class TraceCut:
    """Where ``local_traces`` takes each cylinder's trace from for an n-sample grid and the firing phases (z,) [rad]:
    the flat positions in the previous cycle's pressure (z*n,) and the trace positions (z*n_local,) they go to
    (``from_prev``, ``to_prev``), the same for the current cycle (``from_cur``, ``to_cur``), the local angle
    (n_local,) [rad]. Made once per grid (``trace_cut``), it replaces the joining of both cycles' whole pressure on
    every cycle (17 us per k9k cycle, 57 us per genset-v20 one, against 3 and 10 for the take)."""

    n: int
    phases: np.ndarray
    from_prev: np.ndarray
    to_prev: np.ndarray
    from_cur: np.ndarray
    to_cur: np.ndarray
    angle: np.ndarray

    def fits(self, n: int, phases: np.ndarray) -> bool:
        # np.array_equal's answer (NaN unequal, shapes compared) from the phases as lists: ~0.6 against ~5.8 us a
        # call, asked every cycle (0.6 % of a k9k cycle in py-spy; design note 37)
        return self.n == n and np.asarray(phases).tolist() == self.phases.tolist()


def trace_cut(n: int, phases: np.ndarray, half_width_rad: float = math.pi) -> TraceCut:
    """The take indices of ``local_traces`` (its cut, as indices into the two cycles apart, not their join)."""
    ph = np.array(phases, dtype=np.float64)
    step = 4.0 * math.pi / n
    half = int(round(half_width_rad / step))
    centre = np.rint(np.mod(ph, 4.0 * math.pi) / step).astype(np.int64) % n
    centre = np.where(centre + half > n, centre - n, centre)
    idx = (n + centre - half)[:, None] + np.arange(2 * half)[None, :]  # into the join (z, 2n), as local_traces
    in_cur = idx >= n
    flat = np.arange(ph.shape[0])[:, None] * n + idx - n  # flat position in the current cycle's (z, n)
    return TraceCut(n, ph, (flat + n)[~in_cur], np.flatnonzero(~in_cur), flat[in_cur], np.flatnonzero(in_cur),
                    step * np.arange(-half, half))


def cut_traces(prev: Cycle, cycle: Cycle, cut: TraceCut) -> np.ndarray:
    """``local_traces(prev, cycle, cut.phases)[0]`` by ``cut``'s take indices (tested equal to it)."""
    z = cut.phases.shape[0]
    out = np.empty(z * cut.angle.shape[0])
    out[cut.to_prev] = np.asarray(prev.pressure, dtype=np.float64).reshape(-1)[cut.from_prev]
    out[cut.to_cur] = np.asarray(cycle.pressure, dtype=np.float64).reshape(-1)[cut.from_cur]
    return out.reshape(z, -1)


def add_traces(block: np.ndarray, prev: Cycle, cycle: Cycle, cut: TraceCut) -> np.ndarray | None:
    """``block + cut_traces(prev, cycle, cut)`` (z, n_local), a new array, or None when a sample of the traces is not
    finite (the pair is then left out): the watch's per-cycle step as one kernel (``_add_traces_kernel``: one pass,
    one array, where the take, the finiteness test and the sum were three passes and two arrays; its numpy reference
    ``add_traces_reference``, tested equal)."""
    out = np.empty(block.shape)
    ok = _add_traces_kernel(np.ascontiguousarray(block, dtype=np.float64).reshape(-1),
                            np.ascontiguousarray(prev.pressure, dtype=np.float64).reshape(-1),
                            np.ascontiguousarray(cycle.pressure, dtype=np.float64).reshape(-1),
                            cut.from_prev, cut.to_prev, cut.from_cur, cut.to_cur, out.reshape(-1))
    return out if ok else None


def add_traces_reference(block: np.ndarray, prev: Cycle, cycle: Cycle, cut: TraceCut) -> np.ndarray | None:
    """``add_traces`` in plain numpy (its reference)."""
    traces = cut_traces(prev, cycle, cut)
    return block + traces if np.all(np.isfinite(traces)) else None


@numba.njit(cache=True)
def _add_traces_kernel(block, prev, cur, from_prev, to_prev, from_cur, to_cur, out):
    """out[to] = block[to] + pressure[from] for the previous and the current cycle's flat pressure (z*n,); False if a
    taken sample is not finite (out is then incomplete)."""
    for i in range(to_prev.shape[0]):
        v = prev[from_prev[i]]
        if not math.isfinite(v):
            return False
        out[to_prev[i]] = block[to_prev[i]] + v
    for i in range(to_cur.shape[0]):
        v = cur[from_cur[i]]
        if not math.isfinite(v):
            return False
        out[to_cur[i]] = block[to_cur[i]] + v
    return True


def local_traces(prev: Cycle, cycle: Cycle, phases: np.ndarray,
                 half_width_rad: float = math.pi) -> tuple[np.ndarray, np.ndarray]:
    """(traces (z, n_local), local angle (n_local,)): every cylinder's pressure about its firing TDC from two
    consecutive cycles, as core.monitor.calibration.tdc.local_cycles cuts one (its numpy reference, tested equal),
    all cylinders in one indexing instead of one concatenation each (0.75 ms per genset-v20 cycle)."""
    n = cycle.grid.shape[0]
    step = 4.0 * math.pi / n
    half = int(round(half_width_rad / step))
    centre = np.rint(np.mod(np.asarray(phases, dtype=np.float64), 4.0 * math.pi) / step).astype(np.int64) % n
    centre = np.where(centre + half > n, centre - n, centre)
    joined = np.concatenate([np.asarray(prev.pressure, dtype=np.float64), np.asarray(cycle.pressure, dtype=np.float64)],
                            axis=1)
    idx = (n + centre - half)[:, None] + np.arange(2 * half)[None, :]
    return np.take_along_axis(joined, idx, axis=1), step * np.arange(-half, half)


@dataclass(frozen=True)
class TdcWatchState:
    """sums: BLOCKS arrays (z, n_local), the current window's block sums of the local traces (a cycle replaces its
    block's array by a new one, never writes into one: no copy of all five per cycle), counts (BLOCKS,) the cycles
    in each; cycles in the window;
    previous: the last cycle's (index, pressure (z, n)) for the trace across the cycle boundary; last: the newest
    window's estimates (z,) or None; flags in force; omega_sum: the window's speeds summed [rad/s]; cut: the take
    indices of ``local_traces`` for this grid and these phases, made at the first pair (``trace_cut``)."""

    sums: tuple[np.ndarray, ...] | None
    counts: np.ndarray
    cycles: int
    previous: Cycle | None
    last: tuple[TdcEstimate | None, ...] | None
    flags: tuple[str, ...]
    omega_sum: float
    twist_sum: np.ndarray | float = 0.0
    next_cylinder: int = 0
    first_own: np.ndarray | None = None  # (2, z) each cylinder's first own offset in this run and its statistical
    # sigma [rad] (NaN: not yet read), what a commissioned cylinder's own offset is compared with for a change
    reference: np.ndarray | None = None  # (z, n_local) each cylinder's mean trace at its last fit (NaN rows: none)
    reference_twist: np.ndarray | None = None  # (z,) the window's mean twist then [rad]
    screened: tuple[int, ...] = ()  # cylinders the newest window fitted out of turn (0-based), for the record
    fitted: tuple[TdcEstimate | None, ...] | None = None  # each cylinder's newest fit (``last``: moved by the screen)
    window_trace: np.ndarray | None = None  # (z, n_local) the last window's mean traces, for ``window_shift``
    window_twist: np.ndarray | None = None  # (z,) its mean twist [rad]
    drift: np.ndarray | None = None  # (z,) each cylinder's own shift summed window by window since its last fit [rad]
    cut: TraceCut | None = None  # where each cylinder's local trace lies in two cycles' pressure (``trace_cut``)

    @staticmethod
    def empty() -> TdcWatchState:
        return TdcWatchState(None, np.zeros(BLOCKS), 0, None, None, (), 0.0, 0.0)



def watch_cycle(spec: EngineSpec, state: TdcWatchState, cycle: Cycle, twist: np.ndarray) -> TdcWatchState:
    """``state`` with ``cycle`` (the pressure as the monitor gets it) added; twist (z,) [rad] each throw's static
    twist ahead of the flywheel in the monitor's model of this cycle. A cycle that does not follow the previous one
    only starts the next pair. The caller reads the window when ``cycles`` reaches its length
    (core.monitor.calibration.tdc_window.close_window; the pipeline's TdcWatch stage): the per-cycle step and the
    window's reading are apart, so a cycle's walk enters this file alone."""
    prev = state.previous
    if prev is None or cycle.index != prev.index + 1 or prev.grid.shape != cycle.grid.shape:
        return dataclasses.replace(state, previous=cycle)
    n_grid = cycle.grid.shape[0]
    cut = state.cut if state.cut is not None and state.cut.fits(n_grid, spec.firing_angles) \
        else trace_cut(n_grid, spec.firing_angles)
    b = state.cycles % BLOCKS
    shape = (cut.phases.shape[0], cut.angle.shape[0])
    if np.shape(prev.pressure) == np.shape(cycle.pressure) == (cut.phases.shape[0], n_grid):
        sums = (np.zeros(shape),) * BLOCKS if state.sums is None or state.sums[0].shape != shape \
            else state.sums  # read only: a block is replaced, not written
        block = add_traces(sums[b], prev, cycle, cut)
        if block is None:
            return dataclasses.replace(state, previous=cycle, cut=cut)  # a NaN sample: the pair is left out
    else:  # not one row per cylinder: the reference cut (and its error)
        traces, _ = local_traces(prev, cycle, spec.firing_angles)
        if not np.all(np.isfinite(traces)):
            return dataclasses.replace(state, previous=cycle, cut=cut)
        sums = (np.zeros(traces.shape),) * BLOCKS if state.sums is None or state.sums[0].shape != traces.shape \
            else state.sums
        block = sums[b] + traces
    counts = state.counts.copy()
    sums = sums[:b] + (block,) + sums[b + 1:]
    counts[b] += 1
    return _added(state, sums, counts, state.cycles + 1, cycle, state.omega_sum + cycle.mean_omega,
                  state.twist_sum + np.asarray(twist, dtype=np.float64), cut)


def _added(s: TdcWatchState, sums: tuple[np.ndarray, ...], counts: np.ndarray, cycles: int, previous: Cycle,
           omega_sum: float, twist_sum: np.ndarray, cut: TraceCut) -> TdcWatchState:
    """``dataclasses.replace(s, sums=..., counts=..., cycles=..., previous=..., omega_sum=..., twist_sum=..., cut=...)``
    by position: every cycle makes one, and replace's field-by-field keywords cost twice a positional construction
    of these 18 fields (design note 51). The window's fields are the ones a window closes (tdc_window.close_window)."""
    return TdcWatchState(sums, counts, cycles, previous, s.last, s.flags, omega_sum, twist_sum, s.next_cylinder,
                         s.first_own, s.reference, s.reference_twist, s.screened, s.fitted, s.window_trace,
                         s.window_twist, s.drift, cut)


__all__ = ["CYLINDERS_PER_WINDOW", "TdcWatchState", "TraceCut", "WINDOW_CYCLES", "add_traces", "add_traces_reference",
           "cut_traces", "local_traces", "trace_cut", "watch_cycle"]
