"""The rings of one engine (design.md §1: ring buffer before cycle assembly).

``EngineBuffers`` bundles the rings of one engine: tooth ticks, cam ticks, pressure (time, value) per group of
cylinders sampled together (drivers/assembly/pressure_ring.py; a ``PressureBlock`` cylinder is a group of one, a
``PressureFrame`` fills one group with one call) and load (ticks, torque, power), and files each stream record into
the right one.

A cylinder belongs to the group that first carried it. Its samples arriving later in another shape (a block for a
cylinder of a frame group, or a frame whose cylinder set overlaps another group's) would mix two clocks in one
channel: such records are refused, counted in ``rejected["pressure_conflict"]`` (samples) and logged once per shape.
A frame with the same cylinders in another order is rearranged into its group's row order.

Frames of two or more cylinders are kept by reference (``drivers.assembly.frame_store.FrameGroup``): a record is immutable,
so its values must not be changed after it was filed (every driver hands out fresh arrays). A frame that is not a
writeable, aligned, C-contiguous float64 array is copied once into one.
"""

from __future__ import annotations

import logging
import math
from collections import Counter

import numpy as np
from frictionwatch.core.types import CamBatch, LoadSample, PressureBlock, PressureFrame, StreamRecord, ToothBatch
from frictionwatch.drivers.assembly.frame_store import FrameGroup
from frictionwatch.drivers.assembly.pressure_ring import PressureChannel, PressureGroup, write_frame
from frictionwatch.drivers.assembly.ringbuffer import PRESSURE_LIMIT_PA, RingBuffer, write_block

log = logging.getLogger(__name__)
_F64 = np.dtype(np.float64)
_I64 = np.dtype(np.int64)
_isfinite = math.isfinite
# A load reading beyond what any brake or generator gives (the largest engines: ~8 MN m, ~80 MW) is not a reading:
# filed as NaN, i.e. not measured, as a missing one is, rather than a mean load of 1e300 N m (design note 142).
LOAD_LIMIT_NM = 1e8
LOAD_LIMIT_W = 1e10


