"""Serial framing (docs/protocols.md §2): CRC, round trip, and every kind of bad input, plus hypothesis fuzzing."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.drivers.serial.codec import (
    FLAG_BOOT,
    FLAG_OVERFLOW,
    FLAG_SENSOR_FAULT,
    CamFrame,
    Decoder,
    Encoder,
    HeartbeatFrame,
    InfoFrame,
    TeethFrame,
    crc16_ccitt_false,
    encode_cam,
    encode_frame,
    encode_heartbeat,
    encode_info,
    encode_teeth,
)
from frictionwatch.drivers.timebase import REBASE_GAP
from hypothesis import given, settings
from hypothesis import strategies as st

WRAP = 1 << 32
FUZZ = settings(max_examples=150, deadline=None, derandomize=True)


def crc_reference(data: bytes) -> int:
    """Bitwise CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def teeth_ticks(n: int, start: int = WRAP - 300_000, seed: int = 0) -> np.ndarray:
    """Seeded tooth times: ~2500 ticks (160-2 wheel at 1500 rpm, 10 MHz) with a 3x gap every 158 edges."""
    rng = np.random.default_rng(seed)
    d = rng.integers(2400, 2600, n)
    d[::158] *= 3
    return start + np.cumsum(d).astype(np.int64)


def decoded_ticks(frames: list) -> np.ndarray:
    parts = [f.ticks for f in frames if isinstance(f, TeethFrame)]
    return np.concatenate(parts) if parts else np.empty(0, np.int64)


def split_frames(stream: bytes) -> list[bytes]:
    """Cut an encoder output into its frames (length byte at offset 3)."""
    out, i = [], 0
    while i < len(stream):
        n = 9 + stream[i + 3]
        out.append(stream[i:i + n])
        i += n
    return out


def test_crc_is_ccitt_false() -> None:
    assert crc16_ccitt_false(b"123456789") == 0x29B1  # the catalogue check value of CRC-16/CCITT-FALSE
    rng = np.random.default_rng(1)
    for size in (0, 1, 7, 64, 255):
        data = rng.integers(0, 256, size, dtype=np.uint8).tobytes()
        assert crc16_ccitt_false(data) == crc_reference(data)


def test_example_frame_of_the_spec() -> None:
    # the worked example of docs/protocols.md §2.6: TEETH, SEQ 0x0102, edges at 0xFFFFF000, +2500, +2600
    frame = encode_teeth(0x0102, [0xFFFFF000, 0xFFFFF000 + 2500, 0xFFFFF000 + 5100])
    assert frame.hex(" ") == "a5 5a 01 08 02 01 00 00 f0 ff ff c4 09 28 0a 78 51"
    ticks = decoded_ticks(Decoder().feed(frame))
    np.testing.assert_array_equal(ticks, [0xFFFFF000, 0xFFFFF000 + 2500, 0xFFFFF000 + 5100])


def test_round_trip_across_timer_wrap_any_chunking() -> None:
    t = teeth_ticks(5000)  # crosses 2**32 after ~120 edges
    enc = Encoder(max_edges=32)
    stream = enc.info(10e6, 160, 2, -30.0, 12.5) + enc.teeth(t[:2000]) + enc.cam(t[100:101]) + enc.teeth(t[2000:])
    whole = Decoder()
    frames = whole.feed(stream)
    np.testing.assert_array_equal(decoded_ticks(frames), t)
    assert [f.ticks[0] for f in frames if isinstance(f, CamFrame)] == [t[100]]
    info = next(f for f in frames if isinstance(f, InfoFrame))
    assert (info.tick_hz, info.wheel_teeth, info.wheel_missing, info.first_tooth_deg, info.cam_deg) == \
        (10e6, 160, 2, -30.0, 12.5)
    assert not whole.damage
    rng = np.random.default_rng(2)
    chunked, got, pos = Decoder(), [], 0
    while pos < len(stream):
        step = int(rng.integers(1, 40))
        got += chunked.feed(stream[pos:pos + step])
        pos += step
    np.testing.assert_array_equal(decoded_ticks(got), t)
    assert not chunked.damage


def test_long_deltas_split_frames_and_heartbeat_carries_unwrap_over_stops() -> None:
    # engine stops for 500 s at 10 MHz (> one 2**32 wrap): heartbeats every 0.1 s keep the unwrapping exact
    enc = Encoder()
    before = teeth_ticks(300, start=100)
    after = teeth_ticks(300, start=int(before[-1]) + 5_000_000_000)
    hb = np.arange(before[-1] + 1_000_000, after[0], 1_000_000)
    stream = enc.teeth(before) + b"".join(enc.heartbeat(int(h)) for h in hb) + enc.teeth(after)
    frames = Decoder().feed(stream)
    np.testing.assert_array_equal(decoded_ticks(frames), np.concatenate([before, after]))
    assert sum(isinstance(f, HeartbeatFrame) for f in frames) == hb.size
    # a pause longer than 16 bits of ticks starts a new frame by itself
    slow = np.array([0, 70_000, 140_000, 140_010])
    np.testing.assert_array_equal(decoded_ticks(Decoder().feed(Encoder().teeth(slow))), slow)


