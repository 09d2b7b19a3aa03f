"""Bounded, preallocated ring buffers for one engine's streams (design.md §1: ring buffer before cycle assembly).

``RingBuffer`` holds rows of one or more parallel numpy columns under one absolute sequence number: row ``s`` (0, 1,
2, ... since the buffer was made) stays addressable by ``s`` for as long as it is retained, whatever the wrap.

Storage is *mirrored*: every row is written twice, at ``s % cap`` and ``s % cap + cap``, so any run of at most
``cap`` retained rows is one contiguous slice of the storage. ``view(a, b)`` is therefore zero-copy and can go
straight into ``np.searchsorted`` or a numba kernel; it stays valid until the next ``extend``. Appending a batch is
two slice copies per column (O(batch), no reallocation, no concatenation of the history).

Overflow drops the oldest rows. Rows that were never released by ``discard_before`` count in ``dropped`` (data the
consumer lost); released rows are simply overwritten.

``EngineBuffers`` bundles the rings of one engine: tooth ticks, cam ticks, pressure (time, value) per cylinder and
load (ticks, torque, power), and files each stream record into the right one.
"""

from __future__ import annotations

import math
from collections import Counter

import numba
import numpy as np

from core.types import CamBatch, LoadSample, PressureBlock, StreamRecord, ToothBatch

_F64 = np.dtype(np.float64)


class RingBuffer:
    """Bounded FIFO of rows with absolute sequence numbers; ``columns`` are parallel arrays sharing one index.

    Parameters
    ----------
    capacity : maximum number of retained rows (> 0)
    columns : ``{name: dtype}`` of the parallel columns, e.g. ``{"t": np.float64, "p": np.float64}``
    """

    def __init__(self, capacity: int, columns: dict[str, type | np.dtype]):
        if int(capacity) < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        if not columns:
            raise ValueError("a ring buffer needs at least one column")
        self.capacity = int(capacity)
        self.names = tuple(columns)
        self._cols = {n: np.zeros(2 * self.capacity, dtype=d) for n, d in columns.items()}
        self.start = 0  # sequence number of the oldest retained row
        self.end = 0  # sequence number the next row will get
        self.dropped = 0  # unreleased rows lost to overflow

    def __len__(self) -> int:
        return self.end - self.start

    def extend(self, *values: np.ndarray) -> None:
        """Append a batch: one array per column (in ``names`` order), all of the same length."""
        if len(values) != len(self.names):
            raise ValueError(f"expected {len(self.names)} arrays ({', '.join(self.names)}), got {len(values)}")
        n = len(values[0])
        for v in values:
            if len(v) != n:
                raise ValueError("all columns of a batch must have the same length")
        if n == 0:
            return
        i, skip = self._advance(n)
        m = n - skip
        cap = self.capacity
        first = min(cap - i, m)
        for name, v in zip(self.names, values):
            col = self._cols[name]
            src = v[skip:] if skip else v
            col[i : i + first] = src[:first]
            col[i + cap : i + cap + first] = src[:first]
            if first < m:
                col[0 : m - first] = src[first:]
                col[cap : cap + m - first] = src[first:]

    def _advance(self, n: int) -> tuple[int, int]:
        """Account for n appended rows; returns the storage slot of the first row written and how many leading
        rows of the batch are skipped (a batch longer than the ring keeps its newest rows only)."""
        cap = self.capacity
        skip = n - cap if n > cap else 0
        end = self.end
        new_end = end + n
        new_start = max(self.start, new_end - cap)
        self.dropped += max(0, min(new_start, end) - self.start) + skip
        self.start = new_start
        self.end = new_end
        return (end + skip) % cap, skip

    def view(self, name: str, a: int | None = None, b: int | None = None) -> np.ndarray:
        """Zero-copy contiguous view of column ``name`` for rows ``[a, b)`` (default: all retained rows).

        Valid until the next ``extend``; copy it if it must live longer."""
        a = self.start if a is None else int(a)
        b = self.end if b is None else int(b)
        if not self.start <= a <= b <= self.end:
            raise IndexError(f"rows [{a}, {b}) are not all retained (retained [{self.start}, {self.end}))")
        i = a % self.capacity
        return self._cols[name][i : i + (b - a)]

    def get(self, name: str, seq: int) -> float | int:
        if not self.start <= seq < self.end:
            raise IndexError(f"row {seq} is not retained (retained [{self.start}, {self.end}))")
        return self._cols[name][seq % self.capacity].item()

    def last(self, name: str) -> float | int | None:
        return None if self.end == self.start else self.get(name, self.end - 1)

    def searchsorted(self, name: str, value: float, side: str = "left") -> int:
        """Absolute sequence number where ``value`` would go in column ``name`` (which must be sorted)."""
        if side != "left" and side != "right":
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        # one compiled call on the mirrored storage (no view, no numpy dispatch: it runs for every ring at each
        # discard and twice per cylinder and cycle)
        return self.start + _search_sorted(self._cols[name], self.start % self.capacity, self.end - self.start,
                                           value, side == "right")

    def discard_before(self, seq: int) -> None:
        """Release rows older than ``seq`` (consumed; they no longer count as dropped when overwritten)."""
        self.start = min(max(self.start, int(seq)), self.end)

    def clear(self) -> None:
        self.start = self.end


@numba.njit(cache=True)
def _less(a, b):
    """np.searchsorted's order: NaN after every number."""
    return a < b or (b != b and a == a)


