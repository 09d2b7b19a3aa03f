"""Pressure frames kept as they came: a ``FrameGroup`` holds the rows of two or more cylinders sampled on one clock
without copying them (design.md §1: ring buffer before cycle assembly).

A ``PressureGroup`` (drivers/assembly/pressure_ring.py) copies every sample into a mirrored ring, twice, with a time column;
for an indicating system that is the bulk of the assembly (genset-v20: 20 cylinders x 200 samples per 10 ms frame,
0.2 ms per cycle, memory bound). A record is immutable, so a ``FrameGroup`` keeps a reference to each frame instead
and resamples a cycle straight from the frames that cover it (drivers/assembly/frame_kernels.py), reading each sample of the
window once. Filing a frame is a few scalar writes.

It counts rows like a ``PressureGroup`` of the same capacity (absolute row numbers ``start`` / ``end``, ``dropped``
by ``drivers.assembly.ringbuffer.RingBuffer``'s rules), computes every sample time with the expression a ring would store,
and searches them with the same loop: every answer, row and count equals that of the ring it replaces. A frame is
let go once none of its rows is retained (checked in batches: at most ``_SLACK`` or as many as are live linger).
"""

from __future__ import annotations

import numba
import numpy as np
from frictionwatch.drivers.assembly.frame_kernels import chunk_search, chunk_times, chunk_values, frame_rows
from frictionwatch.drivers.assembly.pressure_ring import PressureChannel
from frictionwatch.drivers.assembly.ringbuffer import RingBuffer
from numba.typed import List


class FrameGroup:
    """The rows of ``cylinders`` (>= 2, row order of the frames) as the frames that brought them.

    ``frames[c]`` (k, n) float64 C-contiguous, ``ci[c] = (first absolute row, first column)``, ``cf[c] = (time of that
    row [ticks], sample period [ticks])`` for c < ``n_chunks``; ``newest`` is the time of the newest row.
    """

    _SLACK = 32
    _BATCH = 8  # frames per typed-list call (_sync)

    def __init__(self, cylinders: tuple[int, ...], capacity: int):
        if int(capacity) < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        if len(cylinders) < 2:
            raise ValueError("a FrameGroup holds two or more cylinders (one cylinder: PressureGroup)")
        self.cylinders = tuple(int(c) for c in cylinders)
        self.capacity = int(capacity)
        self.start = 0
        self.end = 0
        self.dropped = 0  # unreleased samples per channel lost to overflow
        self.newest = 0.0
        self._frames = List.empty_list(numba.float64[:, ::1])  # frames of chunks [0, n_chunks - len(_new))
        self._new: list[np.ndarray] = []  # the newest frames, not yet in _frames (appended in one call: _sync)
        self.ci = np.zeros((64, 2), dtype=np.int64)
        self.cf = np.zeros((64, 2))
        self._ci1, self._cf1 = self.ci.reshape(-1), self.cf.reshape(-1)  # flat views: cheaper scalar writes in add
        self.n_chunks = 0
        self._trim_at = self._SLACK  # chunk count at which dead chunks are let go next
        self._x = np.empty(0)  # scratch: the sample times of a cycle's window

    def __len__(self) -> int:
        return self.end - self.start

    reserve = RingBuffer.reserve

    def add(self, t0: float, period: float, values: np.ndarray, first: int) -> None:
        """File samples first.. of ``values`` (k, n), sample first + q at t0 + q period [ticks] (a frame longer
        than the ring keeps its newest samples, as ``RingBuffer``). ``values`` is kept, not copied."""
        m = values.shape[1] - first
        end0 = self.end
        if end0 + m - self.start <= self.capacity:  # room for them: what reserve does then
            self.end = end0 + m
            skip = 0
        else:
            _, skip = self.reserve(m)
        nc = self.n_chunks
        if 2 * nc == self._ci1.shape[0]:
            self.ci = np.concatenate((self.ci, np.zeros_like(self.ci)))
            self.cf = np.concatenate((self.cf, np.zeros_like(self.cf)))
            self._ci1, self._cf1 = self.ci.reshape(-1), self.cf.reshape(-1)
        t_first = t0 + skip * period  # what write_frame is given as its t0
        ci, cf, j = self._ci1, self._cf1, 2 * nc  # = ci[nc, 0], ci[nc, 1], cf[nc, 0], cf[nc, 1]
        ci[j] = end0 + skip
        ci[j + 1] = first + skip
        cf[j] = t_first
        cf[j + 1] = period
        self.newest = t_first + (m - skip - 1) * period
        self._new.append(values)  # a Python append; the typed list gets them in batches (a typed append is ~1 us)
        nc += 1
        self.n_chunks = nc
        if nc >= self._trim_at:
            self._trim()

    @property
    def frames(self) -> List:
        """The typed list of the frames of chunks [0, n_chunks) (what the kernels read)."""
        if self._new:
            self._sync()
        return self._frames

    def _sync(self) -> None:
        """Move the frames filed since the last kernel call into the typed list: one compiled call per run of up to
        ``_BATCH`` frames instead of one typed append per frame. The tuple is always ``_BATCH`` long (a short run
        padded with its last frame, not appended: ``count`` says how many are), so the kernel has one signature
        (runs of 8, 4, 2 and 1 were four specialisations, ~0.7 s of the cold compile, and a k9k cycle's three
        frames two calls)."""
        new, b = self._new, self._BATCH
        for i in range(0, len(new), b):
            run = new[i : i + b]
            count = len(run)
            _append_frames(self._frames, tuple(run + [run[-1]] * (b - count)), count)
        new.clear()

    def _trim(self) -> None:
        """Let go of the frames that hold no retained row."""
        if self._new:
            self._sync()
        nc = self.n_chunks
        dead = int(np.searchsorted(self.ci[:nc, 0], self.start, side="right")) - 1  # chunks before start's
        if dead > 0:
            _drop_front(self._frames, dead)
            self.ci[: nc - dead] = self.ci[dead:nc].copy()
            self.cf[: nc - dead] = self.cf[dead:nc].copy()
            nc -= dead
            self.n_chunks = nc
        self._trim_at = nc + max(self._SLACK, nc)

    def last_t(self) -> float | None:
        """Time [ticks] of the newest retained sample, None if empty."""
        return None if self.end == self.start else float(self.newest)

    def searchsorted(self, value: float, side: str = "left") -> int:
        """Absolute row where ``value`` would go among the sample times (as ``PressureGroup.searchsorted``)."""
        if side != "left" and side != "right":
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        return self.start + chunk_search(self.ci, self.cf, self.n_chunks, self.start, self.end - self.start,
                                          float(value), side == "right")

    def discard_before(self, seq: int) -> None:
        self.start = min(max(self.start, int(seq)), self.end)

    def discard_older(self, value: float, keep: int) -> None:
        """``discard_before(searchsorted(value) - keep)`` in one call."""
        start = self.start
        seq = start + chunk_search(self.ci, self.cf, self.n_chunks, start, self.end - start, float(value), False) - keep
        if seq > start:
            self.start = seq if seq < self.end else self.end

    def rows_on_grid(self, t_grid: np.ndarray, rows: np.ndarray, out: np.ndarray, codes: np.ndarray) -> int:
        """Every wanted row at the sorted times ``t_grid`` (``drivers.assembly.frame_kernels.frame_rows``)."""
        n = self.end - self.start
        if self._x.shape[0] < n:  # the window is at most every retained row
            self._x = np.empty(n)
        return frame_rows(self.frames, self.ci, self.cf, self.n_chunks, self.start, self.end, t_grid, rows, out,
                           codes, self._x)

    def times(self, a: int, b: int) -> np.ndarray:
        """Sample times [ticks] of the absolute rows [a, b) (all retained), a new array."""
        out = np.empty(max(b - a, 0))
        chunk_times(self.ci, self.cf, self.n_chunks, a, b, out)
        return out

    def values(self, row: int, a: int, b: int) -> np.ndarray:
        """Values [Pa] of group row ``row`` for the absolute rows [a, b) (all retained), a new array."""
        out = np.empty(max(b - a, 0))
        chunk_values(self.frames, self.ci, self.n_chunks, self.end, row, a, b, out)
        return out

    def channel(self, row: int) -> FrameChannel:
        return FrameChannel(self, row)


