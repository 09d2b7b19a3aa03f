"""Tooth and cam edges from the input-capture board over a serial port (``serial:/dev/ttyUSB0?baud=921600``).

The transport only moves bytes; framing lives in drivers/serial/codec.py. Any pyserial URL works as the target
(``loop://`` in tests, a pty, ``/dev/serial/by-id/...``). When the port vanishes (USB unplugged, pty closed) the
source counts ``port_lost``, logs it, and reopens it with exponential back-off (``reconnect`` counted); ``read``
never raises for bad bytes or a lost port, it returns what it has.

URL options: ``baud`` (921600), ``clock`` (name of the shared timer, "daq"), ``reorder`` (frames held to undo
reordering, 0), and, to state the acquisition instead of taking it from the board's INFO frame, ``tick_hz``,
``teeth``, ``missing``, ``first_tooth_deg``, ``cam_deg``.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np
import serial
from frictionwatch.core.types import AcquisitionInfo, CamBatch, FreeEndToothBatch, StreamRecord, ToothBatch, WheelInfo
from frictionwatch.drivers.backoff import Backoff, ReconnectingLink
from frictionwatch.drivers.serial.codec import CamFrame, Decoder, Frame, InfoFrame, Teeth2Frame, TeethFrame
from frictionwatch.drivers.source import Source
from frictionwatch.drivers.timebase import Clocks, TimerUnwrapper, shared_unwrapper

log = logging.getLogger(__name__)

PORT_ERRORS = (serial.SerialException, OSError, ValueError)


class SerialSource(ReconnectingLink, Source):
    """Stream of ToothBatch / CamBatch from a serial port speaking docs/protocols.md §2.

    Parameters
    ----------
    port_url : str
        Device path or pyserial URL.
    baud : int
        Line rate [bit/s]; ignored by ``loop://`` and ptys.
    info : AcquisitionInfo, optional
        Stated acquisition; if None it is taken from the board's INFO frame.
    unwrapper : TimerUnwrapper, optional
        Timer unwrapping shared with the other sources of the same board (default: ``shared_unwrapper("daq")``).
    idle_flush_s : float
        After this long without bytes, held frames are released and a partial frame is given up.
    """

    LINK_ERRORS = PORT_ERRORS

    def __init__(self, port_url: str, *, baud: int = 921600, info: AcquisitionInfo | None = None,
                 unwrapper: TimerUnwrapper | None = None, reorder_window: int = 0, idle_flush_s: float = 0.05,
                 backoff: Backoff | None = None) -> None:
        super().__init__()
        self.port_url = port_url
        self.baud = baud
        self.info = info
        self._stated_info = info is not None
        self.decoder = Decoder(unwrapper=unwrapper or shared_unwrapper("daq"), reorder_window=reorder_window,
                               count=self.count)
        self.idle_flush_s = idle_flush_s
        self.backoff = backoff or Backoff()
        self.port: Any = None
        self.reconnects = 0
        self._lost_at: float | None = None
        self._last_data = time.monotonic()
        self._open(first=True)

    @classmethod
    def from_url(cls, target: str, options: dict[str, str], clocks: Clocks | None = None) -> SerialSource:
        opts = dict(options)
        info = None
        if "tick_hz" in opts:
            cam = opts.pop("cam_deg", None)
            info = AcquisitionInfo(tick_hz=float(opts.pop("tick_hz")), wheel_teeth=int(opts.pop("teeth", "60")),
                                   wheel_missing=int(opts.pop("missing", "2")),
                                   first_tooth_deg=float(opts.pop("first_tooth_deg", "0")),
                                   cam_deg=None if cam is None else float(cam))
        baud = int(opts.pop("baud", "921600"))
        clock = opts.pop("clock", "daq")
        reorder = int(opts.pop("reorder", "0"))
        if opts:
            raise ValueError(f"unknown serial option(s) {sorted(opts)}; known: baud, clock, reorder, tick_hz, teeth, "
                             "missing, first_tooth_deg, cam_deg")
        return cls(target, baud=baud, info=info, unwrapper=shared_unwrapper(clock, clocks),
                   reorder_window=reorder)

    # --- port handling -------------------------------------------------------------------------------------------
    def _open(self, first: bool = False) -> bool:
        try:
            self.port = serial.serial_for_url(self.port_url, baudrate=self.baud, timeout=0)
        except PORT_ERRORS as exc:
            self.port = None
            delay = self.backoff.failed()
            if first:
                self._lost_at = time.monotonic()
                self.count("port_unavailable")
            log.debug("open %s failed (%s); next try in %.2f s", self.port_url, exc, delay)
            return False
        if not first or self._lost_at is not None:
            self.reconnects += 1
            self.count("reconnect")
            outage = time.monotonic() - (self._lost_at or time.monotonic())
            log.info("%s reopened after %.2f s, %d attempts", self.port_url, outage, self.backoff.attempts)
            self._check_outage(outage)
        self._lost_at = None
        self.backoff.reset()
        return True

    def _check_outage(self, outage_s: float) -> None:
        # past half the timer's wrap period, "nearest" unwrapping can pick the wrong epoch: re-base instead
        tick_hz = self.info.tick_hz if self.info else None
        if tick_hz and outage_s * tick_hz > 0.8 * (1 << 31):
            self.count("timer_epoch_unknown_after_outage")
            self.decoder.mark_timer_discontinuity()

    def _lose_link(self, exc: BaseException) -> None:
        log.warning("%s lost: %s", self.port_url, exc)
        self.count("port_lost")
        self._lost_at = time.monotonic()
        try:
            self.port.close()
        except PORT_ERRORS:
            pass
        self.port = None
        self.backoff.failed()

    # --- reading -------------------------------------------------------------------------------------------------
    def _read_chunk(self, wait: float) -> bytes:
        self.port.timeout = wait
        data = self.port.read(1)
        if data:
            waiting = self.port.in_waiting
            if waiting:
                data += self.port.read(waiting)
        return bytes(data)

    def _link_open(self) -> bool:
        return self.port is not None

    def _decode(self, chunk: bytes) -> list[StreamRecord]:
        return self._records(self.decoder.feed(chunk))

    def _decode_flush(self) -> list[StreamRecord]:
        return self._records(self.decoder.flush())

    def _records(self, frames: list[Frame]) -> list[StreamRecord]:
        out: list[StreamRecord] = []
        teeth: list[np.ndarray] = []
        for f in frames:
            if isinstance(f, TeethFrame):
                teeth.append(f.ticks)
                continue
            if teeth:
                out.append(ToothBatch(np.concatenate(teeth)))
                teeth = []
            if isinstance(f, CamFrame):
                out.append(CamBatch(f.ticks))
            elif isinstance(f, Teeth2Frame):
                out.append(FreeEndToothBatch(f.ticks))
            elif isinstance(f, InfoFrame):
                self._take_info(f)
        if teeth:
            out.append(ToothBatch(np.concatenate(teeth)))
        return out

    def _take_info(self, f: InfoFrame) -> None:
        info = AcquisitionInfo(tick_hz=f.tick_hz, wheel_teeth=f.wheel_teeth, wheel_missing=f.wheel_missing,
                               first_tooth_deg=f.first_tooth_deg, cam_deg=f.cam_deg,
                               second_wheel=None if f.second_wheel is None else WheelInfo(*f.second_wheel))
        if self._stated_info:
            if self.info is not None and (self.info.tick_hz, self.info.wheel_teeth, self.info.wheel_missing) != (
                    info.tick_hz, info.wheel_teeth, info.wheel_missing):
                self.count("board_info_differs_from_stated")
            return
        if self.info != info:
            log.info("%s: board states %s", self.port_url, info)
        self.info = info

    def _close_internal(self) -> None:
        if self.port is not None:
            try:
                self.port.close()
            except PORT_ERRORS:
                pass
            self.port = None
