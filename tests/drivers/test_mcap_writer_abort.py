"""A LogWriter left by an exception does not finish the log: a reader says it is truncated, not complete."""

from __future__ import annotations

from pathlib import Path

import pytest
from frictionwatch.drivers.logs.mcap_log import LogReader, LogWriter

from tests.drivers.mcap_corpus import ENGINE_TOML, INFO, corpus


@pytest.mark.parametrize("error", [KeyboardInterrupt, OSError])
def test_exception_inside_the_block_leaves_a_log_that_reads_as_truncated(tmp_path: Path, error) -> None:
    records = corpus(seconds=1.0)
    path = tmp_path / "cut.mcap"
    with pytest.raises(error), LogWriter(path, ENGINE_TOML, INFO, chunk_bytes=16_000) as writer:
        for record in records[: len(records) // 2]:
            writer.write(record)
        assert writer.chunks_written > 2
        raise error
    with LogReader(path) as reader:
        got = list(reader.records())
        assert reader.damage["truncated"] == 1
    assert 0 < len(got) < len(records) // 2  # the chunks already out, not the open one
    writer.abort()  # idempotent, as close() is
    writer.close()


def test_clean_exit_still_finishes_the_log(tmp_path: Path) -> None:
    records = corpus(seconds=0.2)
    path = tmp_path / "whole.mcap"
    with LogWriter(path, ENGINE_TOML, INFO) as writer:
        for record in records:
            writer.write(record)
    with LogReader(path) as reader:
        assert len(list(reader.records())) > 0 and not reader.damage
