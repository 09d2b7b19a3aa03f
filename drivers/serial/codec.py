"""The frictionwatch serial framing (docs/protocols.md §2) on bytes alone: encoder and a resyncing decoder.

Frame (all fields little-endian)::

    A5 5A | TYPE u8 | LEN u8 | SEQ u16 | FLAGS u8 | PAYLOAD[LEN] | CRC u16
    CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0; check("123456789") = 0x29B1)
    over TYPE .. end of PAYLOAD.

``Decoder.feed(bytes) -> list[frame]`` is pure (no I/O, no clock): it finds frames after garbage (resync one byte
past a bad sync), checks the CRC, puts frames in SEQ order (drops by gaps, duplicates, late frames: counted), and
unwraps the board's 32-bit timer into int64 ticks. Every skipped piece of input goes to ``count(reason, n)``.
"""

from __future__ import annotations

import binascii
import struct
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
from frictionwatch.drivers.sequence import SequenceTracker
from frictionwatch.drivers.timebase import TimerUnwrapper

SYNC = b"\xa5\x5a"
HEADER = struct.Struct("<2sBBHB")  # sync, type, len, seq, flags
HEADER_SIZE = HEADER.size  # 7
OVERHEAD = HEADER_SIZE + 2  # header + CRC
MAX_PAYLOAD = 255
MAX_EDGES = 1 + (254 - 4) // 2  # 126 edges: base + 125 deltas in a 254-byte payload

TYPE_TEETH, TYPE_CAM, TYPE_HEARTBEAT, TYPE_INFO, TYPE_TEETH2 = 0x01, 0x02, 0x03, 0x04, 0x05
FLAG_OVERFLOW, FLAG_SENSOR_FAULT, FLAG_BOOT = 0x01, 0x02, 0x04
_U32 = struct.Struct("<I")
INFO = struct.Struct("<IHBBhhH")  # tick_hz, teeth, missing, reserved, first_tooth_cdeg, cam_cdeg, firmware
NO_CAM = 0x7FFF
INFO_WHEEL2 = struct.Struct("<HBBh")  # INFO bytes 14..19 (optional): teeth2 (0 = none), missing2, reserved, first2_cdeg