@numba.njit(cache=True)
def _search_sorted(col, i0, n, key, right):
    """np.searchsorted(col[i0:i0 + n], key, side='right' if right else 'left') with numpy's binary-search loop, so
    the same index even on unsorted input; mixed int/float compare as float64, as numpy's common type."""
    lo = 0
    hi = n
    while lo < hi:
        mid = lo + ((hi - lo) >> 1)
        v = col[i0 + mid]
        go_right = (not _less(key, v)) if right else _less(v, key)
        if go_right:
            lo = mid + 1
        else:
            hi = mid
    return lo


@numba.njit(cache=True)
def _write_block(col_t, col_p, i, t0, period, values):
    """Write samples t0 + k period, values[k] from slot i of two mirrored columns (wrapping at their half)."""
    cap = col_t.shape[0] // 2
    for k in range(values.shape[0]):
        j = (i + k) % cap
        t = t0 + k * period
        col_t[j] = t
        col_t[j + cap] = t
        col_p[j] = values[k]
        col_p[j + cap] = values[k]


class EngineBuffers:
    """The rings of one engine. Pressure rings are made on first sight of a cylinder.

    Pressure sample times are kept as float64 timer ticks (exact to < 1e-3 tick for 28 years at 10 MHz), so a
    block with a non-integer period keeps its exact sample times. Load rows are (ticks, torque [N m], power [W]).
    """

    def __init__(self, tooth_capacity: int = 1 << 14, cam_capacity: int = 256, pressure_capacity: int = 1 << 15,
                 load_capacity: int = 4096):
        self.teeth = RingBuffer(tooth_capacity, {"t": np.int64})
        self.cam = RingBuffer(cam_capacity, {"t": np.int64})
        self.load = RingBuffer(load_capacity, {"t": np.int64, "torque": np.float64, "power": np.float64})
        self.pressure: dict[int, RingBuffer] = {}
        self._pressure_capacity = int(pressure_capacity)
        self.rejected: Counter[str] = Counter()  # input rows refused (out of order), by stream

    def add(self, record: StreamRecord) -> int:
        """File one record; returns the number of rows accepted. Rows out of time order are refused and counted."""
        if isinstance(record, ToothBatch):
            return self._add_ticks(self.teeth, record.ticks, "teeth")
        if isinstance(record, CamBatch):
            return self._add_ticks(self.cam, record.ticks, "cam")
        if isinstance(record, PressureBlock):
            return self.add_pressure(record)
        if isinstance(record, LoadSample):
            last = self.load.last("t")
            if last is not None and record.ticks <= last:
                self.rejected["load"] += 1
                return 0
            self.load.extend(np.array([record.ticks], dtype=np.int64), np.array([record.torque], dtype=np.float64),
                             np.array([record.power], dtype=np.float64))
            return 1
        raise TypeError(f"not a stream record: {type(record).__name__}")

    def _add_ticks(self, ring: RingBuffer, ticks: np.ndarray, stream: str) -> int:
        t = np.asarray(ticks, dtype=np.int64).ravel()
        if t.size == 0:
            return 0
        last = ring.last("t")
        ok = np.ones(t.size, dtype=bool)
        ok[1:] = t[1:] > t[:-1]
        if last is not None:
            ok[0] = t[0] > last
        if not ok.all():  # rare: keep a strictly increasing subsequence, drop edges not later than the last kept
            keep = np.zeros(t.size, dtype=bool)
            top = np.iinfo(np.int64).min if last is None else last
            for i, x in enumerate(t.tolist()):
                if x > top:
                    keep[i] = True
                    top = x
            self.rejected[stream] += int(t.size - keep.sum())
            t = t[keep]
        ring.extend(t)
        return int(t.size)

    def add_pressure(self, block: PressureBlock) -> int:
        """File one pressure block (the hot path: tens of blocks per cycle on a big engine)."""
        v = block.values
        if not (type(v) is np.ndarray and v.dtype is _F64 and v.ndim == 1):  # (identity checks: the hot path)
            v = np.asarray(v, dtype=np.float64).ravel()
        if v.shape[0] == 0:
            return 0
        period = block.period_ticks
        if not (period > 0 and math.isfinite(period)):
            self.rejected["pressure"] += v.size
            return 0
        ring = self.pressure.get(block.cylinder)
        if ring is None:
            ring = self.pressure[block.cylinder] = RingBuffer(self._pressure_capacity, {"t": np.float64,
                                                                                       "p": np.float64})
        t0 = float(block.t0_ticks)
        if ring.end > ring.start:
            last = float(ring._cols["t"][(ring.end - 1) % ring.capacity])  # = ring.get("t", ring.end - 1)
            if t0 <= last:  # an overlapping (repeated) block: keep its new tail only
                first = int((last - t0) // period) + 1
                while first > 0 and t0 + (first - 1) * period > last:
                    first -= 1
                self.rejected["pressure"] += min(first, v.size)
                if first >= v.size:
                    return 0
                t0, v = t0 + first * period, v[first:]
        i, skip = ring._advance(v.size)
        _write_block(ring._cols["t"], ring._cols["p"], i, t0 + skip * period, float(period), v[skip:])
        return int(v.size)

    def dropped(self) -> Counter[str]:
        """Unconsumed rows lost to overflow, per ring."""
        out: Counter[str] = Counter()
        for name, ring in (("teeth", self.teeth), ("cam", self.cam), ("load", self.load)):
            if ring.dropped:
                out[name] = ring.dropped
        for cyl, ring in self.pressure.items():
            if ring.dropped:
                out[f"pressure_{cyl}"] = ring.dropped
        return out
