"""drivers/bridge.py: the wire output follows the firmware rules of docs/protocols.md (§2.6, §3.2, §3.5)."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.core.types import AcquisitionInfo, CamBatch, LoadSample, PressureBlock, ToothBatch
from frictionwatch.drivers.bridge import CAN, SERIAL, can_events, received_records, serial_events, wire_events
from frictionwatch.drivers.can.codec import layouts
from frictionwatch.drivers.can.encoder import PressureEncoder
from frictionwatch.drivers.serial.codec import CamFrame, Decoder, HeartbeatFrame, InfoFrame, TeethFrame

INFO = AcquisitionInfo(tick_hz=10e6, wheel_teeth=60, wheel_missing=2, first_tooth_deg=-84.0, cam_deg=630.0,
                       pressure_cylinders=(1, 2))


def records(seconds: float = 0.5):
    """Teeth of a 60-2 wheel at 1500 rpm with one 0.3 s stop, a cam edge per cycle, two cylinders, load at 100 Hz."""
    pitch = 10e6 * 60.0 / 1500 / 60
    k = np.arange(int(seconds * 10e6 / pitch))
    t = np.round(1000 + k * pitch).astype(np.int64)[k % 60 < 58]
    t = np.where(t > 2_000_000, t + 3_000_000, t)  # the engine stands for 0.3 s
    out = [ToothBatch(t[i:i + 50]) for i in range(0, t.size, 50)]
    out += [CamBatch(np.array([c], np.int64)) for c in t[::116]]
    for cyl in (1, 2):
        out += [PressureBlock(cyl, t0, 500.0, 1e5 + 5e6 * np.random.default_rng(t0).random(200))
                for t0 in range(0, int(seconds * 10e6), 100_000)]
    out += [LoadSample(t0 + 50_000, 101.3, 23_456.7) for t0 in range(0, int(seconds * 10e6), 100_000)]
    return out


def test_serial_frames_follow_the_firmware_rules():
    events = serial_events(records(), INFO)
    assert all(e.channel == SERIAL for e in events) and [e.tick for e in events] == sorted(e.tick for e in events)
    dec = Decoder()
    frames = [(e.tick, dec.feed(e.payload)) for e in events]
    assert all(len(f) == 1 for _, f in frames) and not dec.damage  # one frame each, SEQ without a gap
    assert [f[0].seq for _, f in frames] == list(range(len(frames)))
    beats = [tick for tick, f in frames if isinstance(f[0], HeartbeatFrame)]
    assert np.diff(beats).max() <= 0.1 * 10e6  # rule 2, also while the engine stands
    info = next(f[0] for _, f in frames if isinstance(f[0], InfoFrame))
    assert (info.wheel_teeth, info.first_tooth_deg, info.cam_deg) == (60, -84.0, -90.0)  # 630 deg fits i16 as -90
    assert isinstance(frames[0][1][0], InfoFrame) and not frames[0][1][0].flags  # running board: no BOOT
    for tick, (f,) in frames:
        if isinstance(f, TeethFrame):  # rule 1: <= 32 edges, sent after its last edge, within 2 ms of its first
            assert f.ticks.size <= 32 and f.ticks[-1] <= tick <= f.ticks[0] + 0.002 * 10e6
        if isinstance(f, CamFrame):
            assert tick == f.ticks[0]


def test_can_frames_are_sent_when_complete_and_stamped_on_the_timer():
    events = can_events(records(), INFO)
    assert all(e.channel == CAN for e in events) and [e.tick for e in events] == sorted(e.tick for e in events)
    lay = layouts()
    for e in events:
        assert e.payload.timestamp == pytest.approx(e.tick / 10e6, abs=1e-12)  # host clock = timer
        if e.payload.arbitration_id in lay.fd_id:
            rec = np.frombuffer(bytes(e.payload.data), lay.fd_dtype)[0]
            assert e.tick == rec["T0Ticks"] + rec["NSamples"] * rec["PeriodTicks"] * lay.fd_period_factor
    with pytest.raises(ValueError, match="CAN FD"):
        can_events(records(), INFO, encoder=PressureEncoder(fd=False))


def test_received_records_are_the_records_within_the_wire_resolution():
    recs = records()
    got = received_records(wire_events(recs, INFO), INFO)
    for kind in (ToothBatch, CamBatch):
        np.testing.assert_array_equal(np.concatenate([r.ticks for r in got if isinstance(r, kind)]),
                                      np.concatenate([r.ticks for r in recs if isinstance(r, kind)]))
    loads = [r for r in got if isinstance(r, LoadSample)]
    assert [r.ticks for r in loads] == [r.ticks for r in recs if isinstance(r, LoadSample)]
    assert {(r.torque, r.power) for r in loads} == {(102.0, 23_457.0)}  # 2 N m and 1 W steps
    p_in = np.concatenate([r.values for r in recs if isinstance(r, PressureBlock) and r.cylinder == 2])
    p_out = np.concatenate([r.values for r in got if isinstance(r, PressureBlock) and r.cylinder == 2])
    assert np.abs(p_out - p_in).max() <= 5.1e6 / 32766 / 2 + 0.05  # half a count at the frame's scale
