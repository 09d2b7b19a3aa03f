"""Replay of CAN bus logs in ASAM MDF4 (asammdf), as common loggers (CSS CANedge, Vector) write them.

``read_can_frames`` reads the raw ``CAN_DataFrame`` channels of every channel group into plain arrays (no
per-frame Python objects). ``decode_signals`` decodes any DBC on them (J1939 messages matched by PGN, whatever
the priority and source address, as J1939 requires). ``Mdf4Source`` (``mdf4:log.MF4?speed=1``) feeds the frames
of a frictionwatch bus through the same decoder as the live ``CanSource`` and yields PressureBlock / LoadSample.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import can
import cantools
import numpy as np
from frictionwatch.core.types import StreamRecord
from frictionwatch.drivers.can.codec import j1939_pgn
from frictionwatch.drivers.can.decoder import CanDecoder
from frictionwatch.drivers.errors import CorruptLog, EndOfStream
from frictionwatch.drivers.source import Source
from frictionwatch.drivers.timebase import TimerUnwrapper

log = logging.getLogger(__name__)

FRAME = "CAN_DataFrame"


@dataclass(frozen=True)
class CanFrames:
    """Frames of a log, sorted by time: ``t`` [s, log clock], ``ids``, ``extended``, ``lengths`` [bytes],
    ``data`` (n, width) uint8 zero-padded, ``channel`` bus channel number."""

    t: np.ndarray
    ids: np.ndarray
    extended: np.ndarray
    lengths: np.ndarray
    data: np.ndarray
    channel: np.ndarray

    def __len__(self) -> int:
        return int(self.t.size)

    def slice(self, a: int, b: int) -> CanFrames:
        return CanFrames(self.t[a:b], self.ids[a:b], self.extended[a:b], self.lengths[a:b], self.data[a:b],
                         self.channel[a:b])


def _group_frames(mdf: object, index: int, names: set[str]) -> CanFrames:
    def get(name: str) -> tuple[np.ndarray, np.ndarray]:
        sig = mdf.get(f"{FRAME}.{name}", group=index)  # type: ignore[attr-defined]
        return np.asarray(sig.samples), np.asarray(sig.timestamps, dtype=np.float64)

    ids, t = get("ID")
    ide = get("IDE")[0].astype(bool)
    raw = get("DataBytes")[0]
    if raw.dtype == object:  # variable-length records: one bytes object per frame
        width = max(8, max((len(r) for r in raw), default=8))
        data = np.zeros((raw.size, width), np.uint8)
        for i, r in enumerate(raw):
            data[i, :len(r)] = np.frombuffer(bytes(r), np.uint8)
    else:
        data = np.ascontiguousarray(raw, dtype=np.uint8).reshape(ids.size, -1)
    if f"{FRAME}.DataLength" in names:
        lengths = get("DataLength")[0].astype(np.int64)
    else:  # older files: only the DLC code
        lengths = np.array([can.util.dlc2len(int(d)) for d in get("DLC")[0]], np.int64)
    if f"{FRAME}.BusChannel" in names:
        channel = get("BusChannel")[0].astype(np.int64)
    else:
        channel = np.zeros(ids.size, np.int64)
    return CanFrames(t, ids.astype(np.int64) & 0x1FFFFFFF, ide, lengths, data, channel)


def read_can_frames(path: str | Path) -> CanFrames:
    """All CAN data frames of an MDF4 bus log. Raises CorruptLog if asammdf cannot read the file."""
    from asammdf import MDF  # heavy import, only when a log is read

    try:
        mdf = MDF(str(path))
    except Exception as exc:  # asammdf raises many types (MdfException, struct.error, ValueError...)
        raise CorruptLog(f"{path}: not a readable MDF4 file ({exc})") from exc
    try:
        parts = []
        for i, group in enumerate(mdf.groups):
            names = {ch.name for ch in group.channels}
            if f"{FRAME}.ID" in names and f"{FRAME}.DataBytes" in names:
                parts.append(_group_frames(mdf, i, names))
    except Exception as exc:
        raise CorruptLog(f"{path}: damaged CAN records ({exc})") from exc
    finally:
        mdf.close()
    if not parts:
        return CanFrames(np.empty(0), np.empty(0, np.int64), np.empty(0, bool), np.empty(0, np.int64),
                         np.empty((0, 8), np.uint8), np.empty(0, np.int64))
    width = max(p.data.shape[1] for p in parts)
    data = np.concatenate([np.pad(p.data, ((0, 0), (0, width - p.data.shape[1]))) for p in parts])
    cols = [np.concatenate([getattr(p, f) for p in parts]) for f in ("t", "ids", "extended", "lengths", "channel")]
    order = np.argsort(cols[0], kind="stable")
    return CanFrames(cols[0][order], cols[1][order], cols[2][order], cols[3][order], data[order], cols[4][order])


def iter_messages(frames: CanFrames) -> Iterator[can.Message]:
    """The frames as python-can messages (for tools that want them; the decoders use the arrays)."""
    for i in range(len(frames)):
        n = int(frames.lengths[i])
        yield can.Message(timestamp=float(frames.t[i]), arbitration_id=int(frames.ids[i]),
                          is_extended_id=bool(frames.extended[i]), is_fd=n > 8, channel=int(frames.channel[i]),
                          data=bytes(frames.data[i, :n]))


def _rows_of(frames: CanFrames, message: cantools.database.can.Message) -> np.ndarray:
    if message.is_extended_frame and message.protocol == "j1939":
        sel = frames.extended & (j1939_pgn(frames.ids) == j1939_pgn(message.frame_id))
    else:
        sel = (frames.extended == message.is_extended_frame) & (frames.ids == message.frame_id)
    return np.flatnonzero(sel)


def decode_signals(frames: CanFrames, dbc: cantools.database.can.Database | str | Path,
                   names: Sequence[str] | None = None) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], dict[str, int]]:
    """Decode DBC signals from log frames.

    Returns ``({signal: (t [s], values)}, damage)``; frames too short for their message are skipped and counted
    under ``wrong_dlc``. ``names=None`` decodes every signal of every message found.
    """
    db = dbc if isinstance(dbc, cantools.database.can.Database) else cantools.database.load_file(str(dbc))
    out: dict[str, list[tuple[float, float]]] = {}
    damage: dict[str, int] = {}
    for message in db.messages:
        wanted = [s.name for s in message.signals if names is None or s.name in names]
        if not wanted:
            continue
        for i in _rows_of(frames, message):
            if frames.lengths[i] < message.length:
                damage["wrong_dlc"] = damage.get("wrong_dlc", 0) + 1
                continue
            values = message.decode(bytes(frames.data[i, :message.length]), decode_choices=False)
            for name in wanted:
                out.setdefault(name, []).append((float(frames.t[i]), float(values[name])))
    return {k: (np.array([a for a, _ in v]), np.array([b for _, b in v])) for k, v in out.items()}, damage


EEC1_PGN = 0xF004  # J1939 Electronic Engine Controller 1 (PGN 61444)
EEC1_RPM_PER_BIT = 0.125  # SPN 190 Engine Speed: bytes 4-5, little endian, 0.125 rpm/bit, 0..8031.875 rpm
J1939_NOT_VALID = 0xFB00  # 16-bit values from here up mean 'error' (0xFExx) or 'not available' (0xFFxx)


@dataclass(frozen=True)
class SpeedSeries:
    """J1939 engine speed (SPN 190) of a bus log: ``t`` [s, log clock], ``rpm``; ``sources`` the source addresses
    seen; ``invalid`` frames whose value was 'error' or 'not available', ``short`` frames under 5 data bytes."""

    t: np.ndarray
    rpm: np.ndarray
    sources: tuple[int, ...]
    invalid: int
    short: int


def j1939_engine_speed(frames: CanFrames, source: int | None = None) -> SpeedSeries:
    """EEC1 engine speed of every extended frame with PGN 61444 (any priority; ``source`` None: the most frequent
    source address, as a second ECU sending EEC1 would interleave another engine). No DBC needed: SPN 190's place
    and scale are fixed by SAE J1939-71."""
    sel = frames.extended & (j1939_pgn(frames.ids) == EEC1_PGN)
    addr = frames.ids[sel] & 0xFF
    sources = tuple(int(a) for a in np.unique(addr))
    if source is None and sources:
        values, counts = np.unique(addr, return_counts=True)
        source = int(values[np.argmax(counts)])
    sel[sel] = addr == source
    long_enough = frames.lengths[sel] >= 5
    rows = np.flatnonzero(sel)[long_enough]
    raw = frames.data[rows, 3].astype(np.int64) | (frames.data[rows, 4].astype(np.int64) << 8)
    ok = raw < J1939_NOT_VALID
    return SpeedSeries(frames.t[rows][ok], raw[ok] * EEC1_RPM_PER_BIT, sources, int(np.count_nonzero(~ok)),
                       int(np.count_nonzero(~long_enough)))


class Mdf4Source(Source):
    """Replay of a frictionwatch CAN log: PressureBlock / LoadSample, then EndOfStream.

    ``speed`` 0 replays as fast as possible, 1 in real time, N at N times real time.
    """

    def __init__(self, path: str | Path, *, speed: float = 0.0, chunk: int = 4096, tick_hz: float = 10e6,
                 unwrapper: TimerUnwrapper | None = None) -> None:
        super().__init__()
        if speed < 0:
            raise ValueError("speed must be >= 0 (0 = as fast as possible)")
        self.path = Path(path)
        self.frames = read_can_frames(self.path)
        self.speed = speed
        self.chunk = chunk
        # a replay has its own time line: by default it does not share the live timer's unwrapping
        self.decoder = CanDecoder(unwrapper=unwrapper or TimerUnwrapper(), tick_hz=tick_hz, count=self.count)
        self._pos = 0
        self._start: float | None = None
        self._done = False

    @classmethod
    def from_url(cls, target: str, options: dict[str, str], clocks: object = None) -> Mdf4Source:
        """``clocks`` is not used: a log file carries its own unwrapped timer."""
        opts = dict(options)
        speed = float(opts.pop("speed", "0"))
        tick_hz = float(opts.pop("tick_hz", "10e6"))
        if opts:
            raise ValueError(f"unknown mdf4 option(s) {sorted(opts)}; known: speed, tick_hz")
        return cls(target, speed=speed, tick_hz=tick_hz)

    def _read_internal(self, timeout: float | None) -> list[StreamRecord]:
        n = len(self.frames)
        if self._pos >= n:
            if not self._done:
                self._done = True
                out = self.decoder.flush()
                if out:
                    return out
            raise EndOfStream(f"{self.path}: end of log")
        end = min(n, self._pos + self.chunk)
        if self.speed > 0:
            now = time.monotonic()
            if self._start is None:
                self._start = now - (self.frames.t[self._pos] - self.frames.t[0]) / self.speed
            due = self._start + (self.frames.t[self._pos:end] - self.frames.t[0]) / self.speed
            end = self._pos + max(1, int(np.searchsorted(due, now, side="right")))
            wait = due[0] - now
            if wait > 0:
                if timeout is not None and wait > timeout:
                    time.sleep(timeout)
                    return []
                time.sleep(wait)
        part = self.frames.slice(self._pos, end)
        self._pos = end
        return self.decoder.feed_arrays(part.t, part.ids, part.extended, part.lengths, part.data)
