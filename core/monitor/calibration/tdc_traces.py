"""Each cylinder's pressure about its own firing TDC, cut from two consecutive cycles: what the TDC watch
(core.monitor.calibration.tdc_watch) sums every cycle and fits every window. ``trace_cut`` makes the take indices once
per grid and firing phases; ``add_traces`` adds a pair's traces to a block sum in one kernel (``add_traces_reference``
its numpy reference); ``local_traces`` is the plain joining and indexing all of them are tested equal to.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from frictionwatch.core.types import Cycle


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
