"""Cylinder pressure and generator load from a CAN / CAN FD bus (``can:socketcan/can0``, ``can:virtual/ch0``).

The transport only moves frames; decoding and reassembly live in drivers/can/decoder.py. ``read`` takes one
message (waiting up to the timeout), drains what else is queued (up to ``max_batch``) and decodes the batch at once.
When the bus goes away (interface down, adapter unplugged) the source counts ``bus_lost`` and reopens it with
exponential back-off (``reconnect``); bad frames are counted, never raised.

URL: ``can:<interface>/<channel>?fd=1&bitrate=500000&data_bitrate=5000000&tick_hz=10e6&clock=daq&reorder=4``.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import can
from frictionwatch.core.types import StreamRecord
from frictionwatch.drivers.backoff import Backoff, ReconnectingLink
from frictionwatch.drivers.can.decoder import CanDecoder
from frictionwatch.drivers.source import Source
from frictionwatch.drivers.timebase import Clocks, TimerUnwrapper, shared_unwrapper

log = logging.getLogger(__name__)

BUS_ERRORS = (can.CanError, OSError)


class CanSource(ReconnectingLink, Source):
    """Stream of PressureBlock / LoadSample from a python-can bus.

    Parameters
    ----------
    interface, channel : str
        python-can interface name and channel (``"socketcan", "vcan0"``; ``"virtual", "ch0"``).
    fd : bool
        Open the bus in CAN FD mode (needed for the 64-byte pressure frames).
    bus_kwargs : dict, optional
        Extra arguments for ``can.Bus`` (bitrate, data_bitrate, ...).
    tick_hz, reorder_window : see ``CanDecoder``.
    idle_flush_s : float
        After this long without frames, frames held for reordering are released.
    """

    LINK_ERRORS = BUS_ERRORS

    def __init__(self, interface: str, channel: str, *, fd: bool = True, bus_kwargs: dict[str, Any] | None = None,
                 tick_hz: float = 10e6, unwrapper: TimerUnwrapper | None = None, reorder_window: int = 4,
                 idle_flush_s: float = 0.02, max_batch: int = 4096, backoff: Backoff | None = None) -> None:
        super().__init__()
        self.interface, self.channel, self.fd = interface, channel, fd
        self.bus_kwargs = dict(bus_kwargs or {})
        self.decoder = CanDecoder(unwrapper=unwrapper or shared_unwrapper("daq"), tick_hz=tick_hz,
                                  reorder_window=reorder_window, count=self.count)
        self.idle_flush_s = idle_flush_s
        self.max_batch = max_batch
        self.backoff = backoff or Backoff()
        self.bus: can.BusABC | None = None
        self.reconnects = 0
        self._had_bus = False
        self._last_data = time.monotonic()
        self._open()

    @classmethod
    def from_url(cls, target: str, options: dict[str, str], clocks: Clocks | None = None) -> CanSource:
        interface, sep, channel = target.partition("/")
        if not sep or not interface or not channel:
            raise ValueError(f"expected can:<interface>/<channel>, e.g. can:socketcan/can0, got 'can:{target}'")
        opts = dict(options)
        fd = opts.pop("fd", "1") not in ("0", "false", "no")
        tick_hz = float(opts.pop("tick_hz", "10e6"))
        clock = opts.pop("clock", "daq")
        reorder = int(opts.pop("reorder", "4"))
        bus_kwargs: dict[str, Any] = {k: int(float(opts.pop(k))) for k in ("bitrate", "data_bitrate") if k in opts}
        if opts:
            raise ValueError(f"unknown can option(s) {sorted(opts)}; known: fd, bitrate, data_bitrate, tick_hz, "
                             "clock, reorder")
        return cls(interface, channel, fd=fd, bus_kwargs=bus_kwargs, tick_hz=tick_hz,
                   unwrapper=shared_unwrapper(clock, clocks), reorder_window=reorder)

    def _open(self) -> bool:
        try:
            self.bus = can.Bus(interface=self.interface, channel=self.channel, fd=self.fd, **self.bus_kwargs)
        except (*BUS_ERRORS, ValueError, ImportError) as exc:
            self.bus = None
            delay = self.backoff.failed()
            if not self._had_bus and self.backoff.attempts == 1:
                self.count("bus_unavailable")
            log.debug("open %s/%s failed (%s); next try in %.2f s", self.interface, self.channel, exc, delay)
            return False
        if self._had_bus:
            self.reconnects += 1
            self.count("reconnect")
            log.info("%s/%s reopened after %d attempts", self.interface, self.channel, self.backoff.attempts)
        self._had_bus = True
        self.backoff.reset()
        return True

    def _lose_link(self, exc: BaseException) -> None:
        log.warning("%s/%s lost: %s", self.interface, self.channel, exc)
        self.count("bus_lost")
        self._shutdown_bus()
        self.backoff.failed()

    def _shutdown_bus(self) -> None:
        if self.bus is not None:
            try:
                self.bus.shutdown()
            except BUS_ERRORS:
                pass
            self.bus = None

    # --- the ReconnectingLink hooks ----------------------------------------------------------------------------
    def _link_open(self) -> bool:
        return self.bus is not None

    def _decode(self, chunk: list[can.Message]) -> list[StreamRecord]:
        return self.decoder.feed(chunk)

    def _decode_flush(self) -> list[StreamRecord]:
        return self.decoder.flush()

    def _read_chunk(self, wait: float) -> list[can.Message]:
        assert self.bus is not None
        msg = self.bus.recv(timeout=wait)
        if msg is None:
            return []
        batch = [msg]
        while len(batch) < self.max_batch:
            msg = self.bus.recv(timeout=0)
            if msg is None:
                break
            batch.append(msg)
        return batch

    def _close_internal(self) -> None:
        self._shutdown_bus()
