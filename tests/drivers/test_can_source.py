"""CanSource on python-can's virtual bus (always) and on SocketCAN vcan0 (only where the kernel has it)."""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import can
import numpy as np
import pytest
from frictionwatch.core.types import LoadSample, PressureBlock
from frictionwatch.drivers.backoff import Backoff
from frictionwatch.drivers.can.codec import encode_load
from frictionwatch.drivers.can.encoder import PressureEncoder
from frictionwatch.drivers.can.pressure import CanSource
from frictionwatch.drivers.source import open_source
from frictionwatch.drivers.timebase import TimerUnwrapper, forget_shared

_channels = itertools.count()


@pytest.fixture
def channel() -> str:
    return f"fw-test-{next(_channels)}-{time.monotonic_ns()}"


@pytest.fixture(autouse=True)
def _fresh_timer():
    forget_shared()
    yield
    forget_shared()


def traffic(enc: PressureEncoder, k: int) -> tuple[list[can.Message], np.ndarray]:
    """Block k of 100 samples (4 frames) for cylinders 1..3 at 20 kHz on a 10 MHz timer, and one load frame."""
    t0 = 2**32 - 500_000 + k * 100 * 500
    values = 1e5 + 1e3 * np.arange(100) + 1e6 * k
    msgs = [m for c in (1, 2, 3) for m in enc.block(c, t0, 500.0, values)]
    return msgs + [encode_load(3.3e6, 21_000.0, counter=k)], values


def drain(src: CanSource, want_samples: int, limit_s: float = 3.0) -> list:
    out, end = [], time.monotonic() + limit_s
    while sum(r.values.size for r in out if isinstance(r, PressureBlock)) < want_samples and time.monotonic() < end:
        out += src.read(timeout=0.05)
    return out


def test_virtual_bus_round_trip_through_the_registry(channel: str) -> None:
    with open_source(f"can:virtual/{channel}?fd=1&tick_hz=10e6&reorder=2") as src, \
            can.Bus(interface="virtual", channel=channel, fd=True) as tx:
        assert isinstance(src, CanSource)
        enc = PressureEncoder()
        truth = []
        for k in range(10):
            msgs, values = traffic(enc, k)
            truth.append(values)
            for m in msgs:
                tx.send(m)
        out = drain(src, 3 * 1000)
        for c in (1, 2, 3):
            got = np.concatenate([b.values for b in out if isinstance(b, PressureBlock) and b.cylinder == c])
            np.testing.assert_allclose(got, np.concatenate(truth), rtol=0, atol=200.0)  # half a count of ~340 Pa
        b0 = next(b for b in out if isinstance(b, PressureBlock))
        assert b0.t0_ticks == 2**32 - 500_000 and b0.period_ticks == 500.0
        loads = [r for r in out if isinstance(r, LoadSample)]
        assert len(loads) == 10 and loads[0].power == 3.3e6 and loads[0].torque == 21_000.0
        assert not src.damage


def test_bad_urls() -> None:
    with pytest.raises(ValueError, match="interface"):
        open_source("can:virtual")
    with pytest.raises(ValueError, match="unknown can option"):
        open_source("can:virtual/x?speed=2")


def test_bus_lost_and_back(channel: str, monkeypatch: pytest.MonkeyPatch) -> None:
    src = CanSource("virtual", channel, unwrapper=TimerUnwrapper(), backoff=Backoff(first=0.01, cap=0.02))
    with src, can.Bus(interface="virtual", channel=channel, fd=True) as tx:
        def broken(timeout: float | None = None) -> can.Message:
            raise can.CanOperationError("interface down")

        monkeypatch.setattr(src.bus, "recv", broken)
        assert src.read(timeout=0.05) == []  # counted, not raised
        assert src.damage["bus_lost"] == 1
        deadline = time.monotonic() + 2
        while src.bus is None and time.monotonic() < deadline:
            src.read(timeout=0.02)
        assert src.reconnects == 1 and src.damage["reconnect"] == 1
        msgs, _values = traffic(PressureEncoder(), 0)
        for m in msgs:
            tx.send(m)
        out = drain(src, 300)
        assert sum(b.values.size for b in out if isinstance(b, PressureBlock)) == 300


def test_unknown_interface_does_not_raise() -> None:
    with CanSource("no-such-interface", "x", backoff=Backoff(first=0.01, cap=0.02)) as src:
        assert src.read(timeout=0.05) == [] and src.damage["bus_unavailable"] == 1


@pytest.mark.skipif(not Path("/sys/class/net/vcan0").exists(), reason="SocketCAN vcan0 not available here")
def test_socketcan_vcan0() -> None:
    with open_source("can:socketcan/vcan0") as src, can.Bus(interface="socketcan", channel="vcan0", fd=True) as tx:
        msgs, values = traffic(PressureEncoder(), 0)
        for m in msgs:
            tx.send(m)
        out = drain(src, 300)
        got = np.concatenate([b.values for b in out if isinstance(b, PressureBlock) and b.cylinder == 1])
        np.testing.assert_allclose(got, values, rtol=0, atol=200.0)
