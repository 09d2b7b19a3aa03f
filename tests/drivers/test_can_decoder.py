"""CAN decoding and reassembly: round trips (CAN FD, classic), and every kind of bad input, plus hypothesis fuzzing.

The truth is a smooth seeded pressure trace p(cylinder, tick); every decoded sample must equal the truth at the time
its block says it was taken (to half a count of its frame's scale): that is what "never fabricate" means here.
"""

from __future__ import annotations

import itertools
import math

import can
import numpy as np
from frictionwatch.core.types import LoadSample, PressureBlock
from frictionwatch.drivers.can.codec import (
    encode_load,
    encode_pressure_classic,
    encode_pressure_fd,
    encode_pressure_ref,
    j1939_id,
)
from frictionwatch.drivers.can.decoder import MAX_BLOCK_S, CanDecoder
from frictionwatch.drivers.can.encoder import PressureEncoder
from frictionwatch.drivers.timebase import REBASE_GAP
from hypothesis import given, settings
from hypothesis import strategies as st

FUZZ = settings(max_examples=100, deadline=None, derandomize=True)
PERIOD = 10e6 / 48e3  # 48 kHz at 10 MHz: a non-integer period, 208.33 ticks
ATOL = 400.0  # Pa: half a count at the largest per-frame scale these traces need (17.5 MPa / 32766 / 2 = 267 Pa)


def truth(cyl: int, ticks: np.ndarray) -> np.ndarray:
    return 1e5 + 8e6 * (1 + np.sin(2 * np.pi * np.asarray(ticks, float) / 4e5 + cyl))


def fd_frames(cyls: tuple[int, ...], n_frames: int, t0: int = 1_000_000, period: float = PERIOD) -> list[can.Message]:
    """CAN FD frames of 25 samples, cylinders interleaved, host time 1 ms per frame slot."""
    enc = PressureEncoder(fd=True)
    out = []
    for f in range(n_frames):
        for c in cyls:
            start = t0 + f * 25 * period
            (msg,) = enc.block(c, round(start), period, truth(c, start + np.arange(25) * period))
            msg.timestamp = 1000.0 + f * 1e-3
            out.append(msg)
    return out


def blocks(records: list, cyl: int | None = None) -> list[PressureBlock]:
    return [r for r in records if isinstance(r, PressureBlock) and (cyl is None or r.cylinder == cyl)]


def assert_true_samples(records: list, atol: float = ATOL) -> int:
    """Every sample equals the truth at its stated time (within ``atol`` Pa); returns the number of samples."""
    total = 0
    for b in blocks(records):
        t = b.t0_ticks + np.arange(b.values.size) * b.period_ticks
        ok = np.isfinite(b.values)
        np.testing.assert_allclose(b.values[ok], truth(b.cylinder, t[ok]), rtol=0, atol=atol)
        total += b.values.size
    return total


def test_fd_round_trip_merges_and_chunks() -> None:
    msgs = fd_frames((1, 2, 20), 200)
    dec = CanDecoder()
    out = dec.feed(msgs)
    # 200 frames (0.104 s) per cylinder in one batch: joined, and cut every MAX_BLOCK_S (0.05 s) into three
    assert [len(blocks(out, c)) for c in (1, 2, 20)] == [3, 3, 3] and assert_true_samples(out) == 3 * 5000
    assert not dec.damage and blocks(out, 1)[0].t0_ticks == 1_000_000
    assert max(b.values.size * b.period_ticks for b in blocks(out)) <= MAX_BLOCK_S * 10e6
    for a, b in itertools.pairwise(blocks(out, 1)):
        assert abs(a.t0_ticks + a.values.size * a.period_ticks - b.t0_ticks) <= 1
    rng = np.random.default_rng(4)
    dec, out, i = CanDecoder(), [], 0
    while i < len(msgs):
        k = int(rng.integers(1, 50))
        out += dec.feed(msgs[i:i + k])
        i += k
    assert assert_true_samples(out) == 15000 and not dec.damage
    b1 = blocks(out, 1)
    for a, b in itertools.pairwise(b1):  # split only at batch edges, contiguous in time
        assert abs(a.t0_ticks + a.values.size * a.period_ticks - b.t0_ticks) <= 1


