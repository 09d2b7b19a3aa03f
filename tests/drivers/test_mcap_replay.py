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