class EngineBuffers:
    """The rings of one engine. Pressure groups are made on first sight of a cylinder (or of a frame's cylinders).

    Pressure sample times are kept as float64 timer ticks (exact to < 1e-3 tick for 28 years at 10 MHz), so a
    block with a non-integer period keeps its exact sample times. Load rows are (ticks, torque [N m], power [W]).

    ``pressure`` maps a cylinder to its channel (``PressureChannel``, RingBuffer interface); ``groups`` maps the
    cylinder tuple of each group to the ``PressureGroup``; ``groups_version`` counts group creations.
    """

    def __init__(self, tooth_capacity: int = 1 << 14, cam_capacity: int = 256, pressure_capacity: int = 1 << 15,
                 load_capacity: int = 4096):
        self.teeth = RingBuffer(tooth_capacity, {"t": np.int64})
        self.cam = RingBuffer(cam_capacity, {"t": np.int64})
        self.load = RingBuffer(load_capacity, {"t": np.int64, "torque": np.float64, "power": np.float64})
        self.pressure: dict[int, PressureChannel] = {}
        self.groups: dict[tuple[int, ...], PressureGroup | FrameGroup] = {}
        self.groups_version = 0
        self.pressure_capacity = int(pressure_capacity)
        self._single: dict[int, PressureGroup] = {}  # cylinder -> its group when that is a group of one
        self.rejected: Counter[str] = Counter()  # input rows refused (out of order, conflicting), by stream

    def add(self, record: StreamRecord) -> int:
        """File one record; returns the number of rows accepted (a frame's samples count once per cylinder).
        Rows out of time order are refused and counted."""
        if isinstance(record, ToothBatch):
            return self._add_ticks(self.teeth, record.ticks, "teeth")
        if isinstance(record, CamBatch):
            return self._add_ticks(self.cam, record.ticks, "cam")
        if isinstance(record, PressureBlock):
            return self.add_pressure(record)
        if isinstance(record, PressureFrame):
            return self.add_frame(record)
        if isinstance(record, LoadSample):
            return self.add_load(record)
        raise TypeError(f"not a stream record: {type(record).__name__}")

    def add_load(self, record: LoadSample) -> int:
        """File one load reading (1 if accepted; 0 if not later than the last one, counted)."""
        ring = self.load
        last = ring.last("t")
        if last is not None and record.ticks <= last:
            self.rejected["load"] += 1
            return 0
        torque, power = record.torque, record.power
        if not (abs(torque) <= LOAD_LIMIT_NM and abs(power) <= LOAD_LIMIT_W):  # NaN: not measured, kept as it is
            if abs(torque) > LOAD_LIMIT_NM:
                torque, self.rejected["load_out_of_range"] = math.nan, self.rejected["load_out_of_range"] + 1
            if abs(power) > LOAD_LIMIT_W:
                power, self.rejected["load_out_of_range"] = math.nan, self.rejected["load_out_of_range"] + 1
        ring.append(record.ticks, torque, power)
        return 1

    def _add_ticks(self, ring: RingBuffer, ticks: np.ndarray, stream: str) -> int:
        t = ticks
        if not (type(t) is np.ndarray and t.ndim == 1 and (t.dtype is _I64 or t.dtype == _I64)):
            t = np.asarray(ticks, dtype=np.int64).ravel()
        if t.shape[0] == 0:
            return 0
        if ring.extend_increasing(t):  # the usual batch: one compiled check-and-write
            return int(t.shape[0])
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

    # ---- pressure -----------------------------------------------------------------------------------------------
    def _new_group(self, cylinders: tuple[int, ...]) -> PressureGroup | FrameGroup:
        group = self.groups[cylinders] = (PressureGroup if len(cylinders) == 1 else FrameGroup)(
            cylinders, self.pressure_capacity)
        for r, c in enumerate(cylinders):
            self.pressure[c] = group.channel(r)
        if len(cylinders) == 1:
            self._single[cylinders[0]] = group
        self.groups_version += 1
        return group

    def _conflict(self, shape: str, samples: int) -> int:
        if self.rejected[f"pressure_conflict:{shape}"] == 0:
            log.warning("pressure %s refused: its cylinders already arrive in another grouping (blocks vs frames); "
                        "later ones are only counted", shape)
        self.rejected[f"pressure_conflict:{shape}"] += 1
        self.rejected["pressure_conflict"] += samples
        return 0

    def _tail(self, group: PressureGroup, t0: float, period: float, n: int, k: int) -> tuple[float, int]:
        """Start time and first sample index of the part of an n-sample record that is newer than the group's last
        sample (an overlapping, repeated record keeps its new tail only); the refused samples are counted."""
        if group.end == group.start:
            return t0, 0
        last = float(group.newest)  # = group.last_t()
        if t0 > last:
            return t0, 0
        first = int((last - t0) // period) + 1
        while first > 0 and t0 + (first - 1) * period > last:
            first -= 1
        self.rejected["pressure"] += min(first, n) * k
        return t0 + first * period, first

    def add_pressure(self, block: PressureBlock) -> int:
        """File one pressure block (a hot path for CAN / DAQ input: tens of blocks per cycle on a big engine)."""
        v = block.values
        if not (type(v) is np.ndarray and (v.dtype is _F64 or v.dtype == _F64) and v.ndim == 1):  # the hot path
            v = np.asarray(v, dtype=np.float64).ravel()
        if v.shape[0] == 0:
            return 0
        period = block.period_ticks
        if not (period > 0 and math.isfinite(period)):
            self.rejected["pressure"] += v.size
            return 0
        group = self._single.get(block.cylinder)
        if group is None:
            if block.cylinder in self.pressure:  # the cylinder comes in frames
                return self._conflict(f"block of cylinder {block.cylinder}", v.size)
            group = self._new_group((block.cylinder,))
        t0, first = self._tail(group, float(block.t0_ticks), period, v.shape[0], 1)
        if first >= v.shape[0]:
            return 0
        if first:
            v = v[first:]
        i, skip = group.reserve(v.size)
        self._out_of_range(write_block(group.t, group.p[0], i, t0 + skip * period, float(period), v[skip:]))
        group.period = float(period)  # a hole the whole window falls in (pressure_kernels.window_weights)
        return int(v.size)

    def _frame_group(self, frame: PressureFrame, k: int, n: int
                     ) -> tuple[PressureGroup | FrameGroup | None, np.ndarray | None]:
        """The group of a frame's cylinder tuple (made on first sight) and the row order to apply (None: as it is),
        or (None, None) if the tuple is invalid or conflicts with other groups (counted)."""
        raw = frame.cylinders
        if not (isinstance(raw, tuple | list) and len(raw) == k and k > 0
                and all(isinstance(c, int | np.integer) and not isinstance(c, bool) and c >= 1 for c in raw)
                and len(set(int(c) for c in raw)) == k):
            self.rejected["pressure_bad_frame"] += 1
            return None, None
        cyls = tuple(int(c) for c in raw)
        group = self.groups.get(cyls)
        order = None
        if group is None:
            owners = {id(self.pressure[c].group): self.pressure[c].group for c in cyls if c in self.pressure}
            if not owners:
                group = self._new_group(cyls)
            elif len(owners) == 1 and set(next(iter(owners.values())).cylinders) == set(cyls):
                group = next(iter(owners.values()))  # the same cylinders in another order
                order = np.array([cyls.index(c) for c in group.cylinders], dtype=np.int64)
            else:
                self._conflict(f"frame of cylinders {cyls}", k * n)
                return None, None
        return group, order

    def add_frame(self, frame: PressureFrame) -> int:
        """File one pressure frame: all its cylinders in one call. Returns samples accepted x cylinders."""
        v = frame.values
        if not (type(v) is np.ndarray and (v.dtype is _F64 or v.dtype == _F64) and v.ndim == 2
                and (fl := v.flags).c_contiguous and fl.writeable and fl.aligned):  # (an unpickled dtype is not _F64)
            v = np.ascontiguousarray(v, dtype=np.float64)
            if v.ndim != 2:
                self.rejected["pressure_bad_frame"] += 1
                return 0
            if not (v.flags.writeable and v.flags.aligned):
                v = v.copy()  # kept by reference from here on: a plain array
        k, n = v.shape
        if n == 0:
            return 0
        try:  # a group's key is a valid cylinder tuple: a frame with exactly that tuple needs no further look
            group = self.groups.get(frame.cylinders) if type(frame.cylinders) is tuple else None
        except TypeError:  # a tuple holding something unhashable: not cylinder numbers
            group = None
        order = None
        if group is None or len(group.cylinders) != k:  # first sight, another order, or not valid: look closer
            group, order = self._frame_group(frame, k, n)
            if group is None:
                return 0
        if order is not None:
            v = np.ascontiguousarray(v[order])
        period = frame.period_ticks
        if not (period > 0 and _isfinite(period)):
            self.rejected["pressure"] += v.size
            return 0
        t0, first = self._tail(group, float(frame.t0_ticks), period, n, k)  # an overlap keeps its new tail
        if first >= n:
            return 0
        if k > 1:
            group.add(t0, float(period), self._valid(v), first)  # kept by reference: a copy if it must change
        else:  # a one-cylinder frame shares the ring of its cylinder's blocks
            i, skip = group.reserve(n - first)
            self._out_of_range(write_frame(group.t, group.p, i, t0 + skip * period, float(period), v, first + skip))
            group.period = float(period)
        return int(n - first) * k

    def _valid(self, v: np.ndarray) -> np.ndarray:
        """``v`` with every value beyond +-PRESSURE_LIMIT_PA (ringbuffer.py: an invalid sample) as NaN: a new array,
        ``v`` itself when none is (the kernels that copy blocks into rings do the same as they copy)."""
        lo, hi = v.min(), v.max()  # NaN if v holds one: then look closer (a NaN alone is kept as it is)
        if -PRESSURE_LIMIT_PA <= lo and hi <= PRESSURE_LIMIT_PA:
            return v
        bad = np.abs(v) > PRESSURE_LIMIT_PA  # NaN compares False: kept
        if not self._out_of_range(int(np.count_nonzero(bad))):
            return v
        return np.where(bad, np.nan, v)

    def _out_of_range(self, n: int) -> int:
        """Count ``n`` pressure samples filed as NaN for being out of range (logged once)."""
        if n:
            if not self.rejected["pressure_out_of_range"]:
                log.warning("pressure samples beyond +-%g Pa filed as invalid (NaN); counted in "
                            "rejected['pressure_out_of_range']", PRESSURE_LIMIT_PA)
            self.rejected["pressure_out_of_range"] += n
        return n

    def release_before(self, t_keep: float, load_hold_ticks: float, cam_next: int) -> None:
        """Release what a consumer at tick ``t_keep`` no longer needs: pressure rows before it (two are kept before
        it), load rows older than ``t_keep - load_hold_ticks`` but the last of them (the hold of ``load_mean``),
        cam rows before it that were already placed (rows before ``cam_next``)."""
        for group in self.groups.values():  # the channels of a group share their rows
            group.discard_older(t_keep, 2)
        self.load.discard_older("t", t_keep - load_hold_ticks, 1)
        ring = self.cam
        if ring.start < cam_next:  # else every placed row is released already: nothing to search
            ring.discard_older("t", t_keep, 0, cam_next)

    def dropped(self) -> Counter[str]:
        """Unconsumed rows lost to overflow, per ring (pressure: per cylinder)."""
        out: Counter[str] = Counter()
        for name, ring in (("teeth", self.teeth), ("cam", self.cam), ("load", self.load)):
            if ring.dropped:
                out[name] = ring.dropped
        for group in self.groups.values():
            if group.dropped:
                for cyl in group.cylinders:
                    out[f"pressure_{cyl}"] = group.dropped
        return out

