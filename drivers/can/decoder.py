"""CAN frames -> PressureBlock / LoadSample / FreeEndToothBatch records (docs/protocols.md §3), batch-vectorised.

Per cylinder, frames are put in order by their counter (drivers/sequence.py, a few frames of reordering undone),
then merged into one block while both the counter and the time reference continue (next T0 = T0 + n * period,
within ``time_tolerance`` ticks). A lost frame, a DAQ overrun or a restart splits the block: samples are never
made up. Saturated (raw 32767) and invalid (raw -32768) samples become NaN and are counted.

Load frames carry no acquisition-timer value (the genset controller does not know that timer). Their tick is the
host receive time mapped onto the timer through the latest pressure frame (``tick_hz`` needed); this is good to a
frame's bus latency (about a millisecond), plenty for a cycle-mean load. Before any pressure frame a load frame
has no time reference and is dropped (counted).
"""

from __future__ import annotations

import itertools
import math
from collections import Counter
from collections.abc import Callable, Iterable, Sequence

import can
import numpy as np
from frictionwatch.core.types import FreeEndToothBatch, LoadSample, PressureBlock, StreamRecord
from frictionwatch.drivers.can.codec import (
    CLASSIC_SAMPLES,
    FD_SAMPLES,
    FLAG_DAQ_OVERRUN,
    FLAG_RESTART,
    FLAG_SENSOR_FAULT,
    PGN_LOAD,
    PGN_RESULTS,
    RAW_INVALID,
    RAW_SATURATED,
    j1939_pgn,
    j1939_value,
    layouts,
)
from frictionwatch.drivers.can.teeth import FreeEndTeethTrack, teeth_layout
from frictionwatch.drivers.sequence import SequenceTracker
from frictionwatch.drivers.timebase import TimerUnwrapper

KIND_FD, KIND_REF, KIND_CLASSIC, KIND_LOAD, KIND_OURS, KIND_TEETH2 = 0, 1, 2, 3, 4, 5
Row = tuple[int, int, float, int, float, int, np.ndarray, float]  # seq, t0, period, n, scale, flags, samples, ts


class _Track:
    """Per-cylinder state: counter order and the classic time reference."""

    def __init__(self, window: int) -> None:
        self.tracker: SequenceTracker[Row] = SequenceTracker(1 << 16, window)
        self.ref: tuple[int, int, int, float] | None = None  # classic: seq, t0, period, host time


# the longest acquisition time one PressureBlock spans (see _assemble): a tenth of the cycle assembler's pressure
# wait (drivers/assembly/cycles.py max_wait_s), and ~40 CAN FD frames of a 20 kHz channel, so a batch still makes
# few records
MAX_BLOCK_S = 0.05


