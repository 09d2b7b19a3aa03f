"""LogWriter / LogReader round trips, the log-time rule, metadata, validation, and readability by mcap's readers."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.types import AcquisitionInfo, CamBatch, LoadSample, PressureBlock, PressureFrame, ToothBatch
from frictionwatch.drivers.logs import mcap_schema as ms
from frictionwatch.drivers.logs.mcap_log import LogReader, LogWriter
from google.protobuf import descriptor_pb2
from mcap.reader import make_reader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import Writer
from mcap_protobuf.decoder import DecoderFactory

from tests.drivers.mcap_corpus import ENGINE_TOML, INFO, assert_same_streams, corpus


def write(path: Path, records, **kwargs) -> Path:
    with LogWriter(path, kwargs.pop("engine_toml", ENGINE_TOML), kwargs.pop("info", INFO), **kwargs) as writer:
        for record in records:
            writer.write(record)
    return path


def same_record(a, b) -> bool:
    if type(a) is not type(b):
        return False
    if isinstance(a, ToothBatch | CamBatch):
        return a.ticks.dtype == b.ticks.dtype == np.int64 and np.array_equal(a.ticks, b.ticks)
    if isinstance(a, PressureBlock):
        return (a.cylinder, a.t0_ticks, a.period_ticks) == (b.cylinder, b.t0_ticks, b.period_ticks) and np.array_equal(
            a.values, b.values, equal_nan=True
        )
    if isinstance(a, PressureFrame):
        return (a.cylinders, a.t0_ticks, a.period_ticks) == (b.cylinders, b.t0_ticks, b.period_ticks) and (
            a.values.dtype == b.values.dtype == np.float64 and a.values.tobytes() == b.values.tobytes()
        )
    return a == b


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_one_message_per_record_round_trips_exactly(tmp_path: Path, compression: str) -> None:
    records = corpus(0.2, seed=1)
    path = write(tmp_path / "log.mcap", records, batch_s=None, compression=compression)
    with LogReader(path) as reader:
        got = list(reader.records())
        assert not reader.damage
        assert reader.info == INFO
        assert reader.engine_toml == ENGINE_TOML  # verbatim
    want = sorted(records, key=lambda r: ms.TickClock(INFO.tick_hz).ns(ms.last_tick(r)))  # stable: file order on ties
    assert len(got) == len(want)
    assert all(same_record(a, b) for a, b in zip(got, want, strict=True))


@pytest.mark.parametrize("batch_s", [None, 0.01])
def test_pressure_frames_round_trip_bit_exact_as_counts(tmp_path: Path, batch_s) -> None:
    """Frames (all cylinders on one clock) come back as frames, every sample bit for bit (NaN included), stored
    as ADC counts; with batching the per-cylinder streams are unchanged."""
    records = corpus(0.2, seed=5, frames=True)
    assert any(isinstance(r, PressureFrame) for r in records)
    assert not any(isinstance(r, PressureBlock) for r in records)
    path = write(tmp_path / "log.mcap", records, batch_s=batch_s)
    with LogReader(path) as reader:
        got = list(reader.records())
        assert not reader.damage
    assert all(isinstance(r, PressureFrame) for r in got if isinstance(r, PressureBlock | PressureFrame))
    if batch_s is None:
        want = sorted(records, key=lambda r: ms.TickClock(INFO.tick_hz).ns(ms.last_tick(r)))
        assert all(same_record(a, b) for a, b in zip(got, want, strict=True))
    assert_same_streams(got, records)
    frame = next(r for r in records if isinstance(r, PressureFrame))
    name, data = ms.encode(frame, ms.PressureCounts())
    msg = ms._CLASSES[name].FromString(data)
    assert name == "PressureFrame" and len(msg.counts) == frame.values.size and not msg.values_pa
    assert list(msg.invalid) == [5]  # cylinder 1's saturated sample (row 0, index 5)


@pytest.mark.parametrize(
    "record",
    [
        PressureFrame((1, 1), 0, 500.0, np.ones((2, 3))),  # repeated cylinder
        PressureFrame((0, 1), 0, 500.0, np.ones((2, 3))),
        PressureFrame((1, 2), 0, 500.0, np.ones((3, 3))),  # rows != cylinders
        PressureFrame((1, 2), 0, 500.0, np.ones(3)),
        PressureFrame((1, 2), -1, 500.0, np.ones((2, 3))),
        PressureFrame((1, 2), 0, float("nan"), np.ones((2, 3))),
    ],
)
def test_writer_rejects_bad_frames(tmp_path: Path, record) -> None:
    with LogWriter(tmp_path / "bad.mcap", None, INFO) as writer, pytest.raises(ValueError):
        writer.write(record)


def test_frame_decoder_refuses_inconsistent_messages() -> None:
    cls = ms._CLASSES["PressureFrame"]
    bad = [
        cls(cylinders=[1, 2], t0_ticks=0, period_ticks=500.0, samples=2, values_pa=[1.0, 2.0, 3.0]),
        cls(cylinders=[1, 2], t0_ticks=0, period_ticks=500.0, samples=2, scale_pa=[1.0], counts=[1, 2, 3, 4]),
        cls(cylinders=[1, 2], t0_ticks=0, period_ticks=500.0, samples=2, scale_pa=[1.0, 0.0], counts=[1, 2, 3, 4]),
        cls(cylinders=[1, 2], t0_ticks=0, period_ticks=500.0, samples=2, scale_pa=[-1.0, 1.0], counts=[1, 2, 3, 4]),
        cls(cylinders=[1, 2], t0_ticks=0, period_ticks=500.0, samples=2, scale_pa=[1.0, float("nan")],
            counts=[1, 2, 3, 4]),
        cls(cylinders=[1, 2], t0_ticks=0, period_ticks=500.0, samples=2, scale_pa=[float("inf"), 1.0],
            counts=[1, 2, 3, 4]),
        cls(cylinders=[1, 2], t0_ticks=0, period_ticks=500.0, samples=2, scale_pa=[1.0, 1.0], counts=[1, 2, 3, 4],
            invalid=[4]),
        cls(cylinders=[1, 1], t0_ticks=0, period_ticks=500.0, samples=1, values_pa=[1.0, 2.0]),
        cls(cylinders=[], t0_ticks=0, period_ticks=500.0, samples=0),
    ]
    for msg in bad:
        with pytest.raises(ValueError):
            ms.DECODERS["frictionwatch.PressureFrame"](msg.SerializeToString())


def test_batched_log_keeps_every_tick_and_sample(tmp_path: Path) -> None:
    records = corpus(0.5, seed=2, window_s=0.0017)  # small records: joined into ~10 ms messages
    path = write(tmp_path / "log.mcap", records)
    with LogReader(path) as reader:
        got = list(reader.records())
    assert_same_streams(got, records)
    assert len(got) < len(records)


def test_log_time_is_last_element_rounded_half_up(tmp_path: Path) -> None:
    info = AcquisitionInfo(tick_hz=3e6, wheel_teeth=36, wheel_missing=1, first_tooth_deg=0.0)
    # 3 MHz: 1 tick = 333.33 ns; 2 ticks = 666.67 ns -> 667; 1 tick -> 333; t0 + 2 * 1.5 ticks = 13 -> 4333.33 -> 4333
    records = [
        ToothBatch(np.array([1, 2], np.int64)),
        LoadSample(1, 0.0, 0.0),
        PressureBlock(1, 10, 1.5, np.array([1e5, 1e5, 1e5])),
    ]
    path = write(tmp_path / "t.mcap", records, info=info, batch_s=None)
    with LogReader(path) as reader:
        times = [t for t, _ in reader.iter_timed()]
    assert times == [333, 667, 4333]
    assert ms.TickClock(1e9 / 2).ns(Fraction(1, 4)) == 1  # 0.5 ns rounds half up


def test_time_window_is_half_open(tmp_path: Path) -> None:
    path = write(tmp_path / "log.mcap", corpus(0.3, seed=3), batch_s=None)
    with LogReader(path) as reader:
        timed = list(reader.iter_timed())
        times = [t for t, _ in timed]
        lo, hi = times[len(times) // 3], times[2 * len(times) // 3]
        window = [t for t, _ in reader.iter_timed(start_ns=lo, end_ns=hi)]
    assert window == [t for t in times if lo <= t < hi]
    assert times == sorted(times)


def test_metadata_without_engine_and_cam(tmp_path: Path) -> None:
    info = AcquisitionInfo(tick_hz=1e6, wheel_teeth=60, wheel_missing=2, first_tooth_deg=-90.0)
    path = write(tmp_path / "log.mcap", [LoadSample(5, 1.0, float("nan"))], engine_toml=None, info=info)
    with LogReader(path) as reader:
        assert reader.info == info and reader.engine_toml is None
        assert ms.META_ENGINE not in reader.metadata
        (record,) = reader.records()
    assert record.ticks == 5 and np.isnan(record.power)


def test_pressure_stored_as_counts_only_when_exact(tmp_path: Path) -> None:
    lsb = 25e6 / 65536
    on_grid = np.array([1000, 1001, 1003, 5000]) * lsb
    off_grid = np.array([1.0e5, 1.1e5 + 0.3, np.nan])
    counts = ms.PressureCounts()
    assert "counts" in counts.fields(PressureBlock(1, 0, 500.0, on_grid))
    assert "values_pa" in counts.fields(PressureBlock(2, 0, 500.0, off_grid))
    records = [
        PressureBlock(2, 0, 500.0, off_grid),
        PressureBlock(1, 0, 500.0, on_grid),
        PressureBlock(1, 2000, 500.0, np.array([np.nan, 7 * lsb])),
    ]  # in log-time (last sample) order
    path = write(tmp_path / "p.mcap", records, batch_s=None)
    with LogReader(path) as reader:
        got = list(reader.records())
    assert all(same_record(a, b) for a, b in zip(got, records, strict=True))


@pytest.mark.parametrize(
    ("record", "error"),
    [
        (ToothBatch(np.array([1.5, 2.5])), ValueError),
        (ToothBatch(np.array([-3, 4])), ValueError),
        (PressureBlock(0, 0, 500.0, np.ones(3)), ValueError),
        (PressureBlock(1, 0, 0.0, np.ones(3)), ValueError),
        (PressureBlock(1, 0, 500.0, np.ones((2, 2))), ValueError),
        (LoadSample(-1, 0.0, 0.0), ValueError),
        ("not a record", TypeError),
    ],
)
def test_writer_rejects_what_it_cannot_represent(tmp_path: Path, record, error) -> None:
    with LogWriter(tmp_path / "bad.mcap", None, INFO) as writer, pytest.raises(error):
        writer.write(record)


def test_writer_arguments_and_empty_records(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="compression"):
        LogWriter(tmp_path / "a.mcap", None, INFO, compression="gzip")
    with pytest.raises(ValueError, match="tick_hz"):
        LogWriter(tmp_path / "b.mcap", None, AcquisitionInfo(0.0, 60, 2, 0.0))
    path = write(tmp_path / "c.mcap", [ToothBatch(np.zeros(0, np.int64)), PressureBlock(1, 0, 1.0, np.zeros(0))])
    with LogReader(path) as reader:
        assert list(reader.records()) == [] and not reader.damage


def test_file_is_standard_mcap_with_self_contained_protobuf_schemas(tmp_path: Path) -> None:
    """What Foxglove needs: mcap's reader plus a generic protobuf decoder built from the schema data alone."""
    records = corpus(0.1, seed=4) + corpus(0.2, seed=4, frames=True)[-3:]  # blocks, then a few frames
    path = write(tmp_path / "log.mcap", records)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes
        decoded = list(reader.iter_decoded_messages())
        names = {m.name for m in reader.iter_metadata()}
    assert names == {ms.META_ENGINE, ms.META_ACQUISITION}
    # every message but the second wheel's (a log of one wheel has none) and the restart marks (a recording's)
    assert {d.schema.name for d in decoded} == {f"frictionwatch.{n}" for n in ms.MESSAGES} - {
        "frictionwatch.FreeEndToothBatch", "frictionwatch.StreamRestart"}
    assert {d.channel.topic for d in decoded} == {"teeth", "cam", "pressure", "pressure_frames", "load"}
    teeth = np.concatenate([np.array(d.decoded_message.ticks) for d in decoded if d.channel.topic == "teeth"])
    np.testing.assert_array_equal(teeth, np.concatenate([r.ticks for r in records if isinstance(r, ToothBatch)]))


