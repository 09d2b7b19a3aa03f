"""The second wheel in the replay log (docs/replay-format.md §3, §4): channel ``free_end_teeth``, message
``frictionwatch.FreeEndToothBatch``, the flywheel teeth's clock; the ``wheel2_*`` acquisition keys.

A log without them reads as before (second_wheel None); one with them round-trips exactly; a reader that does not
know the message (an older one) skips and counts it and reads everything else.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.types import FreeEndToothBatch, ToothBatch, WheelInfo
from frictionwatch.drivers.logs import mcap_schema as ms
from frictionwatch.drivers.logs.mcap_log import LogReader, LogWriter
from mcap.reader import make_reader
from numpy.testing import assert_array_equal

from tests.drivers.mcap_corpus import ENGINE_TOML, INFO, corpus

INFO2 = ms.AcquisitionInfo(**{**INFO.__dict__, "second_wheel": WheelInfo(120, 1, 47.0)})


def free_end_edges(seconds: float, seed: int) -> list[FreeEndToothBatch]:
    """A 120-1 wheel at about 1500 rpm on the corpus's 10 MHz clock, in batches of 7 edges (any batching is valid)."""
    rng = np.random.default_rng(seed)
    pitch = 10e6 / 25.0 / 120  # ticks per tooth pitch
    k = np.arange(int(seconds * 25 * 120))
    ticks = np.round(1234 + k * pitch + rng.normal(0.0, 3.0, k.size)).astype(np.int64)[k % 120 != 119]
    return [FreeEndToothBatch(ticks[i:i + 7]) for i in range(0, ticks.size, 7)]


def write(path: Path, records, info=INFO2, batch_s=0.01) -> Path:
    with LogWriter(path, ENGINE_TOML, info, batch_s=batch_s) as writer:
        for r in records:
            writer.write(r)
    return path


@pytest.mark.parametrize("batch_s", [None, 0.01])
def test_second_wheel_round_trips(tmp_path: Path, batch_s) -> None:
    wheel2 = free_end_edges(0.3, 1)
    records = sorted(corpus(0.3, seed=2) + wheel2, key=lambda r: int(ms.last_tick(r)))
    path = write(tmp_path / "log.mcap", records, batch_s=batch_s)
    with LogReader(path) as reader:
        got = list(reader.records())
        assert not reader.damage
        assert reader.info == INFO2
    assert_array_equal(np.concatenate([r.ticks for r in got if isinstance(r, FreeEndToothBatch)]),
                       np.concatenate([r.ticks for r in wheel2]))
    assert_array_equal(np.concatenate([r.ticks for r in got if isinstance(r, ToothBatch)]),
                       np.concatenate([r.ticks for r in records if isinstance(r, ToothBatch)]))
    with open(path, "rb") as f:  # the channel and schema an outside reader sees
        topics = {(c.topic, s.name) for s, c, _ in make_reader(f).iter_messages() if c.topic == "free_end_teeth"}
    assert topics == {("free_end_teeth", "frictionwatch.FreeEndToothBatch")}


def test_a_log_without_it_reads_as_before(tmp_path: Path) -> None:
    path = write(tmp_path / "old.mcap", corpus(0.2, seed=3), info=INFO)
    with LogReader(path) as reader:
        assert reader.info.second_wheel is None
        assert not any(isinstance(r, FreeEndToothBatch) for r in reader.records())
    assert "wheel2_teeth" not in ms.acquisition_metadata(INFO)


def test_an_older_reader_skips_and_counts_it(tmp_path: Path, monkeypatch) -> None:
    records = sorted(corpus(0.2, seed=4) + free_end_edges(0.2, 5), key=lambda r: int(ms.last_tick(r)))
    path = write(tmp_path / "new.mcap", records)
    old = {k: v for k, v in ms.DECODERS.items() if not k.endswith("FreeEndToothBatch")}
    monkeypatch.setattr(ms, "DECODERS", old)  # a reader of the format before the second wheel
    with LogReader(path) as reader:
        got = list(reader.records())
        skipped = reader.damage["skipped message (unknown schema on topic 'free_end_teeth')"]
    assert skipped > 0 and sum(reader.damage.values()) == skipped
    assert not any(isinstance(r, FreeEndToothBatch) for r in got)
    assert len(got) > 0 and any(isinstance(r, ToothBatch) for r in got)


def test_bad_second_wheel_metadata_is_refused() -> None:
    data = ms.acquisition_metadata(INFO2)
    assert ms.acquisition_from_metadata(data) == INFO2
    bad = ms.with_crc({**data, "wheel2_missing": "120"})
    with pytest.raises(ValueError, match="second wheel 120-120"):
        ms.acquisition_from_metadata(bad)