def crc16_ccitt_false(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (binascii.crc_hqx is this CRC when started at 0xFFFF)."""
    return binascii.crc_hqx(data, 0xFFFF)


# --- frames the decoder returns ---------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class TeethFrame:
    """Crank-wheel edges, ``ticks`` int64 unwrapped, strictly increasing across all TeethFrames of a decoder."""

    seq: int
    flags: int
    ticks: np.ndarray


@dataclass(frozen=True, slots=True)
class Teeth2Frame:
    """The second (free-end) wheel's edges, int64 unwrapped ticks on the same timer, strictly increasing across all
    Teeth2Frames of a decoder."""

    seq: int
    flags: int
    ticks: np.ndarray


@dataclass(frozen=True, slots=True)
class CamFrame:
    """Cam / phase edges, int64 unwrapped ticks."""

    seq: int
    flags: int
    ticks: np.ndarray


@dataclass(frozen=True, slots=True)
class HeartbeatFrame:
    """The board's timer when the frame was built (keeps the unwrapping valid while no edges come)."""

    seq: int
    flags: int
    tick: int


@dataclass(frozen=True, slots=True)
class InfoFrame:
    """What the board states about its acquisition (docs/protocols.md §2.4)."""

    seq: int
    flags: int
    tick_hz: float
    wheel_teeth: int
    wheel_missing: int
    first_tooth_deg: float
    cam_deg: float | None
    firmware: int
    second_wheel: tuple[int, int, float] | None = None  # (teeth, missing, first_tooth_deg) of the free-end wheel


Frame = TeethFrame | CamFrame | HeartbeatFrame | InfoFrame | Teeth2Frame


# --- encoder ----------------------------------------------------------------------------------------------------
def encode_frame(ftype: int, seq: int, flags: int, payload: bytes) -> bytes:
    """One frame around ``payload`` (raises ValueError if it is longer than 255 bytes)."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes; at most {MAX_PAYLOAD}")
    head = HEADER.pack(SYNC, ftype & 0xFF, len(payload), seq & 0xFFFF, flags & 0xFF)
    crc = crc16_ccitt_false(head[2:] + payload)
    return head + payload + struct.pack("<H", crc)


def _edges_payload(ticks: Iterable[int]) -> bytes:
    t = np.asarray(ticks, dtype=np.int64).ravel()
    if not 1 <= t.size <= MAX_EDGES:
        raise ValueError(f"a frame carries 1..{MAX_EDGES} edges, got {t.size}")
    deltas = np.diff(t)
    if deltas.size and (deltas.min() < 1 or deltas.max() > 0xFFFF):
        raise ValueError("edge deltas must be 1..65535 ticks; start a new frame (Encoder does this)")
    return struct.pack("<I", int(t[0]) & 0xFFFFFFFF) + deltas.astype("<u2").tobytes()


def encode_teeth(seq: int, ticks: Iterable[int], flags: int = 0) -> bytes:
    """A TEETH frame: ``ticks`` absolute timer values (taken mod 2**32), strictly increasing, deltas <= 65535."""
    return encode_frame(TYPE_TEETH, seq, flags, _edges_payload(ticks))


def encode_cam(seq: int, ticks: Iterable[int], flags: int = 0) -> bytes:
    """A CAM frame (same payload as TEETH)."""
    return encode_frame(TYPE_CAM, seq, flags, _edges_payload(ticks))


def encode_teeth2(seq: int, ticks: Iterable[int], flags: int = 0) -> bytes:
    """A TEETH2 frame: the second wheel's edges (same payload as TEETH)."""
    return encode_frame(TYPE_TEETH2, seq, flags, _edges_payload(ticks))


def encode_heartbeat(seq: int, timer: int, flags: int = 0) -> bytes:
    return encode_frame(TYPE_HEARTBEAT, seq, flags, struct.pack("<I", int(timer) & 0xFFFFFFFF))


def encode_info(seq: int, tick_hz: float, wheel_teeth: int, wheel_missing: int, first_tooth_deg: float,
                cam_deg: float | None = None, firmware: int = 0, flags: int = 0,
                second_wheel: tuple[int, int, float] | None = None) -> bytes:
    """An INFO frame; angles travel in 0.01 deg, ``cam_deg=None`` means no cam sensor; ``second_wheel`` = (teeth,
    missing, first_tooth_deg) adds the 6 bytes of the free-end wheel (LEN 20; without it LEN 14 as before)."""
    cam = NO_CAM if cam_deg is None else round(cam_deg * 100)
    payload = INFO.pack(round(tick_hz), wheel_teeth, wheel_missing, 0, round(first_tooth_deg * 100), cam, firmware)
    if second_wheel is not None:
        teeth2, missing2, first2 = second_wheel
        payload += INFO_WHEEL2.pack(teeth2, missing2, 0, round(first2 * 100))
    return encode_frame(TYPE_INFO, seq, flags, payload)


class Encoder:
    """Stateful encoder as the board firmware works: one SEQ per frame, edges split into frames when a frame is
    full (``max_edges``) or a delta does not fit 16 bits. Used by tests and by the simulator-to-serial bridge."""

    def __init__(self, seq: int = 0, max_edges: int = 32) -> None:
        if not 1 <= max_edges <= MAX_EDGES:
            raise ValueError(f"max_edges must be 1..{MAX_EDGES}")
        self.seq = seq & 0xFFFF
        self.max_edges = max_edges

    def _next(self) -> int:
        s = self.seq
        self.seq = (s + 1) & 0xFFFF
        return s

    def _edges(self, ftype: int, ticks: Iterable[int], flags: int) -> bytes:
        t = np.asarray(ticks, dtype=np.int64).ravel()
        if t.size == 0:
            return b""
        d = np.diff(t)
        if d.size and d.min() < 1:
            raise ValueError("edge ticks must be strictly increasing")
        cuts = np.flatnonzero(d > 0xFFFF) + 1  # a long delta starts a new frame
        out = []
        for run in np.split(t, cuts):
            for i in range(0, run.size, self.max_edges):
                out.append(encode_frame(ftype, self._next(), flags, _edges_payload(run[i:i + self.max_edges])))
        return b"".join(out)

    def teeth(self, ticks: Iterable[int], flags: int = 0) -> bytes:
        return self._edges(TYPE_TEETH, ticks, flags)

    def cam(self, ticks: Iterable[int], flags: int = 0) -> bytes:
        return self._edges(TYPE_CAM, ticks, flags)

    def teeth2(self, ticks: Iterable[int], flags: int = 0) -> bytes:
        return self._edges(TYPE_TEETH2, ticks, flags)

    def heartbeat(self, timer: int, flags: int = 0) -> bytes:
        return encode_heartbeat(self._next(), timer, flags)

    def info(self, tick_hz: float, wheel_teeth: int, wheel_missing: int, first_tooth_deg: float,
             cam_deg: float | None = None, firmware: int = 0, flags: int = 0,
             second_wheel: tuple[int, int, float] | None = None) -> bytes:
        return encode_info(self._next(), tick_hz, wheel_teeth, wheel_missing, first_tooth_deg, cam_deg, firmware,
                           flags, second_wheel)


# --- decoder ----------------------------------------------------------------------------------------------------
class Decoder:
    """Bytes in, frames out (see module docstring). ``reorder_window`` frames may be held to undo reordering
    (0 for a UART, which never reorders). Counted reasons go to ``count`` (default: ``self.damage``)."""

    def __init__(self, *, unwrapper: TimerUnwrapper | None = None, reorder_window: int = 0,
                 count: Callable[[str, int], None] | None = None) -> None:
        self.damage: Counter[str] = Counter()
        self._count = count or (lambda reason, n=1: self.damage.update({reason: n}))
        self.unwrapper = unwrapper or TimerUnwrapper()
        self.tracker: SequenceTracker[tuple[int, int, bytes]] = SequenceTracker(1 << 16, reorder_window)
        self._buf = bytearray()
        self._last_tooth: int | None = None
        self._last_cam: int | None = None
        self._last_tooth2: int | None = None
        self._restart_hint = False  # the sender restarted: its timer may have restarted too
        self._force_rebase = False
        self._last_boot: tuple[int, int, bytes] | None = None
        self.frames_ok = 0

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Decode what ``data`` completes; keeps an incomplete tail for the next call."""
        self._buf += data
        return self._release(self._scan(final=False))

    def flush(self) -> list[Frame]:
        """The link is idle or ended: skip incomplete frames, release held ones."""
        out = self._release(self._scan(final=True))
        return out + self._process(self.tracker.flush())

    def mark_timer_discontinuity(self) -> None:
        """The next timer value cannot be related to the last one (long outage): re-base instead of unwrapping."""
        self._force_rebase = True

    # bytes -> (type, seq, flags, payload) with CRC checked
    def _scan(self, final: bool) -> list[tuple[int, int, int, bytes]]:
        buf, n, pos, garbage = self._buf, len(self._buf), 0, 0
        raw: list[tuple[int, int, int, bytes]] = []
        while True:
            i = buf.find(SYNC, pos)
            if i < 0:
                keep = n - 1 if (n > pos and buf[-1] == SYNC[0] and not final) else n
                garbage += keep - pos
                pos = keep
                break
            garbage += i - pos
            end = i + OVERHEAD + (buf[i + 3] if i + 3 < n else MAX_PAYLOAD)
            if end > n:
                if not final:
                    pos = i
                    break
                self._count("truncated_frame", 1)
                garbage += 1
                pos = i + 1
                continue
            body = bytes(buf[i + 2:end - 2])
            if crc16_ccitt_false(body) != buf[end - 2] | (buf[end - 1] << 8):
                self._count("crc_error", 1)
                garbage += 1
                pos = i + 1
                continue
            raw.append((body[0], body[2] | (body[3] << 8), body[4], body[5:]))
            pos = end
        del buf[:pos]
        if garbage:
            self._count("garbage_bytes", garbage)
        return raw

    def _release(self, raw: list[tuple[int, int, int, bytes]]) -> list[Frame]:
        out: list[Frame] = []
        for ftype, seq, flags, payload in raw:
            if flags & FLAG_BOOT:
                if (seq, ftype, payload) == self._last_boot:  # the same BOOT frame again: not a new restart
                    self._count("duplicate_frame", 1)
                    continue
                self._last_boot = (seq, ftype, payload)
                out += self._process(self.tracker.reset(start=seq))
                self._count("board_restart", 1)
                self._restart_hint = True
            out += self._process(self.tracker.push(seq, (ftype, seq, flags, payload)))
        for reason, k in self.tracker.counts.items():
            self._count(reason, k)
        self.tracker.counts.clear()
        return out

    def _timer(self, raw: int) -> int:
        if self._force_rebase:
            self._force_rebase = self._restart_hint = False
            return self.unwrapper.rebase(raw)
        hint, self._restart_hint = self._restart_hint, False
        return self.unwrapper.unwrap(raw, restart_hint=hint)

    def _process(self, released: list[tuple[tuple[int, int, int, bytes], bool]]) -> list[Frame]:
        out: list[Frame] = []
        for (ftype, seq, flags, payload), restarted in released:
            if restarted:
                self._restart_hint = True
            if flags & FLAG_OVERFLOW:
                self._count("board_capture_overflow", 1)
            frame = self._decode_one(ftype, seq, flags, payload)
            if frame is not None:
                self.frames_ok += 1
                out.append(frame)
        return out

    def _decode_one(self, ftype: int, seq: int, flags: int, payload: bytes) -> Frame | None:
        n = len(payload)
        if ftype in (TYPE_TEETH, TYPE_CAM, TYPE_TEETH2):
            if n < 4 or n % 2:
                self._count("bad_length", 1)
                return None
            return self._edges(ftype, seq, flags, payload)
        if ftype == TYPE_HEARTBEAT:
            if n != 4:
                self._count("bad_length", 1)
                return None
            return HeartbeatFrame(seq, flags, self._timer(struct.unpack_from("<I", payload)[0]))
        if ftype == TYPE_INFO:
            if n < INFO.size:
                self._count("bad_length", 1)
                return None
            hz, teeth, missing, _, first, cam, fw = INFO.unpack_from(payload)
            if hz == 0 or teeth == 0 or missing >= teeth:
                self._count("bad_info_frame", 1)
                return None
            wheel2 = None
            if n >= INFO.size + INFO_WHEEL2.size:
                teeth2, missing2, _, first2 = INFO_WHEEL2.unpack_from(payload, INFO.size)
                if teeth2 and missing2 >= teeth2:
                    self._count("bad_info_frame", 1)
                    return None
                wheel2 = (teeth2, missing2, first2 / 100.0) if teeth2 else None
            return InfoFrame(seq, flags, float(hz), teeth, missing, first / 100.0,
                             None if cam == NO_CAM else cam / 100.0, fw, wheel2)
        self._count("unknown_frame_type", 1)
        return None

    def _edges(self, ftype: int, seq: int, flags: int, payload: bytes) -> Frame | None:
        base = _U32.unpack_from(payload)[0]
        start = self._timer(base)
        if len(payload) == 4:  # one edge: no numpy work beyond the result array
            ticks = np.array((start,), np.int64)
            ok = True
        else:
            deltas = np.frombuffer(payload, "<u2", offset=4)
            ticks = np.empty(deltas.size + 1, np.int64)
            ticks[0] = start
            np.cumsum(deltas, dtype=np.int64, out=ticks[1:])
            ticks[1:] += start
            self.unwrapper.unwrap((base + int(ticks[-1] - start)) & 0xFFFFFFFF)  # reference = newest edge
            ok = bool(deltas.all())
        if flags & FLAG_SENSOR_FAULT:
            self._count("sensor_fault_edges", ticks.size)
            return None
        last = {TYPE_TEETH: self._last_tooth, TYPE_CAM: self._last_cam, TYPE_TEETH2: self._last_tooth2}[ftype]
        if not ok or (last is not None and start <= last):
            keep = np.ones(ticks.size, bool)
            keep[1:] = np.diff(ticks) > 0
            if last is not None:
                keep &= ticks > last
            self._count("non_increasing_edge", int(ticks.size - keep.sum()))
            ticks = ticks[keep]
            if ticks.size == 0:
                return None
        if ftype == TYPE_TEETH:
            self._last_tooth = int(ticks[-1])
            return TeethFrame(seq, flags, ticks)
        if ftype == TYPE_TEETH2:
            self._last_tooth2 = int(ticks[-1])
            return Teeth2Frame(seq, flags, ticks)
        self._last_cam = int(ticks[-1])
        return CamFrame(seq, flags, ticks)