def test_foreign_channels_are_counted_not_fatal(tmp_path: Path) -> None:
    """An unknown topic / schema and a protobuf schema with other field numbers are skipped and counted."""
    path = write(tmp_path / "log.mcap", [LoadSample(10, 1.0, 2.0)], batch_s=None)
    with LogReader(path) as reader:
        good = list(reader.records())
    other = tmp_path / "foreign.mcap"
    with open(other, "wb") as f:
        writer = Writer(f)
        writer.start()
        writer.add_metadata(ms.META_ACQUISITION, ms.acquisition_metadata(INFO))
        json_schema = writer.register_schema("camera", SchemaEncoding.JSONSchema, b"{}")
        cam = writer.register_channel("camera", MessageEncoding.JSON, json_schema)
        fds = ms.file_descriptor()
        fds.message_type[3].field[1].type = descriptor_pb2.FieldDescriptorProto.TYPE_STRING  # torque_nm: a string?

        bad = writer.register_schema(
            "frictionwatch.LoadSample", "protobuf", descriptor_pb2.FileDescriptorSet(file=[fds]).SerializeToString()
        )
        load = writer.register_channel("load", "protobuf", bad)
        ok = writer.register_schema("frictionwatch.LoadSample", "protobuf", ms.schema_data())
        load_ok = writer.register_channel("load", "protobuf", ok)
        payload = ms.encode(good[0])[1]
        writer.add_message(cam, 5, b"{}", 5)
        writer.add_message(load, 6, payload, 6)
        writer.add_message(load_ok, 7, payload, 7)
        writer.add_message(load_ok, 8, b"\xff\xff\xff", 8)  # not protobuf
        writer.finish()
    with LogReader(other) as reader:
        assert list(reader.records()) == good
        assert reader.damage == {
            "skipped message (unknown schema on topic 'camera')": 1,
            "skipped message (unknown schema on topic 'load')": 1,
            "undecodable message (DecodeError)": 1,
        }


def test_unchunked_mcap_is_read(tmp_path: Path) -> None:
    path = tmp_path / "flat.mcap"
    records = corpus(0.05, seed=5)
    with open(path, "wb") as f:
        writer = Writer(f, use_chunking=False)
        writer.start()
        writer.add_metadata(ms.META_ACQUISITION, ms.acquisition_metadata(INFO))
        schema = ms.schema_data()
        channels = {
            n: writer.register_channel(t, "protobuf", writer.register_schema(f"frictionwatch.{n}", "protobuf", schema))
            for n, t in ms.TOPICS.items()
        }
        clock = ms.TickClock(INFO.tick_hz)
        for r in records:
            name, data = ms.encode(r)
            writer.add_message(channels[name], clock.ns(ms.last_tick(r)), data, 0)
        writer.finish()
    with LogReader(path) as reader:
        assert_same_streams(list(reader.records()), records)
        assert not reader.damage