def test_garbage_between_frames_is_skipped_and_counted() -> None:
    t = teeth_ticks(400)
    frames = split_frames(Encoder(max_edges=20).teeth(t))
    junk = [b"\x00\xff", b"\xa5", b"\xa5\x5a\x01\xff", b"\xa5\x5a\xa5\x5a", bytes(range(256))]
    stream = b"".join(f + junk[i % len(junk)] for i, f in enumerate(frames))
    dec = Decoder()
    out = dec.feed(stream) + dec.flush()
    np.testing.assert_array_equal(decoded_ticks(out), t)
    assert dec.damage["garbage_bytes"] > 0 and dec.damage["frames_lost"] == 0


def test_flipped_bit_loses_only_its_frame() -> None:
    t = teeth_ticks(200)
    frames = split_frames(Encoder(max_edges=20).teeth(t))
    bad = bytearray(frames[3])
    bad[9] ^= 0x10
    dec = Decoder()
    got = decoded_ticks(dec.feed(b"".join(frames[:3]) + bytes(bad) + b"".join(frames[4:])))
    np.testing.assert_array_equal(got, np.concatenate([t[:60], t[80:]]))
    assert dec.damage["crc_error"] >= 1 and dec.damage["frames_lost"] == 1


def test_truncated_tail_counted_on_flush() -> None:
    t = teeth_ticks(100)
    stream = Encoder(max_edges=25).teeth(t)
    dec = Decoder()
    got = dec.feed(stream[:-5])
    assert decoded_ticks(got).size == 75
    assert dec.flush() == [] and dec.damage["truncated_frame"] >= 1


def test_duplicates_dropped_and_reordering_undone_within_window() -> None:
    t = teeth_ticks(300)
    frames = split_frames(Encoder(max_edges=10).teeth(t))
    dup = frames[:5] + [frames[4], frames[4]] + frames[5:]
    dec = Decoder()
    np.testing.assert_array_equal(decoded_ticks(dec.feed(b"".join(dup))), t)
    assert dec.damage["duplicate_frame"] == 2
    swapped = frames[:5] + [frames[6], frames[5]] + frames[7:]
    dec = Decoder(reorder_window=2)
    np.testing.assert_array_equal(decoded_ticks(dec.feed(b"".join(swapped)) + dec.flush()), t)
    assert dec.damage["reordered_frame"] == 1 and dec.damage["frames_lost"] == 0
    dec = Decoder(reorder_window=0)  # a UART never reorders: the late frame is counted, not inserted
    got = decoded_ticks(dec.feed(b"".join(swapped)))
    np.testing.assert_array_equal(got, np.concatenate([t[:50], t[60:]]))
    assert dec.damage["frames_lost"] == 1
    dec.feed(b"")
    assert dec.flush() == [] and np.all(np.diff(got) > 0)


def test_dropped_frames_counted_by_sequence_gap() -> None:
    t = teeth_ticks(500)
    frames = split_frames(Encoder(max_edges=10).teeth(t))
    keep = [f for i, f in enumerate(frames) if i not in (3, 10, 11, 12)]
    dec = Decoder()
    got = decoded_ticks(dec.feed(b"".join(keep)))
    assert got.size == 500 - 40 and dec.damage["frames_lost"] == 4


def test_flags_boot_restart_and_zero_deltas() -> None:
    enc = Encoder()
    a = teeth_ticks(50, start=10_000_000)
    stream = enc.teeth(a[:20], flags=FLAG_OVERFLOW) + enc.teeth(a[20:40]) + enc.teeth(a[40:], flags=FLAG_SENSOR_FAULT)
    dec = Decoder()
    got = decoded_ticks(dec.feed(stream))
    np.testing.assert_array_equal(got, a[:40])  # a sensor-fault frame is not trusted
    assert dec.damage["board_capture_overflow"] == 1 and dec.damage["sensor_fault_edges"] == 10
    # board reset: SEQ and timer restart, BOOT flag on the first frame; the stream jumps by REBASE_GAP
    enc2 = Encoder()
    b = teeth_ticks(30, start=5000)
    more = dec.feed(enc2.info(10e6, 160, 2, 0.0, flags=FLAG_BOOT) + enc2.teeth(b))
    np.testing.assert_array_equal(decoded_ticks(more), int(a[-1]) + REBASE_GAP + (b - b[0]))  # newest timer value seen
    assert dec.damage["board_restart"] == 1
    # the same BOOT frame twice is a duplicate, not a second restart
    boot = encode_info(0, 10e6, 160, 2, 0.0, flags=FLAG_BOOT)
    dec3 = Decoder()
    dec3.feed(boot + boot)
    assert dec3.damage["board_restart"] == 1 and dec3.damage["duplicate_frame"] == 1
    # a zero delta repeats an edge: that edge is dropped, the others kept
    raw = encode_frame(0x01, 0, 0, bytes.fromhex("10000000") + bytes.fromhex("c409" "0000" "c409"))
    dec4 = Decoder()
    np.testing.assert_array_equal(decoded_ticks(dec4.feed(raw)), [0x10, 0x10 + 2500, 0x10 + 5000])
    assert dec4.damage["non_increasing_edge"] == 1


