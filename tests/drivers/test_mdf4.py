"""MDF4 bus logs: the CSS CANedge J1939 samples in ../shared/realdata (numbers from their README), a frictionwatch log
written with python-can's own MF4Writer, and truncated / corrupt files."""

from __future__ import annotations

import gc
from pathlib import Path

import can
import numpy as np
import pytest
from frictionwatch.core.types import LoadSample, PressureBlock
from frictionwatch.drivers.can.codec import encode_load
from frictionwatch.drivers.can.decoder import CanDecoder
from frictionwatch.drivers.can.encoder import PressureEncoder
from frictionwatch.drivers.errors import CorruptLog, EndOfStream
from frictionwatch.drivers.logs.mdf4 import CanFrames, Mdf4Source, decode_signals, iter_messages, read_can_frames
from frictionwatch.drivers.source import open_source
from hypothesis import given, settings
from hypothesis import strategies as st

CSS = Path(__file__).resolve().parents[2] / "../shared/realdata/css-canedge-j1939-mf4"
TRUCK = CSS / "truck_j1939_idle_00000001.MF4"
PARKED = CSS / "j1939_FCBF0606_00000001-60B621D9.MF4"
DBC = CSS / "CSS-Electronics-SAE-J1939-DEMO.dbc"

needs_css = pytest.mark.skipif(not CSS.is_dir(), reason="../shared/realdata not present")


def replay(src) -> list:
    out = []
    with pytest.raises(EndOfStream):
        while True:
            out += src.read(timeout=1.0)
    return out


@needs_css
def test_truck_idle_engine_speed_matches_readme() -> None:
    frames = read_can_frames(TRUCK)
    assert len(frames) == 57_849  # README: 57,849 frames, 54 IDs, 127 s
    assert np.unique(frames.ids).size == 54 and 126 < frames.t[-1] - frames.t[0] < 128
    signals, damage = decode_signals(frames, DBC, ["EngineSpeed", "WheelBasedVehicleSpeed"])
    t, rpm = signals["EngineSpeed"]
    assert rpm.size == 12_719 and (rpm.min(), rpm.max()) == (646.5, 653.75)  # README, EEC1 SPN 190 at 100 Hz
    assert 99 < 1 / np.median(np.diff(t)) < 101
    assert np.all(signals["WheelBasedVehicleSpeed"][1] == 0) and not damage


@needs_css
def test_parked_truck_engine_speed_is_zero() -> None:
    signals, _ = decode_signals(read_can_frames(PARKED), DBC, ["EngineSpeed"])
    t, rpm = signals["EngineSpeed"]
    assert rpm.size > 0 and np.all(rpm == 0) and t[-1] - t[0] > 180  # README: EngineSpeed = 0 over 186 s


@needs_css
def test_foreign_log_replays_without_crash() -> None:
    with open_source(f"mdf4:{TRUCK}") as src:
        assert replay(src) == []
        assert src.damage["unknown_can_id"] == 57_849


@needs_css
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # asammdf's __del__ after a failed open
def test_truncated_and_corrupt_logs(tmp_path: Path) -> None:
    cut = tmp_path / "cut.MF4"
    cut.write_bytes(TRUCK.read_bytes()[:300_000])  # a copy in tmp_path only, never in the project
    try:
        frames = read_can_frames(cut)
    except CorruptLog:
        pass  # a clear typed error is fine
    else:
        assert len(frames) < 57_849  # or the readable part
    junk = tmp_path / "junk.MF4"
    junk.write_bytes(b"MDF     4.11    " + bytes(range(256)) * 10)
    with pytest.raises(CorruptLog):
        read_can_frames(junk)
    with pytest.raises(CorruptLog):
        read_can_frames(tmp_path / "missing.MF4")
    gc.collect()  # let asammdf's half-built objects go here, not in a later test


def test_frictionwatch_log_replays_like_the_live_decoder(tmp_path: Path) -> None:
    path = tmp_path / "fw.mf4"
    enc = PressureEncoder()
    writer = can.MF4Writer(str(path))
    live: list[can.Message] = []
    t = 100.0
    for k in range(20):
        for c in (1, 2):
            start = 7_000 + k * 50 * 500
            live += enc.block(c, start, 500.0, 2e5 + 1e4 * np.sin(np.arange(50) / 7 + c + k))
        live.append(encode_load(1.5e6, 9_000.0, counter=k))
    for m in live:
        m.timestamp = t
        m.channel = 0
        t += 0.0005
        writer.on_message_received(m)
    writer.stop()
    direct = CanDecoder().feed(live)
    with Mdf4Source(path, chunk=7) as src:
        replayed = replay(src)
        assert not src.damage
    b_direct = [(b.cylinder, b.t0_ticks) for b in direct if isinstance(b, PressureBlock)]
    v_direct = {c: np.concatenate([b.values for b in direct if isinstance(b, PressureBlock) and b.cylinder == c])
                for c in (1, 2)}
    for c in (1, 2):
        v = np.concatenate([b.values for b in replayed if isinstance(b, PressureBlock) and b.cylinder == c])
        np.testing.assert_array_equal(v, v_direct[c])
    assert b_direct[0] == (1, 7_000)
    assert sum(isinstance(r, LoadSample) for r in replayed) == sum(isinstance(r, LoadSample) for r in direct) == 20
    msgs = list(iter_messages(read_can_frames(path)))
    assert len(msgs) == len(live) and bytes(msgs[0].data) == bytes(live[0].data)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.lists(st.tuples(st.integers(0, 2**29 - 1), st.booleans(), st.integers(0, 8), st.binary(min_size=8,
                                                                                                  max_size=8)),
                max_size=50))
def test_fuzz_decode_signals_on_random_frames(rows: list) -> None:
    n = len(rows)
    frames = CanFrames(t=np.arange(n, dtype=float), ids=np.array([r[0] for r in rows], np.int64),
                       extended=np.array([r[1] for r in rows], bool), lengths=np.array([r[2] for r in rows], np.int64),
                       data=np.array([list(r[3]) for r in rows], np.uint8).reshape(n, 8),
                       channel=np.zeros(n, np.int64))
    from frictionwatch.drivers.can.codec import load_dbc

    signals, _damage = decode_signals(frames, load_dbc(), ["RealPower", "FrictionTorque", "Seq"])
    for t, v in signals.values():
        assert t.size == v.size
    if DBC.exists():
        decode_signals(frames, DBC)
