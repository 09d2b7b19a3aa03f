"""Shared by the live-path tests: one cached simulated session, a pty serial pair, a leak check.

The session: k9k-4cyl at 2000 rpm, 60 % load, 20 cycles, seed 3, the simulator's default effects (tooth-spacing
error, timer jitter, pressure noise through the 16-bit ADC, combustion variability). Simulated once per process.
"""

from __future__ import annotations

import contextlib
import functools
import os
import threading
import time
import tty
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from can.interfaces import virtual
from frictionwatch.core.model.engine import EngineSpec, load_engine
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.core.plant.simulate import SimResult, simulate
from frictionwatch.core.types import CamBatch, LoadSample, PressureBlock, PressureFrame, StreamRecord, ToothBatch
from frictionwatch.drivers.bridge import WireEvent, received_records, wire_events
from frictionwatch.drivers.timebase import forget_shared

ENGINE, RPM, LOAD, CYCLES, SEED = "k9k-4cyl", 2000.0, 0.6, 20, 3


@dataclass(frozen=True)
class Session:
    spec: EngineSpec
    sim: SimResult
    events: list[WireEvent]  # what the tooth board and the CAN nodes send
    received: list[StreamRecord]  # what the decoders make of exactly those events

    @property
    def tick_hz(self) -> float:
        return self.sim.info.tick_hz


@functools.cache
def session() -> Session:
    spec = load_engine(ENGINE)
    sim = simulate(spec, RPM, LOAD, CYCLES, SEED)
    events = wire_events(sim.records, sim.info)
    return Session(spec, sim, events, received_records(events, sim.info))


class PtyPort:
    """A pty pair standing in for a USB serial adapter, optionally behind a stable symlink (udev's by-id name) so
    that it can be unplugged and plugged in again. ``write`` is what the tooth board does."""

    def __init__(self, link: Path | None = None) -> None:
        self.link = link
        self.master = self.slave = -1
        self.plug()

    @property
    def path(self) -> str:
        return str(self.link) if self.link is not None else os.ttyname(self.slave)

    def plug(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # no echo, no line discipline: bytes written before the reader opens it survive
        if self.link is not None:
            self.link.symlink_to(os.ttyname(self.slave))

    def unplug(self) -> None:
        if self.link is not None:
            self.link.unlink()
        os.close(self.master)
        os.close(self.slave)
        self.master = self.slave = -1

    def write(self, data: bytes) -> None:
        if self.master >= 0:
            os.write(self.master, data)

    def close(self) -> None:
        if self.master >= 0:
            self.unplug()


def _open_fds() -> dict[int, str]:
    out = {}
    for name in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):
            out[int(name)] = os.readlink(f"/proc/self/fd/{name}")
    return out


@contextlib.contextmanager
def leak_check(grace_s: float = 3.0) -> Iterator[None]:
    """Fail if the body leaves a thread running, a python-can virtual channel open (python-can's own conftest does
    the same) or a file descriptor (port, pty, log file) open. A fresh shared timer unwrapper on both sides."""
    forget_shared()
    threads = set(threading.enumerate())
    fds = _open_fds()
    yield
    deadline = time.monotonic() + grace_s
    while time.monotonic() < deadline and [t for t in threading.enumerate() if t not in threads]:
        time.sleep(0.02)
    forget_shared()
    extra = [t.name for t in threading.enumerate() if t not in threads]
    with virtual.channels_lock:
        channels = list(virtual.channels)
    new_fds = {fd: target for fd, target in _open_fds().items() if fds.get(fd) != target}
    assert not extra, f"threads left running: {extra}"
    assert not channels, f"virtual CAN channels left open: {channels}"
    assert not new_fds, f"file descriptors left open: {new_fds}"


def wait_until(predicate, timeout: float = 5.0, step: float = 0.01) -> bool:
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            return False
        time.sleep(step)
    return True


def wait_all_delivered(live, records, timeout: float = 20.0) -> None:
    """Wait until the live session has had the last record of each stream: teeth and cam from "serial", pressure
    and load from "can" (so that ``stop`` loses nothing still in a pty or a bus queue)."""
    from frictionwatch.service.live import record_key

    serial = max(record_key(r) for r in records if isinstance(r, ToothBatch | CamBatch))
    bus = max(record_key(r) for r in records if isinstance(r, PressureBlock | PressureFrame | LoadSample))
    assert live.wait_progress("serial", serial, timeout) and live.wait_progress("can", bus, timeout)


# No early release in the live tests: the merge's window (acquisition time) and quiet time (wall time) are longer than
# any session here, so a record is released only when every source has vouched for it (or at stop). Early release
# exists for sources that stay silent in a long-running service; with it, a reader thread starved for a while on a
# loaded machine could let records out before older ones of the other stream, and the results would depend on the
# machine's load (a late load reading changes a cycle's mean load). It is tested without threads on RecordMerge and
# once live in test_live_bad_input.py::test_a_silent_source_holds_the_others_back_only_briefly.
ORDERED_MERGE = {"window_s": 60.0, "quiet_s": 60.0}


def per_cycle(r: CycleResult) -> dict[str, np.ndarray]:
    """The per-cycle quantities compared between paths (SI)."""
    return {
        "t_start": np.array([r.t_start]), "rpm": np.array([r.rpm_mean]), "load_torque": np.array([r.load_torque]),
        "imep": r.imep, "pmax": r.pmax, "pmax_angle": r.pmax_angle, "indicated_torque": r.indicated_torque,
        "friction_balance": np.array([r.friction_balance]),
        "friction_cycle": r.cycle.friction_torque_mean, "friction_smoothed": r.smoothed.friction_torque_mean,
        "fmep_smoothed": np.array([r.smoothed.total_fmep]), "speed_measured": r.speed_measured,
    }
