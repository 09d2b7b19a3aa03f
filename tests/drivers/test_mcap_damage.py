"""Damaged logs: truncation at any byte, flipped bytes, garbage bursts. Every intact chunk's records must come out,
in log-time order, nothing that was not written, damage counted, and only CorruptLog ever raised.

The truth (which chunk holds which message, at which file offsets) comes from mcap's own SeekingReader on the
intact file, not from the scanner under test.
"""

from __future__ import annotations

import io
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.types import CamBatch, PressureBlock, ToothBatch
from frictionwatch.drivers.errors import CorruptLog
from frictionwatch.drivers.logs import mcap_schema as ms
from frictionwatch.drivers.logs.mcap_log import LogReader, LogWriter
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk

from tests.drivers.mcap_corpus import ENGINE_TOML, INFO, corpus


def fingerprint(record) -> tuple:
    if isinstance(record, ToothBatch | CamBatch):
        return type(record).__name__, record.ticks.tobytes()
    if isinstance(record, PressureBlock):
        return "p", record.cylinder, record.t0_ticks, record.period_ticks, record.values.tobytes()
    return "load", record.ticks, record.torque, record.power if record.power == record.power else "nan"


class Original:
    """An intact log with small chunks, and per chunk its byte span and messages (log_time, fingerprint)."""

    def __init__(self, folder: Path) -> None:
        self.path = folder / "original.mcap"
        with LogWriter(self.path, ENGINE_TOML, INFO, chunk_bytes=4000) as writer:
            for record in corpus(0.25, seed=11):
                writer.write(record)
        self.data = self.path.read_bytes()
        with open(self.path, "rb") as f:
            summary = make_reader(f).get_summary()
        assert summary is not None
        decoders = {c.id: ms.DECODERS[summary.schemas[c.schema_id].name] for c in summary.channels.values()}
        self.chunks: list[tuple[int, int, list[tuple[int, tuple]]]] = []
        for index in summary.chunk_indexes:
            chunk = Chunk.read(ReadDataStream(io.BytesIO(self.data[index.chunk_start_offset + 9 :])))
            messages = [
                (m.log_time, fingerprint(decoders[m.channel_id](m.data)))
                for m in breakup_chunk(chunk, validate_crc=True)
                if isinstance(m, Message)
            ]
            self.chunks.append((index.chunk_start_offset, index.chunk_start_offset + index.chunk_length, messages))
        self.all = Counter(m for *_, messages in self.chunks for m in messages)
        assert len(self.chunks) >= 10

    def intact(self, damaged: range) -> Counter:
        """Messages of the chunks whose bytes do not overlap ``damaged``."""
        return Counter(
            m for start, end, messages in self.chunks if end <= damaged.start or start >= damaged.stop for m in messages
        )


@pytest.fixture(scope="module")
def original(tmp_path_factory: pytest.TempPathFactory) -> Original:
    return Original(tmp_path_factory.mktemp("damage"))


def read_back(path: Path) -> tuple[list[tuple[int, tuple]] | None, Counter]:
    """(messages read, damage); None if CorruptLog was raised (the only exception allowed)."""
    try:
        with LogReader(path) as reader:
            try:
                got = [(t, fingerprint(r)) for t, r in reader.iter_timed()]
            except CorruptLog:
                return None, reader.damage
            return got, reader.damage
    except CorruptLog:
        return None, Counter()


def check(original: Original, damaged_file: bytes, damaged: range, path: Path) -> Counter | None:
    """Assert the damage contract; the damage counter, or None if CorruptLog was raised (allowed if nothing intact)."""
    path.write_bytes(damaged_file)
    got, damage = read_back(path)
    want = original.intact(damaged)
    if got is None:
        assert not want, f"CorruptLog although {sum(want.values())} messages were intact"
        return None
    times = [t for t, _ in got]
    assert times == sorted(times), "not in log-time order"
    assert not Counter(got) - original.all, "yielded something that was never written"
    missing = want - Counter(got)
    assert not missing, f"{sum(missing.values())} intact messages lost; damage {dict(damage)}"
    return damage


FAST = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@FAST
@given(cut=st.integers(min_value=0, max_value=10**9))
def test_truncated_anywhere(original: Original, tmp_path: Path, cut: int) -> None:
    cut %= len(original.data)
    damage = check(original, original.data[:cut], range(cut, len(original.data)), tmp_path / "cut.mcap")
    assert damage is None or damage["truncated"] >= 1, "a cut file must report it"


@FAST
@given(offset=st.integers(min_value=0, max_value=10**9), xor=st.integers(min_value=1, max_value=255))
def test_flipped_byte_anywhere(original: Original, tmp_path: Path, offset: int, xor: int) -> None:
    offset %= len(original.data)
    data = bytearray(original.data)
    data[offset] ^= xor
    check(original, bytes(data), range(offset, offset + 1), tmp_path / "flip.mcap")


@FAST
@given(offset=st.integers(min_value=0, max_value=10**9), length=st.integers(1, 3000), seed=st.integers(0, 2**32 - 1))
def test_garbage_burst(original: Original, tmp_path: Path, offset: int, length: int, seed: int) -> None:
    offset %= len(original.data)
    data = bytearray(original.data)
    burst = np.random.default_rng(seed).integers(0, 256, length, dtype=np.uint8).tobytes()
    data[offset : offset + length] = burst[: len(data) - offset]
    check(original, bytes(data), range(offset, offset + length), tmp_path / "burst.mcap")


def test_corrupt_chunk_is_counted_and_skipped(original: Original, tmp_path: Path) -> None:
    start, end, _ = original.chunks[4]
    data = bytearray(original.data)
    data[(start + end) // 2] ^= 0x40  # inside the compressed records
    damage = check(original, bytes(data), range(start, end), tmp_path / "c.mcap")
    assert damage is not None
    assert sum(v for k, v in damage.items() if k.startswith("corrupt chunk")) == 1
    assert sum(damage.values()) == 1


def test_truncated_file_recovers_part_of_the_cut_chunk(original: Original, tmp_path: Path) -> None:
    _, end, _ = original.chunks[-1]
    cut = end - 10  # the last chunk loses its tail; its leading zstd blocks are still readable
    damage = check(original, original.data[:cut], range(cut, len(original.data)), tmp_path / "t.mcap")
    assert damage is not None and damage["truncated"] >= 1 and damage["partial chunk"] == 1


def test_seek_into_a_log_without_summary(original: Original, tmp_path: Path) -> None:
    """The channel definitions sit in the first chunk only; a window that skips it must still decode."""
    path = tmp_path / "nosummary.mcap"
    start = original.chunks[-1][0]
    path.write_bytes(original.data[:start])
    middle = original.chunks[len(original.chunks) // 2][2][0][0]
    with LogReader(path) as reader:
        got = [t for t, _ in reader.iter_timed(start_ns=middle)]
        assert got and got[0] >= middle
        assert not any(k.startswith("skipped") for k in reader.damage)


@pytest.mark.parametrize("content", [b"", b"hello, not an mcap file at all" * 100, bytes(range(256)) * 50])
def test_not_an_mcap_raises_corrupt_log(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(content)
    with pytest.raises(CorruptLog):
        LogReader(path)


def test_log_with_metadata_only_raises_from_records(original: Original, tmp_path: Path) -> None:
    path = tmp_path / "head.mcap"
    path.write_bytes(original.data[: original.chunks[0][0] + 20])  # metadata intact, first chunk cut short
    with LogReader(path) as reader:
        assert reader.info == INFO
        with pytest.raises(CorruptLog, match="no readable record"):
            list(reader.records())