def test_classic_round_trip_with_references_and_partial_frames() -> None:
    enc = PressureEncoder(fd=False, ref_every=32)
    msgs = []
    for k in range(31):  # blocks of 100 samples: frames (3 samples) do not line up with blocks
        start = 5_000 + k * 100 * 2000
        for m in enc.block(3, start, 2000, truth(3, start + np.arange(100) * 2000.0)):
            m.timestamp = 1.0 + k * 0.02
            msgs.append(m)
    refs = sum(m.arbitration_id == 0x142 for m in msgs)
    assert refs == math.ceil(1033 / 32)
    dec = CanDecoder()
    out = dec.feed(msgs)
    # classic scale is fixed at 1000 Pa/count (DBC): half a count is 500 Pa; 3100 % 3 = 1 sample waits for more
    # (0.62 s of samples in one batch: joined, cut every MAX_BLOCK_S into 13 contiguous blocks)
    assert assert_true_samples(out, atol=500.0 + 1e-6) == 3099 and len(blocks(out)) == 13 and not dec.damage
    for a, b in itertools.pairwise(blocks(out)):
        assert a.t0_ticks + a.values.size * a.period_ticks == b.t0_ticks


def test_dropped_frame_splits_block_and_is_counted() -> None:
    msgs = fd_frames((1,), 100)
    dec = CanDecoder()
    out = dec.feed(msgs[:40] + msgs[41:]) + dec.flush()
    b = blocks(out)
    assert [x.values.size for x in b] == [40 * 25, 59 * 25] and dec.damage["frames_lost"] == 1
    assert b[1].t0_ticks == round(1_000_000 + 41 * 25 * PERIOD)
    assert_true_samples(out)


def test_duplicates_dropped_and_reordering_undone() -> None:
    msgs = fd_frames((1, 2), 60)
    dup = msgs[:30] + msgs[28:30] + msgs[30:]
    dec = CanDecoder()
    out = dec.feed(dup) + dec.flush()
    assert assert_true_samples(out) == 2 * 60 * 25 and dec.damage["duplicate_frame"] == 2
    swapped = msgs[:20] + [msgs[24], msgs[21], msgs[22], msgs[23], msgs[20]] + msgs[25:]
    dec = CanDecoder(reorder_window=4)
    out = dec.feed(swapped) + dec.flush()
    assert assert_true_samples(out) == 3000 and len(blocks(out, 1)) == 1 and not dec.damage["frames_lost"]
    dec = CanDecoder(reorder_window=0)
    out = dec.feed(swapped)
    assert dec.damage["late_frame"] >= 1 and dec.damage["frames_lost"] >= 1
    assert_true_samples(out)


def test_unknown_ids_wrong_dlc_and_error_frames_counted() -> None:
    good = fd_frames((5,), 10)
    short = encode_pressure_fd(5, 10, 0, PERIOD, np.ones(3))
    short.data = short.data[:48]
    short.dlc = 48
    std = {"is_extended_id": False}
    junk = [can.Message(arbitration_id=0x7FF, data=b"\x01", **std), can.Message(arbitration_id=0x100, data=bytes(8), **std),
            can.Message(arbitration_id=j1939_id(0xFEF1, 0), is_extended_id=True, data=bytes(8)),
            can.Message(arbitration_id=0x101, is_error_frame=True, **std), short,
            can.Message(arbitration_id=0x142, data=bytes(5), **std)]
    dec = CanDecoder()
    out = dec.feed(good[:5] + junk + good[5:])
    assert assert_true_samples(out) == 250
    assert dec.damage["unknown_can_id"] == 2 and dec.damage["wrong_dlc"] == 3
    assert dec.damage["can_error_or_remote_frame"] == 1


def test_saturation_invalid_and_sensor_fault_become_counted_nan() -> None:
    dec = CanDecoder()
    v = np.full(25, 2e6)
    v[3] = np.nan
    sat = np.zeros(25, bool)
    sat[[5, 6]] = True
    out = dec.feed([encode_pressure_fd(1, 0, 0, 500.0, v, saturated=sat),
                    encode_pressure_fd(1, 1, 12500, 500.0, np.full(10, 2e6), sensor_fault=True)])
    (b,) = blocks(out)
    assert b.values.size == 35 and np.isnan(b.values).sum() == 13
    assert dec.damage["sample_saturated"] == 2 and dec.damage["sample_invalid"] == 11


