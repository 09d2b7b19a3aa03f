"""Bounded, preallocated ring buffers for one engine's streams (design.md §1: ring buffer before cycle assembly).

``RingBuffer`` holds rows of one or more parallel numpy columns under one absolute sequence number: row ``s`` (0, 1,
2, ... since the buffer was made) stays addressable by ``s`` for as long as it is retained, whatever the wrap.

Storage is *mirrored*: every row is written twice, at ``s % cap`` and ``s % cap + cap``, so any run of at most
``cap`` retained rows is one contiguous slice of the storage. ``view(a, b)`` is therefore zero-copy and can go
straight into ``np.searchsorted`` or a numba kernel; it stays valid until the next ``extend``. Appending a batch is
two slice copies per column (O(batch), no reallocation, no concatenation of the history).

Overflow drops the oldest rows. Rows that were never released by ``discard_before`` count in ``dropped`` (data the
consumer lost); released rows are simply overwritten.

``EngineBuffers`` (drivers/assembly/engine_buffers.py) bundles the rings of one engine.
"""

from __future__ import annotations

import numba
import numpy as np


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
        # the mirrored storage (2 capacity,) of each column: row s at s % capacity and s % capacity + capacity
        self.cols = {n: np.zeros(2 * self.capacity, dtype=d) for n, d in columns.items()}
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
        i, skip = self.reserve(n)
        m = n - skip
        cap = self.capacity
        first = min(cap - i, m)
        for name, v in zip(self.names, values):
            col = self.cols[name]
            src = v[skip:] if skip else v
            col[i : i + first] = src[:first]
            col[i + cap : i + cap + first] = src[:first]
            if first < m:
                col[0 : m - first] = src[first:]
                col[cap : cap + m - first] = src[first:]

    def append(self, *values: float | int) -> None:
        """Append one row: one scalar per column (in ``names`` order); ``extend`` for a single row without building
        arrays (the load stream: a reading at a time)."""
        if len(values) != len(self.names):
            raise ValueError(f"expected {len(self.names)} values ({', '.join(self.names)}), got {len(values)}")
        cap = self.capacity
        end = self.end
        if end - self.start < cap:  # room for it: what reserve(1) does then, without the call
            self.end = end + 1
            i = end % cap
        else:
            i, _ = self.reserve(1)
        cols = self.cols
        for name, v in zip(self.names, values):
            col = cols[name]
            col[i] = col[i + cap] = v

    def extend_increasing(self, t: np.ndarray) -> bool:
        """Append the batch ``t`` (int64, 1-D) to a one-column int64 ring if its values are strictly increasing and
        all after the last row (the usual tooth / cam batch): one compiled check-and-write. Returns False, with
        nothing written, otherwise (the caller then sorts the batch out). Rows and counts as ``extend(t)``."""
        if len(self.names) != 1:
            raise ValueError("extend_increasing is for a ring of one column")
        n = t.shape[0]
        if n == 0:
            return True
        cap = self.capacity
        skip = n - cap if n > cap else 0
        col = self.cols[self.names[0]]
        start, end = self.start, self.end
        if not _write_increasing(col, start, end, (end + skip) % cap, t, skip):
            return False
        if end + n - start <= cap:  # room for the batch: what reserve(n) does then
            self.end = end + n
        else:
            self.reserve(n)
        return True

    def reserve(self, n: int) -> tuple[int, int]:
        """Account for n rows about to be appended (start, end, dropped); returns the storage slot of the first row
        to write and how many leading rows of the batch to skip (a batch longer than the ring keeps its newest rows
        only). The caller writes them into ``cols`` (both mirror halves): ``extend`` and the writers of
        ``EngineBuffers`` (``write_block``, ``write_frame``); ``PressureGroup`` and ``FrameGroup`` share it."""
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
        return self.cols[name][i : i + (b - a)]

    def get(self, name: str, seq: int) -> float | int:
        if not self.start <= seq < self.end:
            raise IndexError(f"row {seq} is not retained (retained [{self.start}, {self.end}))")
        return self.cols[name].item(seq % self.capacity)  # a Python scalar, no numpy scalar in between

    def last(self, name: str) -> float | int | None:
        return None if self.end == self.start else self.get(name, self.end - 1)

    def searchsorted(self, name: str, value: float, side: str = "left") -> int:
        """Absolute sequence number where ``value`` would go in column ``name`` (which must be sorted)."""
        if side != "left" and side != "right":
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        # one compiled call on the mirrored storage (no view, no numpy dispatch: it runs for every ring at each
        # discard and twice per cylinder and cycle)
        return self.start + search_sorted(self.cols[name], self.start % self.capacity, self.end - self.start,
                                           value, side == "right")

    def discard_before(self, seq: int) -> None:
        """Release rows older than ``seq`` (consumed; they no longer count as dropped when overwritten)."""
        self.start = min(max(self.start, int(seq)), self.end)

    def discard_older(self, name: str, value: float, keep: int = 0, upto: int | None = None) -> None:
        """``discard_before(searchsorted(name, value) - keep)`` (at most up to row ``upto``; column ``name`` sorted,
        as for ``searchsorted``): one call for the release after every tooth batch."""
        start = self.start
        if start == self.end:
            return
        seq = start + search_sorted(self.cols[name], start % self.capacity, self.end - start, value, False) - keep
        if upto is not None and upto < seq:
            seq = upto
        if seq > start:
            self.start = seq if seq < self.end else self.end

    def clear(self) -> None:
        self.start = self.end


