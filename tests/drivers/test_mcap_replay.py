"""McapSource: URL options, as-fast-as-possible replay, start / seek, and pacing against a fake clock."""

from __future__ import annotations

from pathlib import Path

import pytest
from frictionwatch.drivers.errors import CorruptLog, EndOfStream
from frictionwatch.drivers.logs.mcap_log import LogReader, LogWriter
from frictionwatch.drivers.logs.mcap_replay import McapSource
from frictionwatch.drivers.source import open_source

from tests.drivers.mcap_corpus import ENGINE_TOML, INFO, assert_same_streams, corpus


@pytest.fixture(scope="module")
def log_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("replay") / "run.mcap"
    with LogWriter(path, ENGINE_TOML, INFO) as writer:
        for record in corpus(0.4, seed=21):
            writer.write(record)
    return path


def drain(source: McapSource, timeout: float | None = None) -> list:
    out = []
    while True:
        try:
            out += source.read(timeout)
        except EndOfStream:
            return out


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


def test_open_source_url_replays_everything_at_max_speed(log_path: Path) -> None:
    with LogReader(log_path) as reader:
        want = list(reader.records())
    with open_source(f"mcap:{log_path}") as source:
        assert isinstance(source, McapSource) and source.speed is None
        assert source.info == INFO and source.engine_toml == ENGINE_TOML
        got = drain(source)
        assert not source.damage
    assert_same_streams(got, want)
    assert len(got) == len(want)


def test_start_and_seek(log_path: Path) -> None:
    with LogReader(log_path) as reader:
        timed = list(reader.iter_timed())
    first = timed[0][0]
    with open_source(f"mcap:{log_path}?start=0.2&speed=max") as source:
        assert source.position_ns is not None and source.position_ns >= first + 200_000_000
        got = drain(source)
    assert len(got) == sum(1 for t, _ in timed if t >= first + 200_000_000)
    with McapSource(log_path) as source:
        source.read()
        source.seek(0.1)
        assert len(drain(source)) == sum(1 for t, _ in timed if t >= first + 100_000_000)
        source.seek(0.0)
        assert len(drain(source)) == len(timed)


def test_paced_replay_releases_records_by_log_time(log_path: Path) -> None:
    with LogReader(log_path) as reader:
        times = [t for t, _ in reader.iter_timed()]
    clock = FakeClock()
    with McapSource(log_path, speed=10.0, clock=clock, sleep=clock.sleep) as source:
        first = source.read(timeout=0)  # the anchor: the first record is due at once
        assert len(first) == sum(1 for t in times if t == times[0])
        clock.now += 0.005  # 5 ms of wall time = 50 ms of log time at 10x
        batch = source.read(timeout=0)
        assert len(batch) == sum(1 for t in times if times[0] < t <= times[0] + 50_000_000)
        assert source.read(timeout=0) == []  # nothing more is due yet: no wait beyond the timeout
        rest = drain(source, timeout=1.0)
    assert len(first) + len(batch) + len(rest) == len(times)
    total_log_s = (times[-1] - times[0]) / 1e9
    assert sum(clock.sleeps) == pytest.approx(total_log_s / 10 - 0.005, abs=1e-6)


def test_read_with_short_timeout_returns_empty_when_nothing_is_due(log_path: Path) -> None:
    clock = FakeClock()
    with McapSource(log_path, speed=1.0, clock=clock, sleep=clock.sleep) as source:
        source.read(timeout=0)
        while source.position_ns is not None:
            got = source.read(timeout=1e-6)
            if not got:
                assert clock.sleeps[-1] == pytest.approx(1e-6)
                break


@pytest.mark.parametrize(
    "url", ["mcap:x.mcap?speed=fast", "mcap:x.mcap?speed=0", "mcap:x.mcap?start=-1", "mcap:x.mcap?rate=2"]
)
def test_bad_options_are_value_errors(url: str) -> None:
    with pytest.raises(ValueError):
        open_source(url)


def test_closed_source_and_corrupt_file(log_path: Path, tmp_path: Path) -> None:
    source = McapSource(log_path)
    source.close()
    source.close()  # idempotent
    with pytest.raises(ValueError, match="closed"):
        source.read()
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x00" * 1000)
    with pytest.raises(CorruptLog):
        open_source(f"mcap:{bad}")


