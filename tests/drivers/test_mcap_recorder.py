"""Recorder: rotation keeps every file and the folder within bounds, every file replays on its own, nothing is lost
or duplicated across a rotation, numbering continues after a restart, and a crash leaves a readable file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.types import ToothBatch
from frictionwatch.drivers.logs.mcap_log import LogReader
from frictionwatch.drivers.logs.recorder import Recorder

from tests.drivers.mcap_corpus import ENGINE_TOML, INFO, assert_same_streams, corpus, streams


@pytest.fixture(scope="module")
def records() -> list:
    return corpus(5.0, seed=31)  # ~0.5 MB of log


@pytest.mark.parametrize(("max_file_bytes", "max_files"), [(128 * 1024, 3), (200_000, 2), (150_000, 1)])
def test_rotation_stays_within_bounds_and_every_file_replays(
    tmp_path: Path, records: list, max_file_bytes: int, max_files: int
) -> None:
    written: list[list] = []  # records per file, to compare each surviving file with what went into it
    with Recorder(tmp_path, ENGINE_TOML, INFO, max_file_bytes=max_file_bytes, max_files=max_files) as recorder:
        for record in records:
            if recorder.current is None or not written:
                written.append([])
            before = recorder.current
            recorder.write(record)
            if before is None:
                written[-1].append(record)
            elif recorder.current is None:  # this write closed the file
                written[-1].append(record)
                written.append([])
            else:
                written[-1].append(record)
    files = recorder.files
    written = [w for w in written if w]
    assert 1 <= len(files) <= max_files
    assert len(written) > max_files, "the corpus should force deletions"
    sizes = [f.stat().st_size for f in files]
    assert max(sizes) <= max_file_bytes and sum(sizes) <= max_files * max_file_bytes
    assert min(sizes[:-1], default=max_file_bytes) > max_file_bytes // 3, "rotating far too early"
    for path, want in zip(files, written[-len(files) :], strict=True):
        with LogReader(path) as reader:
            got = list(reader.records())
            assert not reader.damage and reader.info == INFO and reader.engine_toml == ENGINE_TOML
        assert_same_streams(got, want)


def test_numbering_continues_after_restart_and_old_files_go(tmp_path: Path, records: list) -> None:
    with Recorder(tmp_path, None, INFO, max_file_bytes=128 * 1024, max_files=2) as recorder:
        recorder.write_many(records[:200])
    first = recorder.files
    with Recorder(tmp_path, None, INFO, max_file_bytes=128 * 1024, max_files=2) as recorder:
        recorder.write_many(records[200:3000])
    second = recorder.files
    number = [int(p.name.split("-")[1]) for p in second]
    assert len(second) == 2 and number == sorted(number)
    assert min(number) > int(first[-1].name.split("-")[1]), "the first session's files were rotated out"


def test_bad_records_are_counted_not_raised(tmp_path: Path) -> None:
    with Recorder(tmp_path, None, INFO) as recorder:
        recorder.write(ToothBatch(np.array([5, 6], np.int64)))
        recorder.write(ToothBatch(np.array([0.5, 1.5])))  # float ticks cannot be logged
        recorder.write("garbage")  # type: ignore[arg-type]
    assert sum(recorder.skipped.values()) == 2
    (path,) = recorder.files
    with LogReader(path) as reader:
        (record,) = reader.records()
    np.testing.assert_array_equal(record.ticks, [5, 6])


def test_crash_leaves_a_readable_file(tmp_path: Path, records: list) -> None:
    """No close(): the file has no summary; every chunk already written still replays."""
    recorder = Recorder(tmp_path, ENGINE_TOML, INFO, max_file_bytes=4 << 20, chunk_bytes=16 * 1024)
    recorder.write_many(records)
    path = recorder.current
    assert path is not None
    data = path.read_bytes()  # what is on disk now: the open chunk is still in memory
    crashed = tmp_path / "crashed.mcap"
    crashed.write_bytes(data)
    with LogReader(crashed) as reader:
        got = list(reader.records())
        assert reader.damage["truncated"] == 1
    assert len(got) > 0
    have, want = streams(got), streams(records)
    np.testing.assert_array_equal(have["teeth"], want["teeth"][: len(have["teeth"])])  # a prefix of the input
    recorder.close()


def test_arguments_are_checked(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="max_file_bytes"):
        Recorder(tmp_path, None, INFO, max_file_bytes=1000)
    with pytest.raises(ValueError, match="max_files"):
        Recorder(tmp_path, None, INFO, max_files=0)
    with pytest.raises(ValueError, match="prefix"):
        Recorder(tmp_path, None, INFO, prefix="../x")
