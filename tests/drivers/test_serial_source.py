"""SerialSource over pyserial's loop://, a pty pair, and a pty that vanishes and returns (udev-style symlink)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.types import CamBatch, ToothBatch
from frictionwatch.drivers.backoff import Backoff
from frictionwatch.drivers.serial.codec import Encoder
from frictionwatch.drivers.serial.teeth import SerialSource
from frictionwatch.drivers.source import open_source
from frictionwatch.drivers.timebase import TimerUnwrapper, forget_shared

FAST = {"backoff": Backoff(first=0.01, factor=2.0, cap=0.05)}


@pytest.fixture(autouse=True)
def _fresh_timer():
    forget_shared()
    yield
    forget_shared()


def read_until(src: SerialSource, n_edges: int, limit_s: float = 3.0) -> list:
    out, got, end = [], 0, time.monotonic() + limit_s
    while got < n_edges and time.monotonic() < end:
        recs = src.read(timeout=0.05)
        out += recs
        got += sum(r.ticks.size for r in recs if isinstance(r, ToothBatch))
    return out


def ticks_of(records: list) -> np.ndarray:
    parts = [r.ticks for r in records if isinstance(r, ToothBatch)]
    return np.concatenate(parts) if parts else np.empty(0, np.int64)


def tooth_times(n: int, start: int) -> np.ndarray:
    return start + np.cumsum(np.random.default_rng(3).integers(2400, 2600, n)).astype(np.int64)


def test_loop_url_through_the_registry() -> None:
    with open_source("serial:loop://?baud=115200") as src:
        assert isinstance(src, SerialSource) and src.info is None
        enc = Encoder()
        t = tooth_times(600, start=(1 << 32) - 100_000)
        src.port.write(enc.info(10e6, 160, 2, -30.0, 90.0) + enc.teeth(t[:300]) + enc.cam([t[10]]) + b"\x00junk"
                       + enc.teeth(t[300:]))
        recs = read_until(src, t.size)
        np.testing.assert_array_equal(ticks_of(recs), t)
        assert [r.ticks[0] for r in recs if isinstance(r, CamBatch)] == [t[10]]
        assert src.info is not None and (src.info.wheel_teeth, src.info.tick_hz, src.info.cam_deg) == (160, 10e6, 90.0)
        assert src.damage["garbage_bytes"] == 5
    with pytest.raises(ValueError, match="closed"):
        src.read(0)


def test_stated_info_wins_and_bad_options_rejected() -> None:
    with open_source("serial:loop://?tick_hz=1e6&teeth=60&missing=2&first_tooth_deg=-84") as src:
        src.port.write(Encoder().info(10e6, 160, 2, 0.0))
        src.read(timeout=0.2)
        assert src.info.tick_hz == 1e6 and src.info.wheel_teeth == 60
        assert src.damage["board_info_differs_from_stated"] == 1
    with pytest.raises(ValueError, match="unknown serial option"):
        open_source("serial:loop://?bauds=9600")


def test_pty_pair() -> None:
    master, slave = os.openpty()
    try:
        with SerialSource(os.ttyname(slave), unwrapper=TimerUnwrapper(), **FAST) as src:
            t = tooth_times(1000, start=5)
            os.write(master, Encoder().teeth(t))
            np.testing.assert_array_equal(ticks_of(read_until(src, t.size)), t)
    finally:
        os.close(master)
        os.close(slave)


def test_port_that_vanishes_and_returns(tmp_path: Path) -> None:
    link = tmp_path / "ttyFW0"  # like /dev/serial/by-id/...: the name stays, the device behind it changes
    master, slave = os.openpty()
    link.symlink_to(os.ttyname(slave))
    enc = Encoder()
    t = tooth_times(2000, start=1000)
    with SerialSource(str(link), unwrapper=TimerUnwrapper(), **FAST) as src:
        os.write(master, enc.teeth(t[:1000]))
        first = ticks_of(read_until(src, 1000))
        os.close(master)  # unplugged
        os.close(slave)
        link.unlink()
        assert ticks_of(src.read(timeout=0.2)).size == 0  # no exception, nothing made up
        assert src.damage["port_lost"] == 1 and src.port is None
        src.read(timeout=0.1)  # reopen attempts fail while the device is gone
        master, slave = os.openpty()  # plugged in again: a new pty behind the same name
        link.symlink_to(os.ttyname(slave))
        deadline = time.monotonic() + 3
        while src.port is None and time.monotonic() < deadline:
            src.read(timeout=0.05)
        assert src.reconnects == 1 and src.damage["reconnect"] == 1
        enc.seq += 5  # frames sent while unplugged are lost
        os.write(master, enc.teeth(t[1000:]))
        second = ticks_of(read_until(src, 1000))
        assert src.damage["frames_lost"] == 5
    os.close(master)
    os.close(slave)
    np.testing.assert_array_equal(np.concatenate([first, second]), t)  # the board's timer ran on: same epoch


def test_missing_device_does_not_raise(tmp_path: Path) -> None:
    with SerialSource(str(tmp_path / "nothing"), unwrapper=TimerUnwrapper(), **FAST) as src:
        assert src.read(timeout=0.05) == []
        assert src.damage["port_unavailable"] == 1 and src.port is None