def _shape(record) -> tuple:
    """What a record is, its ticks as integers and its pressures: to compare passes moved by whole ticks."""
    from frictionwatch.drivers.logs.mcap_schema import last_tick
    from frictionwatch.drivers.source import StreamRestart

    if isinstance(record, StreamRestart):
        return ("restart", record.ticks)
    return (type(record).__name__, last_tick(record))


@pytest.mark.parametrize("start_s", [0.0, 0.1])
def test_every_pass_of_a_loop_is_the_first_moved_on(log_path: Path, start_s: float) -> None:
    """Each pass is the first pass's records moved by its span (first to last tick, by ``last_tick`` on every record
    of the first pass) plus LOOP_GAP_S, after a restart mark one tick past the pass before: also the passes whose span
    the source takes from the first whole pass rather than working it out again."""
    import math

    from frictionwatch.drivers.logs.mcap_replay import LOOP_GAP_S
    from frictionwatch.drivers.logs.mcap_schema import last_tick
    from frictionwatch.drivers.source import StreamRestart

    src = McapSource(log_path, loop=True, start_s=start_s)
    passes: list[list] = [[]]
    while len(passes) < 5:
        for r in src.read():
            if isinstance(r, StreamRestart):
                passes.append([r])
            else:
                passes[-1].append(r)
    src.close()
    keys = [math.floor(last_tick(r)) for r in passes[0]]
    span = max(keys) - min(keys) + round(LOOP_GAP_S * INFO.tick_hz)
    for p, records in enumerate(passes[1:4], start=1):
        assert records[0].ticks == max(keys) + (p - 1) * span + 1
        assert len(records) == len(passes[0]) + 1
        for first, again in zip(passes[0], records[1:], strict=True):
            name, tick = _shape(first)
            assert _shape(again) == (name, tick + p * span)


def test_a_seek_in_a_looped_pass_keeps_time_going_on(log_path: Path) -> None:
    """A seek in a later pass (whose span the source takes from the first whole pass): every restart mark still
    comes after every tick the stream has given before it, and every pass after the seek is a whole one again."""
    from frictionwatch.drivers.logs.mcap_schema import last_tick
    from frictionwatch.drivers.source import StreamRestart

    src = McapSource(log_path, loop=True, max_records=16)
    stream, sought = [], False
    while src.passes < 5:
        stream += src.read()
        if src.passes == 2 and not sought and len(stream) > 40:
            src.seek(0.2)
            sought = True
    src.close()
    newest, marks = -1.0, 0
    for r in stream:
        if isinstance(r, StreamRestart):
            assert r.ticks > newest
            marks += 1
        newest = max(newest, float(r.ticks if isinstance(r, StreamRestart) else last_tick(r)))
    assert sought and marks == 5


def test_a_shifted_record_is_the_record_with_its_ticks_moved() -> None:
    """``shifted`` builds each record kind field by field (design notes 70): the same as dataclasses.replace of its
    tick field, every other field the same object; a shift of 0 gives the record itself; anything else is refused."""
    import dataclasses

    import numpy as np
    from frictionwatch.core.types import (
        CamBatch,
        FreeEndToothBatch,
        LoadSample,
        PressureBlock,
        PressureFrame,
        ToothBatch,
    )
    from frictionwatch.drivers.logs.mcap_replay import shifted

    ticks = np.array([10, 25, 40], dtype=np.int64)
    values = np.array([[1.0e5, np.nan], [2.0e5, 3.0e5]])
    records = [ToothBatch(ticks), CamBatch(ticks[:1]), FreeEndToothBatch(ticks), LoadSample(7, 120.5, np.nan),
               PressureBlock(3, 11, 2.5, values[0]), PressureFrame((2, 5), 11, 2.5, values)]
    for record in records:
        moved = shifted(record, 1_000_003)
        field = "ticks" if hasattr(record, "ticks") else "t0_ticks"
        want = dataclasses.replace(record, **{field: getattr(record, field) + 1_000_003})
        assert type(moved) is type(record)
        for f in dataclasses.fields(record):
            got, expected = getattr(moved, f.name), getattr(want, f.name)
            if f.name == field:
                assert np.array_equal(got, expected) and np.asarray(got).dtype == np.asarray(expected).dtype
            else:
                assert got is getattr(record, f.name)
        assert shifted(record, 0) is record
    with pytest.raises(TypeError):
        shifted("not a record", 5)  # type: ignore[arg-type]
