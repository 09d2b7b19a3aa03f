"""docs/replay-format.md is a working contract: its example writer produces a log LogReader reads, its proto block and
channel table are the schema the code builds, and its metadata keys are the ones the code writes."""

from __future__ import annotations

import json
import re
import runpy
from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.types import AcquisitionInfo, LoadSample, PressureBlock, PressureFrame, ToothBatch
from frictionwatch.drivers.logs import mcap_schema as ms
from frictionwatch.drivers.logs.mcap_log import LogReader
from google.protobuf import descriptor_pb2

DOC = Path(__file__).resolve().parents[2] / "docs" / "replay-format.md"
F = descriptor_pb2.FieldDescriptorProto
PROTO_TYPES = {"int64": F.TYPE_INT64, "uint32": F.TYPE_UINT32, "double": F.TYPE_DOUBLE, "sint32": F.TYPE_SINT32,
               "string": F.TYPE_STRING}


def blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", DOC.read_text(), flags=re.DOTALL)


def test_example_writer_makes_a_log_the_reader_reads(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (code,) = blocks("python")
    assert 25 <= len(code.splitlines()) <= 45, "the example should stay about 30 lines"
    script = tmp_path / "example_writer.py"
    script.write_text(code)
    monkeypatch.chdir(tmp_path)
    runpy.run_path(str(script), run_name="__main__")
    with LogReader(tmp_path / "example.mcap") as reader:
        records = list(reader.records())
        assert not reader.damage
        assert reader.info.tick_hz == 10e6 and (reader.info.wheel_teeth, reader.info.wheel_missing) == (60, 2)
        assert reader.info.cam_deg is None and reader.info.pressure_cylinders == (1, 2)
        assert reader.engine_toml == 'name = "my-engine"\n'
    teeth = np.concatenate([r.ticks for r in records if isinstance(r, ToothBatch)])
    assert teeth.size == 2900 and np.all(np.diff(teeth) > 0)  # 50 revolutions of 58 teeth
    assert not any(isinstance(r, PressureBlock) for r in records)
    pressure = [r for r in records if isinstance(r, PressureFrame)]
    assert len(pressure) == 200 and all(r.cylinders == (1, 2) and r.values.shape == (2, 200) for r in pressure)
    assert pressure[1].t0_ticks == pressure[0].t0_ticks + 200 * pressure[0].period_ticks  # contiguous 20 kHz
    values = np.concatenate([r.values for r in pressure], axis=1)
    assert np.all(values >= 1e5) and not np.array_equal(values[0], values[1])
    assert sum(isinstance(r, LoadSample) for r in records) == 200


def test_proto_block_is_the_schema_the_code_builds() -> None:
    (proto,) = blocks("proto")
    documented: dict[str, set[tuple[str, int, int, bool]]] = {}
    for name, body in re.findall(r"message (\w+) \{(.*?)\n\}", proto, flags=re.DOTALL):
        fields = re.findall(r"^\s*(repeated )?(\w+) (\w+) = (\d+);", body, flags=re.MULTILINE)
        documented[name] = {(f, int(n), PROTO_TYPES[t], bool(rep)) for rep, t, f, n in fields}
    built = {name: set(fields) for name, (_, fields) in ms.MESSAGES.items()}
    assert documented == built
    topics = dict(re.findall(r"^\| `(\w+)` \| `frictionwatch\.(\w+)` \|", DOC.read_text(), flags=re.MULTILINE))
    assert {v: k for k, v in topics.items()} == ms.TOPICS


def test_metadata_keys_are_documented() -> None:
    text = DOC.read_text()
    keys = set(ms.acquisition_metadata(AcquisitionInfo(1e6, 60, 2, 0.0, 1.0, (1,))))
    for key in keys | {ms.ENGINE_KEY, ms.META_ENGINE, ms.META_ACQUISITION}:
        assert f"`{key}`" in text, key
    example = json.loads(blocks("json")[0])
    assert {"fmep_bar", "cylinders", "cycles", "effects"} <= set(example)
    assert set(example["cylinders"][0]) >= {"cylinder", "friction_torque_mean_nm", "coefficients"}
    assert len(example["cylinders"][0]["coefficients"]) == 6