def test_silent_counter_restart_is_followed() -> None:
    # the BOOT frame itself was lost: 32 frames from "behind" mean a restart; nothing of them is lost
    a = teeth_ticks(400, start=3_000_000_000)
    b = teeth_ticks(400, start=1000)
    dec = Decoder()
    got = decoded_ticks(dec.feed(Encoder(seq=1000).teeth(a)) + dec.feed(Encoder(seq=1, max_edges=8).teeth(b)))
    assert dec.damage["sequence_restart"] == 1
    assert got.size == a.size + b.size and np.all(np.diff(got) > 0)
    assert got[a.size] - got[a.size - 1] == REBASE_GAP  # no made-up interval across the restart
    np.testing.assert_array_equal(got[a.size:] - got[a.size], b - b[0])


def test_bad_lengths_and_unknown_types_counted() -> None:
    dec = Decoder()
    stream = (encode_frame(0x01, 0, 0, b"\x01\x02\x03") + encode_frame(0x03, 1, 0, b"\x00")
              + encode_frame(0x7E, 2, 0, b"hello") + encode_frame(0x04, 3, 0, b"\x00" * 14)
              + encode_heartbeat(4, 123) + encode_cam(5, [200]))
    frames = dec.feed(stream)
    assert dec.damage["bad_length"] == 2 and dec.damage["unknown_frame_type"] == 1
    assert dec.damage["bad_info_frame"] == 1
    assert [type(f) for f in frames] == [HeartbeatFrame, CamFrame]


def test_encoder_rejects_what_the_wire_cannot_carry() -> None:
    with pytest.raises(ValueError):
        encode_teeth(0, np.arange(127) * 10)
    with pytest.raises(ValueError):
        encode_teeth(0, [0, 70_000])
    with pytest.raises(ValueError):
        Encoder().teeth([5, 5])
    with pytest.raises(ValueError):
        encode_frame(1, 0, 0, bytes(256))


@FUZZ
@given(st.binary(max_size=2000), st.integers(1, 64))
def test_fuzz_random_bytes_never_crash(data: bytes, chunk: int) -> None:
    dec = Decoder(reorder_window=2)
    out = []
    for i in range(0, len(data), chunk):
        out += dec.feed(data[i:i + chunk])
    out += dec.flush()
    ticks = decoded_ticks(out)
    assert np.all(np.diff(ticks) > 0)
    assert dec.damage["garbage_bytes"] <= len(data)


OPS = st.sampled_from(["keep", "keep", "keep", "drop", "dup", "flip", "garbage", "swap"])


@FUZZ
@given(st.lists(OPS, min_size=5, max_size=40), st.binary(min_size=1, max_size=30), st.integers(0, 10**6))
def test_fuzz_damaged_stream_keeps_every_intact_frame(ops: list[str], junk: bytes, seed: int) -> None:
    t = teeth_ticks(len(ops) * 8, start=WRAP - 50_000 + seed, seed=seed)
    frames = split_frames(Encoder(max_edges=8).teeth(t))
    wire: list[bytes] = []
    intact: list[np.ndarray] = []
    i = 0
    while i < len(frames):
        op, f, mine = ops[i], frames[i], t[8 * i:8 * i + 8]
        if op == "swap" and i + 1 < len(frames):
            wire += [frames[i + 1], f]
            intact += [mine, t[8 * i + 8:8 * i + 16]]
            i += 2
            continue
        if op == "drop":
            pass
        elif op == "flip":
            b = bytearray(f)
            b[seed % len(b)] ^= 1 << (seed % 8)
            wire.append(bytes(b))
        else:
            wire += [f, f] if op == "dup" else [f] if op != "garbage" else [junk, f]
            intact.append(mine)
        i += 1
    dec = Decoder(reorder_window=2)
    got = decoded_ticks(dec.feed(b"".join(wire)) + dec.flush())
    assert np.all(np.diff(got) > 0)
    want = np.sort(np.concatenate(intact)) if intact else np.empty(0, np.int64)
    if got.size:  # the epoch of the first timer value is arbitrary: align on it (raw values are unique mod 2**32)
        got = got + int(t[np.flatnonzero(t % WRAP == got[0] % WRAP)[0]] - got[0])
    assert np.isin(want, got).all()  # good data never lost
    assert np.isin(got, t).all()  # and nothing made up
