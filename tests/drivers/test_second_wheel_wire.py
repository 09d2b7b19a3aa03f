"""The second (free-end) wheel on the wire (docs/protocols.md §2.4 TEETH2 / INFO bytes 14..19, §3.8
``FreeEndTeethFD``): round trips through the project's encoders and decoders, and bad input counted, never raised."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.core.types import AcquisitionInfo, FreeEndToothBatch, ToothBatch, WheelInfo
from frictionwatch.drivers.bridge import received_records, serial_events
from frictionwatch.drivers.can.codec import load_dbc
from frictionwatch.drivers.can.decoder import CanDecoder
from frictionwatch.drivers.can.teeth import (
    FLAG_SENSOR_FAULT,
    encode_free_end_teeth,
    free_end_frames,
)
from frictionwatch.drivers.serial.codec import (
    Decoder,
    Encoder,
    InfoFrame,
    Teeth2Frame,
    TeethFrame,
    encode_info,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_array_equal

WRAP = 1 << 32
FUZZ = settings(max_examples=100, deadline=None, derandomize=True)


def wheel_ticks(n: int, pitch: int, gap_every: int, start: int, seed: int) -> np.ndarray:
    """Seeded edge times of a wheel with one missing tooth every ``gap_every`` edges (double pitch there)."""
    rng = np.random.default_rng(seed)
    d = rng.integers(pitch - 60, pitch + 60, n)
    d[::gap_every] *= 2
    return start + np.cumsum(d).astype(np.int64)


def of(frames, kind) -> np.ndarray:
    parts = [f.ticks for f in frames if isinstance(f, kind)]
    return np.concatenate(parts) if parts else np.empty(0, np.int64)


@pytest.mark.parametrize("chunk", [1, 7, 4096])
def test_serial_teeth2_round_trip_across_the_timer_wrap(chunk: int) -> None:
    t1 = wheel_ticks(600, 2500, 158, WRAP - 400_000, 1)
    t2 = wheel_ticks(450, 3333, 119, WRAP - 398_000, 2)
    enc = Encoder()
    wire = b"".join(enc.teeth(t1[32 * k:32 * k + 32]) + enc.teeth2(t2[24 * k:24 * k + 24]) for k in range(19))
    dec = Decoder()
    frames = []
    for i in range(0, len(wire), chunk):
        frames += dec.feed(wire[i:i + chunk])
    frames += dec.flush()
    assert_array_equal(of(frames, Teeth2Frame), t2)
    assert_array_equal(of(frames, TeethFrame), t1)
    assert not dec.damage


def test_serial_info_carries_the_second_wheel_and_stays_14_bytes_without() -> None:
    dec = Decoder()
    without, with2 = encode_info(0, 10e6, 160, 2, -30.0, 5.0), encode_info(1, 10e6, 160, 2, -30.0, 5.0,
                                                                       second_wheel=(120, 1, 47.25))
    assert without[3] == 14 and with2[3] == 20
    a, b = (f for f in dec.feed(without + with2) if isinstance(f, InfoFrame))
    assert a.second_wheel is None and b.second_wheel == (120, 1, 47.25)
    assert (b.wheel_teeth, b.wheel_missing, b.first_tooth_deg) == (160, 2, -30.0)
    bad = encode_info(2, 10e6, 160, 2, -30.0, 5.0, second_wheel=(120, 120, 0.0))
    assert not dec.feed(bad) and dec.damage["bad_info_frame"] == 1


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), max_size=12), st.integers(1, 64))
def test_serial_damaged_teeth2_stream_is_counted_never_raised(hits, chunk: int) -> None:
    t2 = wheel_ticks(200, 3333, 119, WRAP - 100_000, 3)
    wire = bytearray(Encoder(max_edges=10).teeth2(t2))
    for pos, xor in hits:
        wire[pos % len(wire)] ^= xor
    dec = Decoder()
    frames = []
    for i in range(0, len(wire), chunk):
        frames += dec.feed(bytes(wire[i:i + chunk]))
    frames += dec.flush()
    got = of(frames, Teeth2Frame)
    assert np.all(np.diff(got) > 0)
    assert np.isin(got, t2).all()  # a CRC-good frame is never made up
    if any(x for _, x in hits):
        assert sum(dec.damage.values()) > 0 or got.size == t2.size


@pytest.mark.parametrize("batch", [1, 3, 50])
def test_can_free_end_teeth_round_trip_across_the_wrap(batch: int) -> None:
    t2 = wheel_ticks(500, 3333, 119, WRAP - 300_000, 4)
    msgs = free_end_frames(t2, seq=65530)  # the counter wraps too
    dec = CanDecoder()
    out = []
    for i in range(0, len(msgs), batch):
        out += dec.feed(msgs[i:i + batch])
    out += dec.flush()
    assert all(isinstance(r, FreeEndToothBatch) for r in out)
    assert_array_equal(np.concatenate([r.ticks for r in out]), t2)
    assert not dec.damage


def test_can_layout_agrees_with_cantools() -> None:
    t = np.array([100, 2100, 4200, 10_000], np.int64)
    msg = encode_free_end_teeth(7, t, FLAG_SENSOR_FAULT)
    assert msg.data[:16].hex(" ") == "07 00 64 00 00 00 04 02 d0 07 34 08 a8 16 00 00"  # protocols.md §3.8
    assert msg.arbitration_id == 0x180 and msg.is_fd and not msg.is_extended_id and len(msg.data) == 64
    sig = load_dbc().decode_message(msg.arbitration_id, msg.data)
    assert (sig["Seq"], sig["BaseTicks"], sig["NEdges"], sig["SensorFault"], sig["Overflow"]) == (7, 100, 4, 1, 0)
    assert [sig[f"D0{i}"] for i in (1, 2, 3, 4)] == [2000, 2100, 5800, 0]
    with pytest.raises(ValueError, match="1..29 edges"):
        encode_free_end_teeth(0, np.arange(30) * 10)


def test_can_bad_frames_are_counted_and_the_rest_delivered() -> None:
    t2 = wheel_ticks(29 * 6, 3333, 119, 1_000_000, 5)
    msgs = free_end_frames(t2)
    msgs[2] = encode_free_end_teeth(2, t2[58:87], FLAG_SENSOR_FAULT)  # fault: its edges dropped
    bad = bytearray(msgs[4].data)
    bad[6] = 0  # NEdges 0: a bad header
    msgs[4] = msgs[4].__class__(arbitration_id=msgs[4].arbitration_id, is_extended_id=False, is_fd=True,
                                data=bytes(bad))
    short = msgs[0].__class__(arbitration_id=msgs[0].arbitration_id, is_extended_id=False, is_fd=True,
                               data=bytes(8))  # wrong length
    dec = CanDecoder(reorder_window=0)
    out = dec.feed([msgs[0], msgs[1], short, msgs[2], msgs[3], msgs[4]]) + dec.feed([msgs[5]]) + dec.flush()
    got = np.concatenate([r.ticks for r in out])
    keep = np.ones(t2.size, bool)
    keep[58:87] = keep[116:145] = False
    assert_array_equal(got, t2[keep])
    assert dec.damage["wrong_dlc"] == 1 and dec.damage["bad_frame_header"] == 1
    assert dec.damage["teeth2_sensor_fault_edges"] == 29 and dec.damage["teeth2_frames_lost"] == 1


def test_bridge_serial_round_trip_of_both_wheels() -> None:
    info = AcquisitionInfo(10e6, 160, 2, -30.0, None, (), WheelInfo(120, 1, 47.0))
    t1 = wheel_ticks(800, 2500, 158, 5_000, 6)
    t2 = wheel_ticks(600, 3333, 119, 6_000, 7)
    records = [ToothBatch(t1[i:i + 158]) for i in range(0, 800, 158)] + [
        FreeEndToothBatch(t2[i:i + 119]) for i in range(0, 600, 119)]
    events = serial_events(records, info)
    info_frames = [f for ev in events for f in Decoder().feed(ev.payload) if isinstance(f, InfoFrame)]
    assert info_frames and all(f.second_wheel == (120, 1, 47.0) for f in info_frames)
    back = received_records(events, info)
    assert_array_equal(np.concatenate([r.ticks for r in back if isinstance(r, FreeEndToothBatch)]), t2)
    assert_array_equal(np.concatenate([r.ticks for r in back if isinstance(r, ToothBatch)]), t1)
