"""The second (free-end) wheel's edges on CAN FD: ``FreeEndTeethFD`` (docs/protocols.md §3.8), encoder and decoder.

A board that time-stamps the free-end pickup with the acquisition timer (the tooth board's own counter, or a copy
disciplined to it, as the pressure DAQ does) sends its edges as frames of 1..29: ``BaseTicks`` (u32, the counter at
the first edge) and up to 28 u16 deltas. The byte layout is read from the shipped DBC (drivers/can/codec.py). The
decoder puts frames in ``Seq`` order (drivers/sequence.py), unwraps ``BaseTicks`` with the shared unwrapper and gives
``FreeEndToothBatch`` records with strictly increasing ticks; a bad header, a fault frame or a repeated edge is
counted and skipped, never raised.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import can
import numpy as np
from frictionwatch.core.types import FreeEndToothBatch
from frictionwatch.drivers.can.codec import byte_field, load_dbc
from frictionwatch.drivers.sequence import SequenceTracker
from frictionwatch.drivers.timebase import TimerUnwrapper

MESSAGE = "FreeEndTeethFD"
MAX_DELTAS = 28
MAX_EDGES = MAX_DELTAS + 1
FLAG_OVERFLOW, FLAG_SENSOR_FAULT, FLAG_RESTART = 0x01, 0x02, 0x04


@dataclass(frozen=True)
class TeethLayout:
    frame_id: int
    dtype: np.dtype  # Seq, BaseTicks, NEdges, Flags, deltas (28,)


@functools.cache
def teeth_layout() -> TeethLayout:
    """The frame's byte layout from the DBC (ValueError if it no longer fits: flags must share one byte)."""
    msg = load_dbc().get_message_by_name(MESSAGE)
    names = ["Seq", "BaseTicks", "NEdges"]
    fields = [byte_field(msg, n) for n in names]
    bits = [msg.get_signal_by_name(n).start for n in ("Overflow", "SensorFault", "Restart")]
    if [b - bits[0] for b in bits] != [0, 1, 2] or bits[0] % 8:
        raise ValueError(f"{MESSAGE}: Overflow, SensorFault, Restart must be bits 0..2 of one byte")
    first = byte_field(msg, "D01")
    for i in range(1, MAX_DELTAS + 1):
        off, dt, _, _ = byte_field(msg, f"D{i:02d}")
        if off != first[0] + 2 * (i - 1) or dt != "<u2":
            raise ValueError(f"{MESSAGE}: deltas must be a contiguous u16 array")
    dtype = np.dtype({"names": [*names, "Flags", "deltas"],
                      "formats": [f[1] for f in fields] + ["u1", ("<u2", MAX_DELTAS)],
                      "offsets": [f[0] for f in fields] + [bits[0] // 8, first[0]], "itemsize": 64})
    return TeethLayout(msg.frame_id, dtype)


def encode_free_end_teeth(seq: int, ticks: Iterable[int], flags: int = 0) -> can.Message:
    """One frame: ``ticks`` (1..29 absolute timer values, taken mod 2**32, deltas 1..65535)."""
    t = np.asarray(ticks, dtype=np.int64).ravel()
    if not 1 <= t.size <= MAX_EDGES:
        raise ValueError(f"a {MESSAGE} frame carries 1..{MAX_EDGES} edges, got {t.size}")
    d = np.diff(t)
    if d.size and (d.min() < 1 or d.max() > 0xFFFF):
        raise ValueError("edge deltas must be 1..65535 ticks; start a new frame (free_end_frames does this)")
    rec = np.zeros(1, teeth_layout().dtype)
    rec["Seq"], rec["BaseTicks"], rec["NEdges"], rec["Flags"] = seq & 0xFFFF, int(t[0]) & 0xFFFFFFFF, t.size, flags
    rec["deltas"][0, :d.size] = d
    return can.Message(arbitration_id=teeth_layout().frame_id, is_extended_id=False, is_fd=True,
                       bitrate_switch=True, data=rec.tobytes())


def free_end_frames(ticks: np.ndarray, seq: int = 0) -> list[can.Message]:
    """Edges cut into frames as the board does (29 a frame, a new frame where a delta exceeds 16 bits)."""
    t = np.asarray(ticks, dtype=np.int64)
    out = []
    for run in np.split(t, np.flatnonzero(np.diff(t) > 0xFFFF) + 1):
        for i in range(0, run.size, MAX_EDGES):
            out.append(encode_free_end_teeth(seq + len(out), run[i:i + MAX_EDGES]))
    return out


class FreeEndTeethTrack:
    """Decoder state of the ``FreeEndTeethFD`` stream: counter order, timer unwrapping, the last edge."""

    def __init__(self, unwrapper: TimerUnwrapper, count: Callable[[str, int], None], window: int = 4) -> None:
        self.unwrapper, self._count = unwrapper, count
        self.tracker: SequenceTracker[tuple[int, int, int, bytes]] = SequenceTracker(1 << 16, window)
        self.last: int | None = None

    def feed(self, data: np.ndarray) -> list[FreeEndToothBatch]:
        """Rows (k, 64) uint8 of this frame id, in arrival order."""
        rec = np.ascontiguousarray(data[:, :64]).view(teeth_layout().dtype).ravel()
        released = []
        for r in rec:
            n, flags, seq = int(r["NEdges"]), int(r["Flags"]), int(r["Seq"])
            if not 1 <= n <= MAX_EDGES:
                self._count("bad_frame_header", 1)
                continue
            if flags & FLAG_RESTART:
                self._count("teeth2_restart", 1)
                released += self.tracker.reset(start=seq)
            released += self.tracker.push(seq, (int(r["BaseTicks"]), n, flags, r["deltas"][:n - 1].copy()))
        return self._edges(released)

    def flush(self) -> list[FreeEndToothBatch]:
        return self._edges(self.tracker.flush())

    def _edges(self, released: list) -> list[FreeEndToothBatch]:
        for reason, k in self.tracker.counts.items():
            self._count("teeth2_" + reason, k)
        self.tracker.counts.clear()
        out = []
        for (base, n, flags, deltas), restarted in released:
            start = self.unwrapper.unwrap(base, restart_hint=bool(restarted or flags & FLAG_RESTART))
            ticks = start + np.concatenate([[0], np.cumsum(deltas, dtype=np.int64)])
            if n > 1:
                self.unwrapper.unwrap((base + int(ticks[-1] - start)) & 0xFFFFFFFF)  # reference = newest edge
            if flags & FLAG_OVERFLOW:
                self._count("teeth2_capture_overflow", 1)
            if flags & FLAG_SENSOR_FAULT:
                self._count("teeth2_sensor_fault_edges", n)
                continue
            keep = np.ones(n, bool)
            keep[1:] = np.diff(ticks) > 0
            if self.last is not None:
                keep &= ticks > self.last
            if not keep.all():
                self._count("non_increasing_edge", int(n - keep.sum()))
                ticks = ticks[keep]
            if ticks.size:
                self.last = int(ticks[-1])
                out.append(FreeEndToothBatch(ticks.astype(np.int64)))
        return out
