"""Pressure rings grouped by sampling clock: channels sampled together share one time column.

An indicating system samples all its channels at once (``PressureFrame``); a CAN / DAQ / serial driver delivers one
cylinder per record (``PressureBlock``). A block is a group of one, a ``PressureGroup``: one mirrored time column
``t`` (2 cap,) and one value block ``p`` (k, 2 cap), row r = ``cylinders[r]``. The frames of two or more cylinders
go to a ``drivers.assembly.frame_store.FrameGroup`` instead, which keeps the frames themselves (nothing copied at ingest)
behind the same interface. Resampling every cylinder of a group onto a cycle's grid is one numba call
(``rows_on_grid``; drivers/assembly/pressure_kernels.py).

``PressureChannel`` is the per-cylinder face of a group with the ``RingBuffer`` interface (columns "t" and "p",
absolute row numbers, zero-copy views): ``EngineBuffers.pressure[cyl]`` keeps working for one-cylinder code such
as the pressure phase test. Its start / end / dropped are the group's: the rows of a group stay aligned.

Mirrored storage, overflow and release rules are those of ``drivers.assembly.ringbuffer.RingBuffer``.
"""

from __future__ import annotations

import numba
import numpy as np
from frictionwatch.core.types import PressureBlock, PressureFrame
from frictionwatch.drivers.assembly.pressure_kernels import pressure_rows
from frictionwatch.drivers.assembly.ringbuffer import PRESSURE_LIMIT_PA, RingBuffer, search_sorted


class PressureGroup:
    """Ring of the cylinders ``cylinders`` sampled on one clock (shared sample times).

    Parameters
    ----------
    cylinders : 1-based cylinder numbers, row order of ``p``
    capacity : retained samples per channel (> 0)
    """

    def __init__(self, cylinders: tuple[int, ...], capacity: int):
        if int(capacity) < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        if not cylinders:
            raise ValueError("a pressure group needs at least one cylinder")
        self.cylinders = tuple(int(c) for c in cylinders)
        self.capacity = int(capacity)
        self.t = np.zeros(2 * self.capacity)  # sample times [timer ticks, float64]
        self.p = np.zeros((len(self.cylinders), 2 * self.capacity))  # pressure [Pa], row r = cylinders[r]
        self.start = 0
        self.end = 0
        self.dropped = 0  # unreleased samples per channel lost to overflow
        # the newest filed record's sample period [ticks] (0: none known): the resampling's hole test (window_weights)
        self.period = 0.0

    def __len__(self) -> int:
        return self.end - self.start

    reserve = RingBuffer.reserve

    def last_t(self) -> float | None:
        """Time [ticks] of the newest retained sample, None if empty."""
        return None if self.end == self.start else float(self.t[(self.end - 1) % self.capacity])

    @property
    def newest(self) -> float:
        """Time [ticks] of the newest sample (meaningful when the group is not empty)."""
        return self.t[(self.end - 1) % self.capacity]

    def searchsorted(self, value: float, side: str = "left") -> int:
        """Absolute row where ``value`` would go in the time column (as ``RingBuffer.searchsorted``)."""
        if side != "left" and side != "right":
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        return self.start + search_sorted(self.t, self.start % self.capacity, self.end - self.start, value,
                                           side == "right")

    def discard_before(self, seq: int) -> None:
        self.start = min(max(self.start, int(seq)), self.end)

    def discard_older(self, value: float, keep: int) -> None:
        """``discard_before(searchsorted(value) - keep)`` in one call."""
        start = self.start
        seq = start + search_sorted(self.t, start % self.capacity, self.end - start, value, False) - keep
        if seq > start:
            self.start = seq if seq < self.end else self.end

    def rows_on_grid(self, t_grid: np.ndarray, rows: np.ndarray, out: np.ndarray, codes: np.ndarray) -> int:
        """Every wanted row at the sorted times ``t_grid`` (``drivers.assembly.pressure_kernels.pressure_rows``)."""
        return pressure_rows(self.t, self.p, self.start, self.end, t_grid, rows, out, codes, self.period)

    def channel(self, row: int) -> PressureChannel:
        return PressureChannel(self, row)


class PressureChannel(RingBuffer):
    """One cylinder of a ``PressureGroup`` with the ``RingBuffer`` interface (columns "t" and "p")."""

    def __init__(self, group: PressureGroup, row: int):  # noqa: D107 - no RingBuffer storage of its own
        self.group = group
        self.row = row
        self.cylinder = group.cylinders[row]
        self.capacity = group.capacity
        self.names = ("t", "p")
        self.cols = {"t": group.t, "p": group.p[row]}  # a row of a C-order block: contiguous

    start = property(lambda self: self.group.start, lambda self, v: setattr(self.group, "start", v))
    end = property(lambda self: self.group.end, lambda self, v: setattr(self.group, "end", v))
    dropped = property(lambda self: self.group.dropped, lambda self, v: setattr(self.group, "dropped", v))

    def extend(self, *values: np.ndarray) -> None:
        if len(self.group.cylinders) != 1:
            raise ValueError("rows of a multi-cylinder group are written together (EngineBuffers.add_frame)")
        super().extend(*values)


@numba.njit(cache=True)
def write_frame(col_t, block_p, i, t0, period, values, s0):
    """Write samples s0.. of a (k, n) frame, sample s at t0 + (s - s0) period, from slot i of the mirrored time
    column and value block (wrapping at their half; the same times as ``drivers.assembly.ringbuffer.write_block``);
    a value beyond +-PRESSURE_LIMIT_PA is written as NaN. Returns the number of such values."""
    cap = col_t.shape[0] // 2
    k, n = values.shape
    m = n - s0
    first = min(cap - i, m)  # rows before the wrap; the rest go to slot 0 on
    for q in range(m):
        t = t0 + q * period
        j = i + q if q < first else q - first
        col_t[j] = t
        col_t[j + cap] = t
    bad = 0
    for r in range(k):
        for q in range(m):
            x = values[r, s0 + q]
            if abs(x) > PRESSURE_LIMIT_PA:  # an invalid sample (ringbuffer.PRESSURE_LIMIT_PA); NaN compares False
                x = np.nan
                bad += 1
            j = i + q if q < first else q - first
            block_p[r, j] = x
            block_p[r, j + cap] = x
    return bad


def frame_blocks(frame: PressureFrame) -> list[PressureBlock]:
    """A frame as one ``PressureBlock`` per cylinder, in its row order (for protocols that carry one cylinder per
    message: CAN, DAQ, serial). Row r is exactly ``PressureBlock(cylinders[r], t0_ticks, period_ticks, values[r])``."""
    values = np.asarray(frame.values, dtype=np.float64)
    return [PressureBlock(int(c), frame.t0_ticks, frame.period_ticks, np.ascontiguousarray(values[r]))
            for r, c in enumerate(frame.cylinders)]