class FrameChannel(PressureChannel):
    """One cylinder of a ``FrameGroup`` with the ``RingBuffer`` interface (columns "t" and "p"); its views are
    copies gathered from the frames."""

    def __init__(self, group: FrameGroup, row: int):  # noqa: D107 - no storage of its own
        self.group = group
        self.row = row
        self.cylinder = group.cylinders[row]
        self.capacity = group.capacity
        self.names = ("t", "p")
        self.cols = {}

    def view(self, name: str, a: int | None = None, b: int | None = None) -> np.ndarray:
        """Copy of column ``name`` ("t" or "p") for the rows [a, b) (default: all retained rows)."""
        a = self.start if a is None else int(a)
        b = self.end if b is None else int(b)
        if not self.start <= a <= b <= self.end:
            raise IndexError(f"rows [{a}, {b}) are not all retained (retained [{self.start}, {self.end}))")
        if name == "t":
            return self.group.times(a, b)
        if name == "p":
            return self.group.values(self.row, a, b)
        raise KeyError(name)

    def get(self, name: str, seq: int) -> float:
        if not self.start <= seq < self.end:
            raise IndexError(f"row {seq} is not retained (retained [{self.start}, {self.end}))")
        return self.view(name, seq, seq + 1)[0].item()

    def searchsorted(self, name: str, value: float, side: str = "left") -> int:
        if name == "t":
            return self.group.searchsorted(value, side)
        if side != "left" and side != "right":
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        return self.start + int(np.searchsorted(self.view(name), value, side))

    def extend(self, *values: np.ndarray) -> None:
        raise ValueError("rows of a multi-cylinder group are written together (EngineBuffers.add_frame)")

    def row_on_grid(self, t_grid: np.ndarray, out: np.ndarray) -> int:
        """This cylinder at the sorted times ``t_grid`` into ``out`` (m,); returns its ROW_* code."""
        rows = np.full(len(self.group.cylinders), -1, dtype=np.int64)
        rows[self.row] = 0
        codes = np.zeros(rows.shape[0], dtype=np.int64)
        self.group.rows_on_grid(t_grid, rows, out.reshape(1, -1), codes)
        return int(codes[self.row])


@numba.njit(cache=True)
def _drop_front(frames, n):
    del frames[0:n]


@numba.njit(cache=True)
def _append_frames(frames, new, count):
    """Append the first ``count`` arrays of the tuple ``new`` to the typed list ``frames``."""
    for i in range(count):
        frames.append(new[i])