def test_overrun_time_gap_wrap_and_restart() -> None:
    dec = CanDecoder()
    t_hi = 2**32 - 30_000
    frames = [encode_pressure_fd(2, s, t_hi + s * 12_500, 500.0, np.full(25, 1e6)) for s in range(4)]
    frames.append(encode_pressure_fd(2, 4, t_hi + 6 * 12_500, 500.0, np.full(25, 1e6)))  # 2 frames' time missing
    frames.append(encode_pressure_fd(2, 5, t_hi + 7 * 12_500, 500.0, np.full(25, 1e6), daq_overrun=True))
    out = blocks(dec.feed(frames))
    assert [b.t0_ticks - t_hi for b in out] == [0, 6 * 12_500, 7 * 12_500]  # 2**32 crossed, unwrapped
    assert dec.damage["time_gap_in_sequence"] == 1 and dec.damage["daq_overrun"] == 1
    last = t_hi + 7 * 12_500
    after = dec.feed([encode_pressure_fd(2, 0, 100, 500.0, np.full(25, 1e6), restart=True),
                      encode_pressure_fd(2, 1, 12_600, 500.0, np.full(25, 1e6))])
    assert dec.damage["daq_restart"] == 1 and len(blocks(after)) == 1
    assert blocks(after)[0].t0_ticks == last + REBASE_GAP  # timer restarted: a long, honest gap


def test_classic_needs_a_fresh_reference() -> None:
    dec = CanDecoder(ref_timeout_s=1.0)
    a = encode_pressure_classic(1, 7, [1e5, 2e5, 3e5])
    a.timestamp = 0.0
    dec.feed([a])
    assert dec.damage["no_time_reference"] == 1
    ref = encode_pressure_ref(1, 8, 50_000, 100)
    ref.timestamp = 1.0
    b = encode_pressure_classic(1, 8, [1e5, 2e5, 3e5])
    b.timestamp = 1.0
    early = encode_pressure_classic(1, 5, [1e5, 2e5, 3e5])
    early.timestamp = 1.0
    late = encode_pressure_classic(1, 9, [1e5, 2e5, 3e5])
    late.timestamp = 3.0
    out = blocks(dec.feed([ref, b, early, late]))
    assert [(x.t0_ticks, x.values.size) for x in out] == [(50_000, 3)]
    assert dec.damage["before_time_reference"] == 1 and dec.damage["stale_time_reference"] == 1


def test_load_samples_on_the_pressure_clock() -> None:
    dec = CanDecoder(tick_hz=10e6)
    first = encode_load(1e6, 5000.0, counter=0)
    first.timestamp = 999.0
    dec.feed([first])
    assert dec.damage["load_without_time_reference"] == 1
    msgs = fd_frames((1,), 10)  # last frame received at 1000.009 s, its last sample at end tick
    end_tick = round(1_000_000 + 9 * 25 * PERIOD) + 25 * PERIOD
    loads = [encode_load(3.3e6, math.nan, counter=1), encode_load(3.3e6, 21_000.0, counter=1),
             encode_load(3.2e6, 20_000.0, counter=5, source_address=0x33)]
    for i, m in enumerate(loads):
        m.timestamp = 1000.019 + i * 0.01
    out = [r for r in dec.feed(msgs + loads) if isinstance(r, LoadSample)]
    assert len(out) == 2 and math.isnan(out[0].torque) and out[0].power == 3.3e6
    assert abs(out[0].ticks - (end_tick + 0.010 * 10e6)) <= 2
    assert dec.damage["load_duplicate_frame"] == 1 and dec.damage["load_frames_lost"] == 3
    assert dec.damage["load_value_not_available"] == 1
    only = CanDecoder(load_source_address=0xEA)
    only.feed(msgs + loads)
    assert only.damage["unknown_can_id"] == 1  # the frame from SA 0x33 is not our controller's


FRAME_IDS = st.sampled_from([0x100, 0x113, 0x140, 0x160, 0x7FF, 0x18FF10EA, 0x18FF2080, 0x0CF00400])