class CanDecoder:
    """Stateful decoder of frictionwatch CAN traffic; ``feed`` a batch of messages, get records in time order.

    Parameters
    ----------
    unwrapper : TimerUnwrapper, optional
        Shared with the serial source of the same board (see drivers/timebase.py).
    tick_hz : float
        Acquisition timer clock [Hz]: to place load frames in time and to cut long blocks (MAX_BLOCK_S).
    reorder_window : int
        Frames per cylinder held to undo reordering before a gap is declared.
    ref_timeout_s : float
        A classic time reference older than this (host time) is not used.
    load_source_address : int, optional
        Accept GensetLoad only from this J1939 source address (on a bus where another device uses PGN 0xFF10).
    count : callable, optional
        ``count(reason, n)`` for skipped input (default: ``self.damage``).
    """

    def __init__(self, *, unwrapper: TimerUnwrapper | None = None, tick_hz: float = 10e6, reorder_window: int = 4,
                 ref_timeout_s: float = 1.0, time_tolerance: float = 1.5, load_source_address: int | None = None,
                 count: Callable[[str, int], None] | None = None) -> None:
        self.lay = layouts()
        self.damage: Counter[str] = Counter()
        self._count = count or (lambda reason, n=1: self.damage.update({reason: n}))
        self.unwrapper = unwrapper or TimerUnwrapper()
        self.tick_hz = tick_hz
        self.window = reorder_window
        self.ref_timeout_s = ref_timeout_s
        self.tol = time_tolerance
        self.load_sa = load_source_address
        self.tracks: dict[tuple[int, int], _Track] = {}  # (KIND_FD or KIND_CLASSIC, cylinder)
        self._load_seq: SequenceTracker[int] = SequenceTracker(256, 0, restart_after=4)
        self._clock: tuple[float, float] | None = None  # (host time, tick) of the newest pressure frame
        self._kind = np.full(2048, -1, np.int8)
        self._cyl = np.zeros(2048, np.int16)
        for kind, table in ((KIND_FD, self.lay.fd_id), (KIND_REF, self.lay.ref_id), (KIND_CLASSIC, self.lay.classic_id)):
            for fid, cyl in table.items():
                self._kind[fid], self._cyl[fid] = kind, cyl
        self._kind[teeth_layout().frame_id] = KIND_TEETH2
        self.teeth2 = FreeEndTeethTrack(self.unwrapper, self._count, reorder_window)  # the free-end wheel's edges
        bits = self.lay.fd_flag_bits
        self._bit_fault = 1 << bits[FLAG_SENSOR_FAULT]
        self._bit_overrun = 1 << bits[FLAG_DAQ_OVERRUN]
        self._bit_restart = 1 << bits[FLAG_RESTART]

    def _track(self, cyl: int, kind: int = KIND_FD) -> _Track:
        tr = self.tracks.get((kind, cyl))
        if tr is None:
            tr = self.tracks[(kind, cyl)] = _Track(self.window)
        return tr

    # --- entry points --------------------------------------------------------------------------------------------
    def feed(self, messages: Iterable[can.Message]) -> list[StreamRecord]:
        """Decode a batch of python-can messages (any mix of ids; error and remote frames are counted)."""
        msgs: Sequence[can.Message] = messages if isinstance(messages, list) else list(messages)
        good = [m for m in msgs if not (m.is_error_frame or m.is_remote_frame)]
        if len(good) != len(msgs):
            self._count("can_error_or_remote_frame", len(msgs) - len(good))
        n = len(good)
        if n == 0:
            return []
        ids = np.fromiter([m.arbitration_id for m in good], np.int64, n)
        ext = np.fromiter([m.is_extended_id for m in good], bool, n)
        ts = np.fromiter([m.timestamp for m in good], np.float64, n)
        datas = [m.data for m in good]
        lengths = np.fromiter(map(len, datas), np.int64, n)
        if (lengths == 64).all():
            data = np.frombuffer(b"".join(datas), np.uint8).reshape(n, 64)
        else:
            data = np.frombuffer(b"".join(bytes(d[:64]).ljust(64, b"\0") for d in datas), np.uint8).reshape(n, 64)
        return self.feed_arrays(ts, ids, ext, lengths, data)

    def feed_arrays(self, ts: np.ndarray, ids: np.ndarray, extended: np.ndarray, lengths: np.ndarray,
                    data: np.ndarray) -> list[StreamRecord]:
        """Decode frames given as arrays: host time [s], identifier, extended flag, data length, data (n, >=8)
        uint8 zero-padded. Used by ``feed`` and by log replay (MDF4), which has the arrays already."""
        ids = np.asarray(ids, np.int64)
        extended = np.asarray(extended, bool)
        kind = np.full(ids.size, -1, np.int8)
        std = ~extended & (ids >= 0) & (ids < 2048)
        kind[std] = self._kind[ids[std]]
        if extended.any():
            pgn = j1939_pgn(ids[extended])
            is_load = pgn == PGN_LOAD
            if self.load_sa is not None:
                is_load &= (ids[extended] & 0xFF) == self.load_sa
            kind[extended] = np.where(is_load, KIND_LOAD, np.where(pgn == PGN_RESULTS, KIND_OURS, -1))
        if (kind == -1).any():
            self._count("unknown_can_id", int((kind == -1).sum()))
        need = np.where((kind == KIND_FD) | (kind == KIND_TEETH2), 64, 8)
        bad = (kind >= 0) & (kind != KIND_OURS) & ((lengths != need) | (need > data.shape[1]))
        if bad.any():
            self._count("wrong_dlc", int(bad.sum()))
            kind[bad] = -2
        fd_rows = np.flatnonzero(kind == KIND_FD)
        ref_rows = np.flatnonzero(kind == KIND_REF)
        cls_rows = np.flatnonzero(kind == KIND_CLASSIC)
        fd = _records(data, fd_rows, self.lay.fd_dtype)
        ref = _records(data, ref_rows, self.lay.ref_dtype)
        hint = np.concatenate([(fd["Flags"] & self._bit_restart) != 0, np.zeros(ref_rows.size, bool)])
        t0 = self._unwrap(fd_rows, fd["T0Ticks"], ref_rows, ref["T0Ticks"], hint)
        out: list[StreamRecord] = []
        out += self._fd(fd, t0[:fd_rows.size], self._cyl[ids[fd_rows]], ts[fd_rows])
        if ref_rows.size or cls_rows.size:
            out += self._classic(ids, ts, data, ref_rows, ref, t0[fd_rows.size:], cls_rows)
        for i in np.flatnonzero(kind == KIND_LOAD):
            out += self._load(float(ts[i]), bytes(data[i, :8]))
        teeth2 = np.flatnonzero(kind == KIND_TEETH2)
        if teeth2.size:
            out += self.teeth2.feed(data[teeth2])
        out.sort(key=_time_of)
        return out

    def flush(self) -> list[StreamRecord]:
        """Release frames held for reordering (bus idle, or end of a log)."""
        out: list[StreamRecord] = []
        for (_, cyl), tr in self.tracks.items():
            out += self._assemble_rows(cyl, [r for r, _ in tr.tracker.flush()])
        out += self.teeth2.flush()
        self._sync_counts()
        out.sort(key=_time_of)
        return out

    # --- pressure ------------------------------------------------------------------------------------------------
    def _unwrap(self, rows_a: np.ndarray, raw_a: np.ndarray, rows_b: np.ndarray, raw_b: np.ndarray,
                hint: np.ndarray) -> np.ndarray:
        """Unwrap the timer values of two row sets together, in arrival order; returns them concatenated."""
        rows = np.concatenate([rows_a, rows_b])
        raw = np.concatenate([raw_a, raw_b]).astype(np.int64)
        order = np.argsort(rows, kind="stable")
        out = np.empty(rows.size, np.int64)
        out[order] = self.unwrapper.unwrap_many(raw[order], hint[order])
        return out

    def _fd(self, rec: np.ndarray, t0: np.ndarray, cyl: np.ndarray, ts: np.ndarray) -> list[StreamRecord]:
        if rec.size == 0:
            return []
        n = rec["NSamples"].astype(np.int64)
        period = rec["PeriodTicks"] * self.lay.fd_period_factor
        ok = (n >= 1) & (n <= FD_SAMPLES) & (period > 0)
        if not ok.all():
            self._count("bad_frame_header", int((~ok).sum()))
        rows = np.flatnonzero(ok)
        rows = rows[np.argsort(cyl[rows], kind="stable")]  # grouped by cylinder, each in arrival order
        scale = rec["Scale"][rows] * self.lay.fd_scale_factor
        cols = (rec["Seq"][rows].astype(np.int64), t0[rows], period[rows], n[rows], scale,
                rec["Flags"][rows].astype(np.int64), rec["samples"][rows], ts[rows])
        return self._grouped(cyl[rows], cols, KIND_FD)

    def _grouped(self, cyl: np.ndarray, cols: tuple[np.ndarray, ...], kind: int) -> list[StreamRecord]:
        """Frames grouped by cylinder (ascending, each group in arrival order) -> blocks, cylinder by cylinder.

        A group that simply continues its counter (the common case) is assembled with the other such groups in one
        vectorised pass: a decoder's cost per frame was mostly numpy's per-call overhead, paid once per cylinder
        and batch. A group with a gap, a reordering or a restart goes frame by frame through its reorder window."""
        seq, flags = cols[0], cols[5]
        starts = np.flatnonzero(np.r_[True, cyl[1:] != cyl[:-1]])
        ends = np.r_[starts[1:], seq.size]
        continues = np.ones(seq.size, bool)
        continues[1:] = np.diff(seq) % 65536 == 1
        continues[starts] = True
        continues &= (flags & self._bit_restart) == 0
        simple = np.logical_and.reduceat(continues, starts)
        fast = np.zeros(seq.size, bool)
        slow: dict[int, list[StreamRecord]] = {}
        for a, b, plain in zip(starts.tolist(), ends.tolist(), simple.tolist(), strict=True):
            c = int(cyl[a])
            tr = self._track(c, kind)
            if plain and tr.tracker.advance(int(seq[a]), b - a):
                fast[a:b] = True
            else:
                slow[c] = self._reordered(c, tr, tuple(col[a:b] for col in cols))
        out = self._assemble(cyl[fast], *(col[fast] for col in cols)) if fast.any() else []
        if slow:  # put them in cylinder order, as the fast ones are (ties in time then keep one order)
            out = sorted(out + [r for blocks in slow.values() for r in blocks], key=_cylinder_of)
        return out

    def _reordered(self, cyl: int, tr: _Track, cols: tuple[np.ndarray, ...]) -> list[StreamRecord]:
        seq, flags = cols[0], cols[5]
        released: list[Row] = []
        for k in range(seq.size):
            if flags[k] & self._bit_restart:
                self._count("daq_restart", 1)
                released += [r for r, _ in tr.tracker.reset(start=int(seq[k]))]
            row = tuple(col[k] for col in cols)
            released += [r for r, _ in tr.tracker.push(int(seq[k]), row)]  # type: ignore[arg-type]
        self._sync_counts()
        return self._assemble_rows(cyl, released)

    def _assemble_rows(self, cyl: int, rows: list[Row]) -> list[StreamRecord]:
        if not rows:
            return []
        cols = [np.array([r[j] for r in rows]) for j in range(6)]
        samples = np.stack([r[6] for r in rows])
        ts = np.array([r[7] for r in rows])
        return self._assemble(np.full(len(rows), cyl), *cols, samples, ts)

    def _assemble(self, cyl: np.ndarray, seq: np.ndarray, t0: np.ndarray, period: np.ndarray, n: np.ndarray,
                  scale: np.ndarray, flags: np.ndarray, samples: np.ndarray, ts: np.ndarray) -> list[StreamRecord]:
        """Frames in order within each cylinder (rows grouped by cylinder) -> one block per continuous run."""
        end = t0 + n * period
        start_break = np.ones(seq.size, bool)
        same_cyl = cyl[1:] == cyl[:-1]
        seq_next = (seq[1:] - seq[:-1]) % 65536 == 1
        time_next = np.abs(t0[1:] - end[:-1]) <= self.tol
        start_break[1:] = ~(same_cyl & seq_next & time_next & (period[1:] == period[:-1]))
        overrun = (flags & self._bit_overrun) != 0
        start_break |= overrun
        # and every MAX_BLOCK_S within a run: the record merge and the replay log key a block by its last sample,
        # so a long block holds its first samples back until the teeth have gone on past them; past the cycle
        # assembler's pressure wait (0.5 s) their cycles are lost as pressure_missing. A reader starved for a
        # moment drains that much at once (tests/drivers/test_can_block_span.py)
        run_t0 = t0[np.flatnonzero(start_break)][np.cumsum(start_break) - 1]
        piece = (t0 - run_t0) // (MAX_BLOCK_S * self.tick_hz)
        start_break[1:] |= piece[1:] != piece[:-1]
        gaps = int((same_cyl & seq_next & ~time_next).sum())
        if gaps:
            self._count("time_gap_in_sequence", gaps)
        if overrun.any():
            self._count("daq_overrun", int(overrun.sum()))
        values = samples.astype(np.float64) * scale[:, None]
        width = samples.shape[1]
        valid = np.arange(width) < n[:, None]
        sat, inv = samples == RAW_SATURATED, samples == RAW_INVALID
        fault = (flags & self._bit_fault) != 0
        if sat.any() or inv.any() or fault.any():
            inv |= fault[:, None]
            values[sat | inv] = np.nan
            for reason, mask in (("sample_saturated", sat & valid & ~inv), ("sample_invalid", inv & valid)):
                if mask.any():
                    self._count(reason, int(mask.sum()))
        full = bool((n == width).all())
        starts = np.flatnonzero(start_break).tolist() + [seq.size]
        out: list[StreamRecord] = []
        for a, b in itertools.pairwise(starts):
            vals = values[a:b].ravel() if full else values[a:b][valid[a:b]]
            out.append(PressureBlock(cylinder=int(cyl[a]), t0_ticks=int(t0[a]), period_ticks=float(period[a]), values=vals))
        k = int(np.argmax(ts))
        self._clock = (float(ts[k]), float(end[k]))
        return out

    def _classic(self, ids: np.ndarray, ts: np.ndarray, data: np.ndarray, ref_rows: np.ndarray, ref: np.ndarray,
                 ref_t0: np.ndarray, cls_rows: np.ndarray) -> list[StreamRecord]:
        """Classic frames: time each data frame from its cylinder's latest reference (in this batch or kept from
        an earlier one), then assemble like CAN FD."""
        cls = _records(data, cls_rows, self.lay.classic_dtype)
        good_ref = ref["PeriodTicks"] > 0
        if not good_ref.all():
            self._count("bad_frame_header", int((~good_ref).sum()))
        ref_cyl = self._cyl[ids[ref_rows]]
        cls_cyl = self._cyl[ids[cls_rows]]
        groups: list[tuple[np.ndarray, tuple[np.ndarray, ...]]] = []  # per cylinder, ascending: one _grouped call
        for c in np.unique(np.concatenate([ref_cyl, cls_cyl])):
            tr = self._track(int(c), KIND_CLASSIC)
            r = np.flatnonzero((ref_cyl == c) & good_ref)
            d = np.flatnonzero(cls_cyl == c)
            k = np.searchsorted(ref_rows[r], cls_rows[d]) - 1  # latest reference of this batch before each frame
            in_batch = k >= 0
            kk = np.maximum(k, 0)
            prev = tr.ref or (0, 0, 0, -np.inf)
            r_seq = np.where(in_batch, ref["Seq"][r][kk] if r.size else 0, prev[0]).astype(np.int64)
            r_t0 = np.where(in_batch, ref_t0[r][kk] if r.size else 0, prev[1]).astype(np.int64)
            r_per = np.where(in_batch, ref["PeriodTicks"][r][kk] if r.size else 0, prev[2]).astype(np.int64)
            r_ts = np.where(in_batch, ts[ref_rows[r]][kk] if r.size else 0.0, prev[3])
            if r.size:
                j = r[-1]
                tr.ref = (int(ref["Seq"][j]), int(ref_t0[j]), int(ref["PeriodTicks"][j]), float(ts[ref_rows[j]]))
            if d.size == 0:
                continue
            seq = cls["Seq"][d].astype(np.int64)
            dist = (seq - r_seq) % 65536
            none = ~in_batch & (prev[2] == 0)
            stale = ~none & (ts[cls_rows[d]] - r_ts > self.ref_timeout_s)
            before = ~none & ~stale & (dist >= 32768)
            for reason, mask in (("no_time_reference", none), ("stale_time_reference", stale),
                                 ("before_time_reference", before)):
                if mask.any():
                    self._count(reason, int(mask.sum()))
            ok = ~(none | stale | before)
            if not ok.any():
                continue
            n = int(ok.sum())
            cols = (seq[ok], r_t0[ok] + dist[ok] * CLASSIC_SAMPLES * r_per[ok], r_per[ok].astype(np.float64),
                    np.full(n, CLASSIC_SAMPLES), np.full(n, self.lay.classic_factor), np.zeros(n, np.int64),
                    cls["samples"][d][ok], ts[cls_rows[d]][ok])
            groups.append((np.full(n, c), cols))
        if not groups:
            return []
        return self._grouped(np.concatenate([g[0] for g in groups]),
                             tuple(np.concatenate(col) for col in zip(*(g[1] for g in groups), strict=True)),
                             KIND_CLASSIC)

    # --- load ----------------------------------------------------------------------------------------------------
    def _load(self, t_host: float, payload: bytes) -> list[StreamRecord]:
        msg = self.lay.load
        raw = msg.decode(payload, decode_choices=False, scaling=False)
        released = self._load_seq.push(int(raw["Counter"]), 0)
        self._sync_counts(prefix="load_")
        if not released:
            return []
        if self._clock is None:
            self._count("load_without_time_reference", 1)
            return []
        power, why_p = j1939_value(msg, "RealPower", raw["RealPower"])
        torque, why_t = j1939_value(msg, "ShaftTorque", raw["ShaftTorque"])
        for why in (why_p, why_t):
            if why is not None:
                self._count(f"load_value_{why}", 1)
        tick = self._clock[1] + (t_host - self._clock[0]) * self.tick_hz
        return [LoadSample(ticks=round(tick), torque=torque, power=power)]

    def _sync_counts(self, prefix: str = "") -> None:
        trackers = [self._load_seq] if prefix else [t.tracker for t in self.tracks.values()]
        for tracker in trackers:
            for reason, k in tracker.counts.items():
                self._count(prefix + reason, k)
            tracker.counts.clear()


def _records(data: np.ndarray, rows: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Rows of the byte matrix viewed as structured records of ``dtype`` (a copy, contiguous)."""
    if rows.size == 0:
        return np.zeros(0, dtype)
    return np.ascontiguousarray(data[rows, :dtype.itemsize]).view(dtype).ravel()


def _cylinder_of(rec: StreamRecord) -> int:
    return rec.cylinder  # type: ignore[union-attr]  (only PressureBlocks are grouped)


def _time_of(rec: StreamRecord) -> float:
    if isinstance(rec, PressureBlock):
        return float(rec.t0_ticks)
    if isinstance(rec, LoadSample):
        return float(rec.ticks)
    if isinstance(rec, FreeEndToothBatch):
        return float(rec.ticks[0])
    return math.inf
