"""Stream records -> what the acquisition hardware would put on the wires, and a player that puts it there.

No physics: the simulator (or a recorded log) says what the sensors saw; this module only does what the tooth board
(docs/protocols.md §2), the pressure DAQ (§3.2) and the genset controller (§3.5) would do with it, using the
project's encoders (``serial_codec.Encoder``, ``can_encoder.PressureEncoder``, ``can_codec.encode_load``).

    events = wire_events(records, info)        # WireEvent(tick, channel, payload) in send order
    received = received_records(events, info)  # what a receiver decodes from exactly these bytes and frames
    player = WirePlayer(events, write_serial=port.write, bus=bus, tick_hz=info.tick_hz, speed=1.0)
    player.start(); ...; player.join()

Send times (``tick``, acquisition-timer ticks) follow the firmware rules: a TEETH frame closes at 32 edges, when a
delta would not fit 16 bits, or 2 ms (timer) after its first edge; a CAM frame per edge; a HEARTBEAT every 100 ms; an
INFO every second (the board was already running when the host connected: no BOOT flag). A CAN FD pressure frame is
sent when its 25 sample slots are over (T0 + n * period); a GensetLoad frame at its reading's tick.

Host clock. CAN load frames carry no timer value; the receiver places them through the host receive time of the
latest pressure frame (drivers/can_decoder.py). Each CAN message therefore gets ``timestamp = tick / tick_hz``, a
host clock that runs with the acquisition timer. Sent on a python-can virtual bus opened with
``preserve_timestamps=True`` the receiver sees exactly these times, so a load frame lands on its own tick and a live
run is reproducible; on real hardware the bus latency (about 1 ms) moves it instead, as the protocol states.
CAN pressure travels as CAN FD only (the classic-CAN variant is not generated here).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import can
import numpy as np
from frictionwatch.core.types import (
    AcquisitionInfo,
    CamBatch,
    FreeEndToothBatch,
    LoadSample,
    PressureBlock,
    PressureFrame,
    StreamRecord,
    ToothBatch,
)
from frictionwatch.drivers.assembly.pressure_ring import frame_blocks
from frictionwatch.drivers.can.codec import FD_SAMPLES, SA_GENSET, encode_load
from frictionwatch.drivers.can.decoder import CanDecoder
from frictionwatch.drivers.can.encoder import PressureEncoder
from frictionwatch.drivers.logs.mcap_schema import last_tick
from frictionwatch.drivers.serial.codec import CamFrame, Decoder, Encoder, Teeth2Frame, TeethFrame
from frictionwatch.drivers.timebase import TimerUnwrapper

log = logging.getLogger(__name__)

SERIAL, CAN = "serial", "can"
FRAME_SPAN_S = 0.002  # docs/protocols.md §2.6 rule 1
HEARTBEAT_S = 0.1  # rule 2
INFO_EVERY_S = 1.0  # rule 3
_RANK = {ToothBatch: 0, CamBatch: 1, PressureBlock: 2, PressureFrame: 2, LoadSample: 3, FreeEndToothBatch: 4}


@dataclass(frozen=True)
class WireEvent:
    """One transmission: ``payload`` (serial bytes or a ``can.Message``) sent on ``channel`` at timer ``tick``."""

    tick: float
    channel: str  # SERIAL or CAN
    payload: bytes | can.Message


def _wrapped_deg(deg: float) -> float:
    """An angle of the 720 deg cycle in the i16 range of the INFO frame (0.01 deg units): -360 <= a < 360."""
    return (deg + 360.0) % 720.0 - 360.0


def _edge_groups(ticks: np.ndarray, max_edges: int, span: float) -> list[tuple[float, np.ndarray]]:
    """Edges cut into TEETH frames by the firmware rules; (send tick, edges) per frame."""
    out: list[tuple[float, np.ndarray]] = []
    i, n = 0, ticks.size
    while i < n:
        first = ticks[i]
        j = i + 1
        while j < n and j - i < max_edges and ticks[j] - first <= span and ticks[j] - ticks[j - 1] <= 0xFFFF:
            j += 1
        if j - i == max_edges:  # full: out with its last edge
            send = float(ticks[j - 1])
        elif j < n and ticks[j] - ticks[j - 1] > 0xFFFF and ticks[j] - first <= span:  # the next delta won't fit
            send = float(ticks[j])
        else:  # the 2 ms timer
            send = float(first) + span
        out.append((send, ticks[i:j]))
        i = j
    return out


def serial_events(records: Iterable[StreamRecord], info: AcquisitionInfo, *, encoder: Encoder | None = None,
                  max_edges: int = 32, frame_span_s: float = FRAME_SPAN_S, heartbeat_s: float = HEARTBEAT_S,
                  info_every_s: float = INFO_EVERY_S) -> list[WireEvent]:
    """The tooth board's serial output for the ToothBatch / CamBatch / FreeEndToothBatch records (others are ignored;
    the second wheel's edges go out as TEETH2 frames and its description in the INFO frame, when ``info`` has one).

    Frames are numbered (SEQ) in send order by ``encoder`` (a fresh one by default; pass one to continue a link).
    """
    enc = encoder or Encoder(max_edges=max_edges)
    records = list(records)
    teeth = [r.ticks for r in records if isinstance(r, ToothBatch)]
    cams = [r.ticks for r in records if isinstance(r, CamBatch)]
    teeth2 = [r.ticks for r in records if isinstance(r, FreeEndToothBatch)]
    t = np.concatenate(teeth).astype(np.int64) if teeth else np.empty(0, np.int64)
    c = np.concatenate(cams).astype(np.int64) if cams else np.empty(0, np.int64)
    t2 = np.concatenate(teeth2).astype(np.int64) if teeth2 else np.empty(0, np.int64)
    if t.size == 0 and c.size == 0 and t2.size == 0:
        return []
    hz = info.tick_hz
    plan: list[tuple[float, int, Callable[[], bytes]]] = []  # (send tick, order on ties, encoder call)
    for send, edges in _edge_groups(t, max_edges, frame_span_s * hz):
        plan.append((send, 1, lambda e=edges: enc.teeth(e)))
    for tc in c:
        plan.append((float(tc), 2, lambda tc=tc: enc.cam([tc])))
    for send, edges in _edge_groups(t2, max_edges, frame_span_s * hz):
        plan.append((send, 4, lambda e=edges: enc.teeth2(e)))
    start = float(min(t[:1].tolist() + c[:1].tolist() + t2[:1].tolist()))
    w2 = info.second_wheel
    wheel2 = None if w2 is None else (w2.teeth, w2.missing, _wrapped_deg(w2.first_tooth_deg))
    end = max(p[0] for p in plan)
    for tick in np.arange(start, end + 1.0, heartbeat_s * hz):
        plan.append((float(tick), 3, lambda tick=tick: enc.heartbeat(int(tick))))
    for tick in np.arange(start, end + 1.0, info_every_s * hz):
        plan.append((float(tick), 0, lambda: enc.info(hz, info.wheel_teeth, info.wheel_missing,
                                                      _wrapped_deg(info.first_tooth_deg),
                                                      None if info.cam_deg is None else _wrapped_deg(info.cam_deg),
                                                      second_wheel=wheel2)))
    plan.sort(key=lambda p: (p[0], p[1]))
    return [WireEvent(tick, SERIAL, make()) for tick, _, make in plan]  # SEQ assigned here, in send order


def can_events(records: Iterable[StreamRecord], info: AcquisitionInfo, *, encoder: PressureEncoder | None = None,
               load_source_address: int = SA_GENSET, load_counter: int = 0) -> list[WireEvent]:
    """The pressure DAQ's CAN FD frames and the genset controller's GensetLoad frames, in send order."""
    enc = encoder or PressureEncoder(fd=True)
    if not enc.fd:
        raise ValueError("the bridge generates CAN FD pressure frames only (PressureEncoder(fd=True))")
    hz = info.tick_hz
    out: list[tuple[float, int, can.Message]] = []
    counter = load_counter
    for rec in records:
        # a CAN pressure frame carries one cylinder: a PressureFrame goes out as its rows, cylinder by cylinder
        for r in frame_blocks(rec) if isinstance(rec, PressureFrame) else (rec,):
            if not isinstance(r, PressureBlock):
                continue
            n = len(r.values)
            msgs = enc.block(r.cylinder, r.t0_ticks, r.period_ticks, r.values)
            for i, msg in enumerate(msgs):
                end = float(r.t0_ticks) + min((i + 1) * FD_SAMPLES, n) * float(r.period_ticks)
                msg.timestamp = end / hz
                out.append((end, 0, msg))
        if isinstance(rec, LoadSample):
            msg = encode_load(rec.power, rec.torque, counter, load_source_address)
            counter += 1
            msg.timestamp = rec.ticks / hz
            out.append((float(rec.ticks), 1, msg))
    out.sort(key=lambda e: (e[0], e[1]))  # stable: cylinders keep their order on equal ticks
    return [WireEvent(tick, CAN, msg) for tick, _, msg in out]


def wire_events(records: Sequence[StreamRecord], info: AcquisitionInfo, *, max_edges: int = 32,
                frame_span_s: float = FRAME_SPAN_S, heartbeat_s: float = HEARTBEAT_S) -> list[WireEvent]:
    """Serial and CAN events of a record stream, merged in send order (serial first on equal ticks)."""
    events = serial_events(records, info, max_edges=max_edges, frame_span_s=frame_span_s, heartbeat_s=heartbeat_s)
    events += can_events(records, info)
    order = sorted(range(len(events)), key=lambda i: (events[i].tick, events[i].channel != SERIAL, i))
    return [events[i] for i in order]


def received_records(events: Iterable[WireEvent], info: AcquisitionInfo,
                     damage: Counter[str] | None = None) -> list[StreamRecord]:
    """What the project's decoders deliver from exactly these events (no transport), in the replay log's order
    (tick of each record's last element; ties: teeth, cam, pressure, load).

    This is the wire's view of the session: tooth and cam ticks unchanged, pressure quantised to the CAN FD int16
    counts of each frame's scale, load to GensetLoad's resolution (1 W, 2 N m) at its own tick. What the decoders
    counted (nothing, for events made here) is added to ``damage`` if given.
    """
    unwrapper = TimerUnwrapper()
    serial = Decoder(unwrapper=unwrapper)
    bus = CanDecoder(unwrapper=unwrapper, tick_hz=info.tick_hz)
    out: list[StreamRecord] = []
    batch: list[can.Message] = []

    def teeth_and_cams(frames: list) -> list[StreamRecord]:
        kinds = {TeethFrame: ToothBatch, CamFrame: CamBatch, Teeth2Frame: FreeEndToothBatch}
        return [kinds[type(f)](f.ticks) for f in frames if type(f) in kinds]

    for ev in events:
        if ev.channel == CAN:
            batch.append(ev.payload)  # type: ignore[arg-type]
            continue
        if batch:
            out += bus.feed(batch)
            batch = []
        out += teeth_and_cams(serial.feed(ev.payload))  # type: ignore[arg-type]
    if batch:
        out += bus.feed(batch)
    out += bus.flush() + teeth_and_cams(serial.flush())
    counted = serial.damage + bus.damage
    if damage is not None:
        damage.update(counted)
    if counted:
        log.warning("received_records: the decoders counted %s", dict(counted))
    return sorted(out, key=lambda r: (last_tick(r), _RANK[type(r)]))  # the simulator's and the log's order


class WirePlayer:
    """Plays wire events from a thread: serial payloads to ``write_serial``, CAN messages to ``bus.send``.

    Parameters
    ----------
    events : WireEvent in send order.
    write_serial : callable taking bytes (e.g. ``lambda b: os.write(master_fd, b)``); may block (back-pressure).
    bus : python-can bus to send the CAN events on (a virtual bus with ``preserve_timestamps=True`` keeps the
        host-clock timestamps, see the module docstring); None if there are no CAN events.
    tick_hz : acquisition timer clock [Hz] (pacing only).
    speed : replay rate relative to real time; None = as fast as the sinks take it.

    ``error`` holds the exception that ended the thread early (a sink that failed), else None.
    """

    def __init__(self, events: Sequence[WireEvent], write_serial: Callable[[bytes], object] | None,
                 bus: can.BusABC | None, *, tick_hz: float, speed: float | None = None,
                 name: str = "wire-player") -> None:
        if speed is not None and not speed > 0:
            raise ValueError(f"speed must be > 0 or None, got {speed!r}")
        self.events, self.write_serial, self.bus = list(events), write_serial, bus
        self.tick_hz, self.speed = tick_hz, speed
        self.sent = 0
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> WirePlayer:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the end of the events; True if the thread has ended."""
        self._thread.join(timeout)
        return not self._thread.is_alive()

    @property
    def done(self) -> bool:
        return not self._thread.is_alive()

    def _run(self) -> None:
        if not self.events:
            return
        wall0, tick0 = time.monotonic(), self.events[0].tick
        try:
            for ev in self.events:
                if self._stop.is_set():
                    return
                if self.speed is not None:
                    wait = (ev.tick - tick0) / self.tick_hz / self.speed - (time.monotonic() - wall0)
                    if wait > 0 and self._stop.wait(wait):
                        return
                if ev.channel == SERIAL:
                    if self.write_serial is not None:
                        self.write_serial(ev.payload)  # type: ignore[arg-type]
                elif self.bus is not None:
                    self.bus.send(ev.payload)  # type: ignore[arg-type]
                self.sent += 1
        except Exception as exc:  # noqa: BLE001 - reported to the owner through ``error``
            self.error = exc
            log.warning("wire player stopped: %s", exc)