@FUZZ
@given(st.lists(st.tuples(FRAME_IDS, st.binary(max_size=64), st.floats(0, 10)), max_size=60))
def test_fuzz_random_frames_never_crash(frames: list) -> None:
    msgs = [can.Message(arbitration_id=i, is_extended_id=i > 0x7FF, is_fd=len(d) > 8, data=d, timestamp=t)
            for i, d, t in frames]
    dec = CanDecoder()
    out = dec.feed(msgs) + dec.flush()
    for b in blocks(out):
        assert b.values.size >= 1 and b.values.dtype == np.float64 and math.isfinite(b.period_ticks)
    assert all(isinstance(r, (PressureBlock, LoadSample)) for r in out)


@FUZZ
@given(st.lists(st.sampled_from(["keep", "keep", "keep", "drop", "dup", "swap"]), min_size=3, max_size=40),
       st.integers(0, 2**32 - 1))
def test_fuzz_damaged_stream_never_fabricates(ops: list[str], t0: int) -> None:
    msgs = fd_frames((1, 2), len(ops), t0=t0)
    wire, intact, i = [], 0, 0
    while i < len(ops):
        pair = msgs[2 * i:2 * i + 2]
        if ops[i] == "swap" and i + 1 < len(ops):
            wire += msgs[2 * i + 2:2 * i + 4] + pair
            intact += 4
            i += 2
            continue
        if ops[i] != "drop":
            wire += pair * (2 if ops[i] == "dup" else 1)
            intact += 2
        i += 1
    dec = CanDecoder(reorder_window=4)
    out = dec.feed(wire) + dec.flush()
    # the first timer value seen sets the epoch: a stream first seen after 2**32 unwraps one wrap lower
    shift = 2**32 if blocks(out) and min(b.t0_ticks for b in blocks(out)) < t0 else 0
    for b in blocks(out):
        t = b.t0_ticks + shift + np.arange(b.values.size) * b.period_ticks
        np.testing.assert_allclose(b.values, truth(b.cylinder, t), rtol=0, atol=ATOL)
    assert sum(b.values.size for b in blocks(out)) == intact * 25  # good data never lost


@FUZZ
@given(st.lists(st.sampled_from(["keep", "keep", "keep", "drop", "dup", "swap"]), min_size=3, max_size=30),
       st.lists(st.integers(1, 89), max_size=4), st.integers(0, 2**32 - 1))
def test_cylinders_decoded_together_as_each_alone(ops: list[str], cuts: list[int], t0: int) -> None:
    """The decoder assembles the cylinders of a batch in one pass (the ones whose counters simply continue) and the
    others frame by frame: each cylinder's blocks and counts must be those of its frames decoded on their own, with
    damage (drops, duplicates, swaps) on some cylinders and batch boundaries anywhere."""
    msgs = fd_frames((1, 2, 3), len(ops), t0=t0)
    wire = []
    for i, op in enumerate(ops):  # cylinder 2 keeps every frame; 1 and 3 take the damage
        for m in msgs[3 * i:3 * i + 3]:
            damaged = m.arbitration_id != msgs[1].arbitration_id
            if damaged and op == "drop":
                continue
            wire += [m, m] if damaged and op == "dup" else [m]
            if damaged and op == "swap" and len(wire) >= 4:
                wire[-1], wire[-4] = wire[-4], wire[-1]
    bounds = sorted({c for c in cuts if c < len(wire)})
    batches = [wire[a:b] for a, b in itertools.pairwise([0, *bounds, len(wire)])]
    together = CanDecoder(reorder_window=3)
    out = [r for b in batches for r in together.feed(b)] + together.flush()
    damage: dict[str, int] = {}
    for cyl_id in {m.arbitration_id for m in msgs}:
        alone = CanDecoder(reorder_window=3)
        mine = [[m for m in b if m.arbitration_id == cyl_id] for b in batches]
        ref = blocks([r for b in mine for r in alone.feed(b)] + alone.flush())
        got = [b for b in blocks(out) if ref and b.cylinder == ref[0].cylinder]
        assert [(b.t0_ticks, b.period_ticks) for b in got] == [(b.t0_ticks, b.period_ticks) for b in ref]
        for g, r in zip(got, ref, strict=True):
            np.testing.assert_allclose(g.values, r.values, rtol=0, atol=0)
        for k, v in alone.damage.items():
            damage[k] = damage.get(k, 0) + v
    assert {k: v for k, v in together.damage.items() if v} == {k: v for k, v in damage.items() if v}