@numba.njit(cache=True)
def sorts_before(a, b):
    """np.searchsorted's order: NaN after every number."""
    return a < b or (b != b and a == a)


@numba.njit(cache=True)
def search_sorted(col, i0, n, key, right):
    """np.searchsorted(col[i0:i0 + n], key, side='right' if right else 'left'): numba's np.searchsorted (numpy's
    loop and NaN order; mixed int/float compare as numpy's common type), one compiled call on the mirrored storage."""
    x = col[i0 : i0 + n]
    if right:
        return np.searchsorted(x, key, side="right")
    return np.searchsorted(x, key, side="left")


@numba.njit(cache=True)
def _write_increasing(col, start, end, i, t, skip):
    """If t is strictly increasing and after the ring's last row (rows [start, end) of the mirrored int64 column),
    write t[skip:] from slot i (wrapping at the half) and return True; else write nothing and return False."""
    cap = col.shape[0] // 2
    n = t.shape[0]
    if end > start:
        prev = col[(end - 1) % cap]
        if t[0] <= prev:
            return False
    for k in range(1, n):
        if t[k] <= t[k - 1]:
            return False
    for k in range(n - skip):
        j = (i + k) % cap
        col[j] = t[skip + k]
        col[j + cap] = t[skip + k]
    return True


# No cylinder pressure sensor reads beyond +-1000 bar (transducers end at 250-1000 bar; a bad pegging or charge-amp
# drift is a few bar): a value beyond it, or infinite, is an invalid sample and is filed as NaN (PressureBlock's own
# convention), so its cycle is skipped as 'pressure_nan' and counted rather than given an IMEP of 1e22 bar that
# also overflows the monitor's state (design note 142). Checked as the samples are copied into the ring: no pass
# of its own.
PRESSURE_LIMIT_PA = 1e8


@numba.njit(cache=True)
def write_block(col_t, col_p, i, t0, period, values):
    """Write samples t0 + k period, values[k] from slot i of two mirrored columns (wrapping at their half); a value
    beyond +-PRESSURE_LIMIT_PA is written as NaN. Returns the number of such values."""
    cap = col_t.shape[0] // 2
    bad = 0
    for k in range(values.shape[0]):
        j = (i + k) % cap
        t = t0 + k * period
        col_t[j] = t
        col_t[j + cap] = t
        x = values[k]
        if abs(x) > PRESSURE_LIMIT_PA:  # NaN compares False: kept as it is
            x = np.nan
            bad += 1
        col_p[j] = x
        col_p[j + cap] = x
    return bad

