"""Batching of stream records into log messages of about one span (default 10 ms) each.

A live driver may hand over a handful of edges per record, a simulator a whole cycle; one MCAP message per record
would then cost ~30 bytes of framing per few bytes of data, or give coarse replay pacing. ``Batcher`` joins
consecutive records of one stream (teeth, cam, pressure per cylinder, pressure frames per cylinder set) and splits
long ones, without changing a single tick or sample: the concatenation of the messages of a stream equals the
concatenation of its records.

Pressure blocks and frames are joined only when the next block continues the sample grid exactly
(``t0_next == t0 + n * period`` in rational arithmetic), and split only where ``t0 + k * period`` is an integer.
Load samples pass through unchanged.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
from frictionwatch.core.types import (
    CamBatch,
    FreeEndToothBatch,
    PressureBlock,
    PressureFrame,
    StreamRecord,
    ToothBatch,
)


class _Pressure:
    """Pending samples of one pressure stream (a block's cylinder or a frame's cylinder tuple): sample i at
    ``t0 + i * period``; values are (n,) for blocks, (k, n) for frames, joined along their last axis."""

    def __init__(self, record: PressureBlock | PressureFrame) -> None:
        self.t0 = record.t0_ticks
        self.period = record.period_ticks
        self.exact_period = Fraction(record.period_ticks)
        self.parts = [record.values]
        self.n = record.values.shape[-1]
        self.rows = record.values.shape[0] if record.values.ndim == 2 else 1

    def continues(self, record: PressureBlock | PressureFrame) -> bool:
        return record.period_ticks == self.period and Fraction(self.t0) + self.n * self.exact_period == record.t0_ticks

    def take(self, count: int, key: int | tuple[int, ...]) -> PressureBlock | PressureFrame:
        values = np.concatenate(self.parts, axis=-1) if len(self.parts) > 1 else self.parts[0]
        part = np.ascontiguousarray(values[..., :count])
        out = PressureFrame(key, self.t0, self.period, part) if isinstance(key, tuple) else \
            PressureBlock(key, self.t0, self.period, part)
        self.t0 = int(Fraction(self.t0) + count * self.exact_period)  # integral by construction of `count`
        self.parts = [values[..., count:]]
        self.n -= count
        return out


class Batcher:
    """Join and split records into messages of about ``span_ticks`` timer ticks.

    ``add(record)`` returns the messages that are complete; ``drain()`` the rest (call it at the end).
    """

    def __init__(self, span_ticks: float) -> None:
        if not span_ticks > 0:
            raise ValueError(f"span_ticks must be > 0, got {span_ticks!r}")
        self.span = span_ticks
        self._edges: dict[type, np.ndarray] = {}
        self._pressure: dict[int | tuple[int, ...], _Pressure] = {}  # block cylinder or frame cylinders

    def add(self, record: StreamRecord) -> list[StreamRecord]:
        if isinstance(record, ToothBatch | CamBatch | FreeEndToothBatch):
            return self._add_edges(record)
        if isinstance(record, PressureBlock):
            return self._add_pressure(record, record.cylinder)
        if isinstance(record, PressureFrame):
            return self._add_pressure(record, tuple(record.cylinders))
        return [record]

    def _add_edges(self, record: ToothBatch | CamBatch | FreeEndToothBatch) -> list[StreamRecord]:
        kind = type(record)
        out: list[StreamRecord] = []
        pending = self._edges.pop(kind, None)
        ticks = record.ticks
        if pending is not None:
            if ticks[0] <= pending[-1]:  # not a continuation (restart, glitch): keep both as they are
                out.append(kind(pending))
            else:
                ticks = np.concatenate((pending, ticks))
        while ticks[-1] - ticks[0] >= self.span:
            k = max(1, int(np.searchsorted(ticks, ticks[0] + self.span, side="left")))
            out.append(kind(ticks[:k].copy()))
            ticks = ticks[k:]
        self._edges[kind] = ticks
        return out

    def _step(self, pending: _Pressure) -> int | None:
        """Samples per message: about one span, a multiple of the grid's denominator; None = never split."""
        per = max(1, math.ceil(self.span / pending.period))
        q = pending.exact_period.denominator
        step = q * math.ceil(per / q)
        return step if step <= 10 * per else None

    def _add_pressure(self, block: PressureBlock | PressureFrame, key: int | tuple[int, ...]
                      ) -> list[StreamRecord]:
        out: list[StreamRecord] = []
        pending = self._pressure.get(key)
        if pending is not None and pending.continues(block):
            pending.parts.append(block.values)
            pending.n += block.values.shape[-1]
        else:
            if pending is not None:
                out.append(pending.take(pending.n, key))
            pending = self._pressure[key] = _Pressure(block)
        step = self._step(pending)
        if step is None:
            if pending.n * pending.period >= self.span:
                out.append(pending.take(pending.n, key))
        else:
            while pending.n > step:  # keep a remainder so the next block can join it
                out.append(pending.take(step, key))
        if pending.n == 0:
            del self._pressure[key]
        return out

    @property
    def pending_bytes(self) -> int:
        """Raw bytes held back (8 per tick or sample), to be written by later ``add`` or ``drain`` calls."""
        return 8 * (sum(len(t) for t in self._edges.values()) + sum(p.n * p.rows for p in self._pressure.values()))

    def drain(self) -> list[StreamRecord]:
        out: list[StreamRecord] = [kind(ticks) for kind, ticks in self._edges.items() if len(ticks)]
        out += [p.take(p.n, key) for key, p in self._pressure.items() if p.n]
        self._edges.clear()
        self._pressure.clear()
        return out
