"""A PressureFrame message decoded by the compiled pass (drivers/logs/mcap_frame_kernel.py, design note 94) is the
record the reference (mcap_schema ``_decode_frame``, upb) decodes, or fails with the reference's error: every frame
of the replay logs, crafted frames of each kind the kernel declines, and seeded byte damage."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.types import PressureFrame
from frictionwatch.drivers.logs import mcap_schema as ms
from frictionwatch.drivers.logs.mcap_frame_kernel import DECLINED, frame_counts, ticks_kernel
from frictionwatch.drivers.logs.mcap_log import LogReader
from frictionwatch.drivers.logs.mcap_scan import chunk_records

LOGS = sorted((Path(__file__).resolve().parents[2] / "replay_logs").glob("*.mcap"))


def frame_messages(path: Path) -> list[bytes]:
    with LogReader(path) as log:
        topic = {cid: ch.topic for cid, ch in log._channels.items()}
        return [item[3] for ref in log._scan.chunks for item in chunk_records(log._buf, ref, log._note)
                if isinstance(item, tuple) and topic.get(item[0]) == "pressure_frames"]


def outcome(decode, data: bytes):
    try:
        return decode(data)
    except ms.DECODE_ERRORS as exc:
        return (type(exc).__name__, str(exc))


def assert_same(data: bytes) -> None:
    """Both decoders give one record (integers exactly; the values are the same float64 products, so tolerance 0,
    NaN where NaN) or one error."""
    ref, fast = outcome(ms._decode_frame, data), outcome(ms._decode_frame_fast, data)
    if not isinstance(ref, PressureFrame):
        assert fast == ref
        return
    assert isinstance(fast, PressureFrame)
    assert fast.cylinders == ref.cylinders and all(type(c) is int for c in fast.cylinders)
    assert fast.t0_ticks == ref.t0_ticks and type(fast.t0_ticks) is int
    assert fast.period_ticks == ref.period_ticks
    assert fast.values.dtype == np.float64 and fast.values.shape == ref.values.shape
    np.testing.assert_allclose(fast.values, ref.values, rtol=0, atol=0, equal_nan=True)


def declined(data: bytes) -> bool:
    return frame_counts(data)[0] == DECLINED


@pytest.mark.parametrize("path", LOGS, ids=lambda p: p.stem)
def test_every_frame_of_the_replay_logs(path):
    frames = frame_messages(path)
    assert frames
    for data in frames:
        assert_same(data)
    # the kernel decodes every frame in the counts form (a log's first frames may be values_pa: no step known yet)
    values_form = sum(1 for d in frames if ms._CLASSES["PressureFrame"].FromString(d).values_pa)
    assert sum(declined(d) for d in frames) == values_form < len(frames)


def encoded(values: np.ndarray, cylinders=(1, 2, 3), t0=1_000_000, period=125.5) -> bytes:
    counts = ms.PressureCounts()
    frame = PressureFrame(cylinders, t0, period, values)
    counts.frame_fields(frame)  # learn each row's step
    return ms.encode(frame, counts)[1]


def counts_frame(seed: int = 0, nan_at=()) -> bytes:
    rng = np.random.default_rng(seed)
    counts = rng.integers(-70_000, 2_000_000, (3, 50))
    counts[:, :2] = (5, 6)  # each row's step is the smallest gap between its values: one step apart somewhere
    values = counts.astype(np.float64) * np.array([[7.5], [0.25], [12.0]])
    values.ravel()[list(nan_at)] = np.nan
    return encoded(values)


def raw(fields: list[tuple[int, int, bytes]]) -> bytes:
    """A message from (field, wire type, payload) in the given order (payload: the bytes after the tag; a length
    prefix is added for wire type 2)."""
    out = b""
    for f, wt, payload in fields:
        out += varint(f << 3 | wt) + (varint(len(payload)) + payload if wt == 2 else payload)
    return out


def varint(v: int) -> bytes:
    v &= (1 << 64) - 1
    out = b""
    while True:
        b, v = v & 0x7F, v >> 7
        out += bytes([b | (0x80 if v else 0)])
        if not v:
            return out


def zigzag(c: int) -> int:
    return (c << 1) ^ (c >> 31)


def test_counts_frames_with_and_without_invalid_samples():
    for data in (counts_frame(1), counts_frame(2, nan_at=(3, 7, 149))):
        assert not declined(data)
        assert_same(data)
    frame = ms._decode_frame_fast(counts_frame(2, nan_at=(3, 7, 149)))
    assert np.isnan(frame.values.ravel()[[3, 7, 149]]).all() and np.isfinite(frame.values).sum() == 147


def test_declined_kinds_decode_or_fail_as_the_reference():
    counts = [5, -3, 0, 2**31 - 1, -(2**31), 1]
    packed = b"".join(varint(zigzag(c)) for c in counts)
    scales = np.array([2.0, 0.5]).tobytes()
    base = [(1, 2, varint(1) + varint(2)), (2, 0, varint(77)), (3, 1, np.float64(10.0).tobytes()),
            (4, 0, varint(3)), (6, 2, scales), (7, 2, packed)]
    assert not declined(raw(base))
    assert_same(raw(base))
    np.testing.assert_allclose(ms._decode_frame_fast(raw(base)).values,
                               np.array(counts, float).reshape(2, 3) * [[2.0], [0.5]], rtol=0, atol=0)
    cases = {
        "fields in another order": [base[5], *base[:5]],
        "an unknown field": [*base, (9, 0, varint(4))],
        "a field twice": [*base, (2, 0, varint(78))],
        "counts not packed": [*base[:5], *((7, 0, varint(zigzag(c))) for c in counts)],
        "a negative t0": [base[0], (2, 0, varint(-5)), *base[2:]],
        "values_pa as well": [*base, (5, 2, np.zeros(6).tobytes())],
        "one count short": [*base[:5], (7, 2, packed[:-1])],
        "a count too many": [*base[:5], (7, 2, packed + varint(2))],
        "a zero scale": [*base[:4], (6, 2, np.array([2.0, 0.0]).tobytes()), base[5]],
        "one scale": [*base[:4], (6, 2, scales[:8]), base[5]],
        "a repeated cylinder": [(1, 2, varint(2) + varint(2)), *base[1:]],
        "cylinder 0": [(1, 2, varint(0) + varint(2)), *base[1:]],
        "no period": [base[0], base[1], *base[3:]],
        "a NaN period": [base[0], base[1], (3, 1, np.float64(np.nan).tobytes()), *base[3:]],
        "an invalid index past the samples": [*base, (8, 2, varint(6))],
        "an invalid index": [*base, (8, 2, varint(5) + varint(0))],
        "no samples": [base[0], *base[1:3], *base[4:]],
        "period as a varint": [base[0], base[1], (3, 0, varint(10)), *base[3:]],
    }
    for name, fields in cases.items():
        assert_same(raw(fields)), name
    assert not declined(raw(cases["fields in another order"]))  # canonical in every field: decoded, any order
    assert not declined(raw(cases["a negative t0"]))
    assert not declined(raw(cases["an invalid index"]))
    for name in ("an unknown field", "a field twice", "counts not packed", "values_pa as well", "a zero scale"):
        assert declined(raw(cases[name])), name


def test_damaged_bytes_decode_or_fail_as_the_reference():
    """Seeded damage to real and crafted frames: cut short, a byte changed, a byte dropped or doubled."""
    rng = random.Random(94)
    frames = [counts_frame(3, nan_at=(4,)), frame_messages(LOGS[0])[5]]
    for data in frames:
        for _ in range(150):
            i = rng.randrange(len(data))
            kind = rng.randrange(4)
            if kind == 0:
                bad = data[:i]
            elif kind == 1:
                bad = data[:i] + bytes([rng.randrange(256)]) + data[i + 1:]
            elif kind == 2:
                bad = data[:i] + data[i + 1:]
            else:
                bad = data[:i] + data[i:i + 1] + data[i:]
            assert_same(bad)


TEETH = {"teeth": "ToothBatch", "cam": "CamBatch", "free_end_teeth": "FreeEndToothBatch"}


def tick_messages(path: Path) -> list[tuple[str, bytes]]:
    with LogReader(path) as log:
        topic = {cid: ch.topic for cid, ch in log._channels.items()}
        return [(TEETH[topic[item[0]]], item[3]) for ref in log._scan.chunks
                for item in chunk_records(log._buf, ref, log._note)
                if isinstance(item, tuple) and topic.get(item[0]) in TEETH]


def assert_same_ticks(name: str, data: bytes) -> None:
    """The batch's ticks (integers: exactly) or the reference's error."""
    ref = outcome(lambda d: ms.teeth_ticks_reference(name, d), data)
    fast = outcome(lambda d: ms.DECODERS[f"{ms.PACKAGE}.{name}"](d), data)
    if isinstance(ref, tuple):
        assert fast == ref
        return
    assert type(fast).__name__ == name and fast.ticks.dtype == np.int64
    np.testing.assert_array_equal(fast.ticks, ref)


@pytest.mark.parametrize("path", LOGS, ids=lambda p: p.stem)
def test_every_tooth_and_cam_batch_of_the_replay_logs(path):
    messages = tick_messages(path)
    assert "ToothBatch" in {n for n, _ in messages}  # (deutz-1cyl has no cam)
    for name, data in messages:
        assert_same_ticks(name, data)
        assert ticks_kernel(np.frombuffer(data, np.uint8))[0] == 0  # as our writer makes them: all compiled


def test_crafted_and_damaged_tick_batches():
    ticks = [0, 1, 127, 128, 2**40 + 3, 2**62, -1, -(2**63)]
    packed = b"".join(varint(t) for t in ticks)
    cases = [raw([(1, 2, packed)]), raw([(1, 2, packed), (1, 2, varint(9))]),  # packed twice: concatenated
             b"".join(raw([(1, 0, varint(t))]) for t in ticks),  # not packed
             raw([(1, 2, packed), (2, 0, varint(1))]), b"", raw([(1, 2, packed[:-1])])]
    for data in cases:
        assert_same_ticks("ToothBatch", data)
    np.testing.assert_array_equal(ms.DECODERS[f"{ms.PACKAGE}.CamBatch"](cases[0]).ticks, ticks)
    rng = random.Random(9400)
    data = tick_messages(LOGS[0])[3][1]
    for _ in range(300):
        i = rng.randrange(len(data))
        bad = [data[:i], data[:i] + bytes([rng.randrange(256)]) + data[i + 1:], data[:i] + data[i + 1:]][i % 3]
        assert_same_ticks("ToothBatch", bad)
