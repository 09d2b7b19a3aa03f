"""Sources of stream records: one thin base (template method, after python-can's BusABC) and a lazy URL registry
(after pyserial's serial_for_url): ``mcap:replay_logs/demo.mcap?speed=10``, ``serial:/dev/ttyUSB0?baud=921600``,
``can:virtual/ch0``, ``mdf4:file.MF4``, ``sim:k9k-4cyl?rpm=1700``.
"""

from __future__ import annotations

import importlib
import logging
from abc import ABC, abstractmethod
from collections import Counter
from dataclasses import dataclass
from urllib.parse import parse_qsl, urlsplit

from frictionwatch.core.types import AcquisitionInfo, StreamRecord
from frictionwatch.drivers.timebase import Clocks

log = logging.getLogger(__name__)

# scheme -> (module, class); imported only when used
SOURCES: dict[str, tuple[str, str]] = {
    "mcap": ("frictionwatch.drivers.logs.mcap_replay", "McapSource"),
    "serial": ("frictionwatch.drivers.serial.teeth", "SerialSource"),
    "can": ("frictionwatch.drivers.can.pressure", "CanSource"),
    "mdf4": ("frictionwatch.drivers.logs.mdf4", "Mdf4Source"),
}


@dataclass(frozen=True)
class StreamRestart:
    """Not data: a mark in a source's record stream that the stream starts again at ``ticks`` and nothing before it
    continues into what follows (a replayed log looping back to its start, ``mcap:...?loop=1``). The engine pipeline
    restarts its cycle assembler there and counts a ``reason`` (service.pipeline.EnginePipeline.restarts) instead of
    reading the seam as a data gap; a recorder writes it (docs/replay-format.md, ``restarts``), so that a recording
    says it too. ``ticks`` lies after every record before the mark
    and before every record after it, so a time-ordered merge keeps it in place."""

    ticks: int
    reason: str = "loop_restart"
    # a hole (a live session's queue dropped a source's batches while the analysis was behind, service/live.py): the
    # first dropped tick, the records dropped and the crank cycles their flywheel tooth edges held (edges / edges a
    # cycle: the wheel's own clock, whatever the speed or a replay's silences inside). None / 0: nothing was dropped
    dropped_from_ticks: int | None = None
    dropped_records: int = 0
    dropped_cycles: float = 0.0
    # what starts again: "all" (the cycle assembly: the flywheel's edges went), "second_wheel" (only the second
    # wheel's cut: its edges alone went), "none" (no wheel's edges went: pressure, cam or load only; the cycles that
    # lack them are skipped as the assembler finds them)
    assembly: str = "all"

    @property
    def is_hole(self) -> bool:
        return self.dropped_records > 0


class Source(ABC):
    """A stream of records in acquisition order. ``read`` is written once here; drivers override ``_read_internal``.

    ``info`` describes the acquisition (tick clock, wheel); ``engine_toml`` the engine if the source knows it.
    ``damage`` counts what was skipped and why (reason -> count); a per-frame error never ends the stream.
    """

    info: AcquisitionInfo | None = None
    engine_toml: str | None = None

    def __init__(self) -> None:
        self.damage: Counter[str] = Counter()
        self._closed = False

    def read(self, timeout: float | None = None) -> list[StreamRecord | StreamRestart]:
        """Records available within ``timeout`` seconds ([] if none), with a ``StreamRestart`` mark where the stream
        starts again (a looped replay). Raises EndOfStream when a finite source ends."""
        if self._closed:
            raise ValueError("read from a closed source")
        return self._read_internal(timeout)

    def count(self, reason: str, n: int = 1) -> None:
        """Count a skipped piece of input under a short reason and log the first occurrence."""
        if self.damage[reason] == 0:
            log.warning("%s: %s", type(self).__name__, reason)
        self.damage[reason] += n

    @abstractmethod
    def _read_internal(self, timeout: float | None) -> list[StreamRecord | StreamRestart]: ...

    def _close_internal(self) -> None:  # noqa: B027 - optional hook
        pass

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._close_internal()

    def __enter__(self) -> Source:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_source(url: str, clocks: Clocks | None = None) -> Source:
    """Open a source from ``scheme:target?key=value``. Unknown schemes raise ValueError listing the known ones.
    ``clocks``: the timers of the session the source joins (live boards unwrap their timer there; None: the
    process-wide set, drivers.timebase.shared_unwrapper)."""
    scheme, _, rest = url.partition(":")
    if scheme not in SOURCES or not rest:
        raise ValueError(f"unknown source '{url}'; expected one of: {', '.join(s + ':...' for s in SOURCES)}")
    parts = urlsplit("x://" + rest) if "?" in rest else None
    target = rest.split("?", 1)[0]
    options = dict(parse_qsl(parts.query)) if parts else {}
    module, cls = SOURCES[scheme]
    return getattr(importlib.import_module(module), cls).from_url(target, options, clocks=clocks)
