"""Replay-log encoding benchmark: file size and decode speed of JSON, protobuf and a raw numpy layout.

A genset-v20-sized stream is synthesised (1500 rpm, 160-2 wheel at 10 MHz ticks, 20 cylinders of pressure at
20 kHz with 10 kPa noise and a 16-bit ADC over 25 MPa, load at 100 Hz, one cam edge per cycle, 10 ms records)
and written through the project's LogWriter / read back through LogReader with each codec, zstd chunks for all.
The figures chose the format of docs/replay-format.md. The last encoding line writes the same pressure as one
``PressureFrame`` of all 20 cylinders per 10 ms (what an indicating system delivers) instead of 20 blocks.

    python -m bench.bench_log_format [--seconds 10]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import struct
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import ClassVar

import numpy as np
from frictionwatch.core.types import (
    AcquisitionInfo,
    CamBatch,
    LoadSample,
    PressureBlock,
    PressureFrame,
    StreamRecord,
    ToothBatch,
)
from frictionwatch.drivers.logs import mcap_schema as ms
from frictionwatch.drivers.logs.mcap_log import DEFAULT_CHUNK_BYTES, Codec, LogReader, LogWriter, ProtobufCodec
from frictionwatch.drivers.logs.mcap_schema import PressureCounts
from mcap.reader import make_reader
from mcap.records import Schema

TICK_HZ = 10e6
TARGET_X_REAL_TIME = 50  # issue 5: driver decode >= 50x the genset-v20 data rate on one core
INFO = AcquisitionInfo(TICK_HZ, 160, 2, -30.0, 5.0, tuple(range(1, 21)))
FIRING_DEG = [0, 36, 216, 252, 72, 108, 288, 324, 144, 180, 504, 540, 648, 684, 432, 468, 576, 612, 360, 396]
ENGINE_TOML = (Path(__file__).resolve().parents[1] / "core" / "model" / "engines" / "genset-v20.toml").read_text()


def genset_stream(seconds: float = 10.0, seed: int = 0, rpm: float = 1500.0, frames: bool = False
                  ) -> list[StreamRecord]:
    """Records as a live acquisition delivers them: every 10 ms the teeth, 20 pressure blocks (``frames``: one
    PressureFrame of the 20 cylinders instead), a load sample."""
    rng = np.random.default_rng(seed)
    omega0 = rpm / 60 * 2 * np.pi
    theta = np.linspace(0, omega0 * (seconds + 0.1), 200_000)  # fine crank-angle grid [rad]
    omega = omega0 * (1 + 2e-3 * np.sin(10 * theta) + 5e-4 * np.sin(5 * theta))  # firing order 10 per rev
    t_of_theta = np.concatenate(([0.0], np.cumsum(np.diff(theta) * 0.5 * (1 / omega[1:] + 1 / omega[:-1]))))
    step = 2 * np.pi / 160
    wheel = np.arange(158) * step + rng.normal(0, np.deg2rad(0.02), 158)  # tooth 0 after the gap; spacing error
    n_rev = int(theta[-1] / (2 * np.pi))
    tooth_theta = (np.arange(n_rev)[:, None] * 2 * np.pi + wheel[None, :]).ravel()
    t_teeth = np.interp(tooth_theta, theta, t_of_theta)
    teeth = np.floor(t_teeth[t_teeth < seconds] * TICK_HZ).astype(np.int64) + rng.integers(
        0, 2, (t_teeth < seconds).sum()
    )
    cam = np.floor(np.interp(np.arange(0, theta[-1], 4 * np.pi), theta, t_of_theta) * TICK_HZ).astype(np.int64)
    cam = cam[cam < seconds * TICK_HZ]
    t_p = np.arange(int(seconds * 20e3)) / 20e3
    crank_deg = np.rad2deg(np.interp(t_p, t_of_theta, theta))
    lsb = 25e6 / 65536
    pressure = {}
    for k, fire in enumerate(FIRING_DEG, start=1):
        local = (crank_deg - fire + 360) % 720 - 360  # deg from this cylinder's firing TDC, -360..360
        volume = 1 + 10.5 / 2 * (1 - np.cos(np.deg2rad(local)))  # clearance = 1, compression ratio 11.5
        burnt = np.where(local > -12, 1 - np.exp(-6.9 * (np.clip(local + 12, 0, 45) / 45) ** 3), 0.0)
        p = 3.3e5 * (11.5 / volume) ** 1.35 * (1 + 1.6 * burnt) + rng.normal(0, 10e3, t_p.size)
        pressure[k] = np.round(np.clip(p, 0, 25e6) / lsb) * lsb
    out: list[StreamRecord] = []
    for w in range(round(seconds / 0.01)):
        lo, hi = int(w * 0.01 * TICK_HZ), int((w + 1) * 0.01 * TICK_HZ)
        out.append(ToothBatch(teeth[(teeth >= lo) & (teeth < hi)]))
        if ((cam >= lo) & (cam < hi)).any():
            out.append(CamBatch(cam[(cam >= lo) & (cam < hi)]))
        if frames:
            rows = np.array([pressure[k][w * 200 : (w + 1) * 200] for k in pressure])
            out.append(PressureFrame(tuple(pressure), lo, 500.0, rows))
        for k in pressure if not frames else ():
            out.append(PressureBlock(k, lo, 500.0, pressure[k][w * 200 : (w + 1) * 200]))
        torque = 21200 + rng.normal(0, 50)
        out.append(LoadSample((lo + hi) // 2, torque, torque * omega0 * 0.97))
    return out


class JsonCodec:
    """JSON messages with a jsonschema (Foxglove-readable), same fields as the protobuf format (pressure as ADC
    counts where exact, else values with NaN as null: JSON has no NaN)."""

    message_encoding = "json"
    _FIELDS: ClassVar[dict[str, list[str]]] = {
        "ToothBatch": ["ticks"],
        "CamBatch": ["ticks"],
        "LoadSample": ["ticks", "torque_nm", "power_w"],
        "PressureBlock": ["cylinder", "t0_ticks", "period_ticks", "values_pa", "scale_pa", "counts", "invalid"],
    }

    def __init__(self) -> None:
        self._counts = PressureCounts()

    def schemas(self) -> dict[str, tuple[str, str, bytes]]:
        def schema(fields: list[str]) -> bytes:
            arrays = ("ticks", "values_pa", "counts", "invalid")
            props = {f: {"type": "array"} if f in arrays else {"type": "number"} for f in fields}
            return json.dumps({"type": "object", "properties": props}).encode()

        return {n: (f"frictionwatch.{n}", "jsonschema", schema(f)) for n, f in self._FIELDS.items()}

    def encode(self, record: StreamRecord) -> tuple[str, bytes]:
        if isinstance(record, ToothBatch | CamBatch):
            body: dict[str, object] = {"ticks": record.ticks.tolist()}
        elif isinstance(record, PressureBlock):
            fields = self._counts.fields(record)
            body = {"cylinder": record.cylinder, "t0_ticks": record.t0_ticks, "period_ticks": record.period_ticks}
            if "counts" in fields:
                body.update(
                    scale_pa=fields["scale_pa"],
                    counts=fields["counts"].tolist(),  # type: ignore[union-attr]
                    invalid=fields["invalid"].tolist(),
                )  # type: ignore[union-attr]
            else:
                body["values_pa"] = [None if math.isnan(v) else v for v in record.values.tolist()]
        else:
            assert isinstance(record, LoadSample)
            body = {"ticks": record.ticks, "torque_nm": record.torque, "power_w": record.power}
        return type(record).__name__, json.dumps(body, separators=(",", ":")).encode()

    def decoder_for(self, message_encoding: str, schema: Schema | None) -> Callable[[bytes], StreamRecord] | None:
        name = schema.name.removeprefix("frictionwatch.") if schema else ""
        decoders: dict[str, Callable[[dict], StreamRecord]] = {
            "ToothBatch": lambda d: ToothBatch(np.array(d["ticks"], np.int64)),
            "CamBatch": lambda d: CamBatch(np.array(d["ticks"], np.int64)),
            "PressureBlock": lambda d: PressureBlock(d["cylinder"], d["t0_ticks"], d["period_ticks"], _values(d)),
            "LoadSample": lambda d: LoadSample(d["ticks"], d["torque_nm"], d["power_w"]),
        }
        decode = decoders.get(name)
        return None if decode is None else (lambda data: decode(json.loads(data)))


def _values(d: dict) -> np.ndarray:
    if "counts" not in d:
        return np.array(d["values_pa"], np.float64)  # None -> NaN
    values = np.array(d["counts"], np.float64) * d["scale_pa"]
    values[d["invalid"]] = np.nan
    return values


class RawCodec:
    """Custom binary layout (not Foxglove-readable): little-endian header struct + numpy bytes; pressure as int32
    ADC counts where exact (header: cylinder, t0, period, scale or 0 for float64 values, number of invalid)."""

    message_encoding = "x-frictionwatch-raw"
    _PRESSURE = struct.Struct("<IqddI")
    _LOAD = struct.Struct("<qdd")

    def __init__(self) -> None:
        self._counts = PressureCounts()

    def schemas(self) -> dict[str, tuple[str, str, bytes]]:
        layout = {
            "ToothBatch": b"int64[n] ticks",
            "CamBatch": b"int64[n] ticks",
            "PressureBlock": b"uint32 cylinder, int64 t0_ticks, float64 period_ticks, float64[n] values_pa",
            "LoadSample": b"int64 ticks, float64 torque_nm, float64 power_w",
        }
        return {n: (f"frictionwatch.raw.{n}", "x-frictionwatch-raw", text) for n, text in layout.items()}

    def encode(self, record: StreamRecord) -> tuple[str, bytes]:
        if isinstance(record, ToothBatch | CamBatch):
            data = record.ticks.astype("<i8").tobytes()
        elif isinstance(record, PressureBlock):
            fields = self._counts.fields(record)
            if "counts" in fields:
                invalid = fields["invalid"].astype("<u4")  # type: ignore[union-attr]
                head = self._PRESSURE.pack(
                    record.cylinder, record.t0_ticks, record.period_ticks, fields["scale_pa"], invalid.size
                )
                data = head + invalid.tobytes() + fields["counts"].astype("<i4").tobytes()  # type: ignore[union-attr]
            else:
                head = self._PRESSURE.pack(record.cylinder, record.t0_ticks, record.period_ticks, 0.0, 0)
                data = head + record.values.astype("<f8").tobytes()
        else:
            assert isinstance(record, LoadSample)
            data = self._LOAD.pack(record.ticks, record.torque, record.power)
        return type(record).__name__, data

    def decoder_for(self, message_encoding: str, schema: Schema | None) -> Callable[[bytes], StreamRecord] | None:
        name = schema.name.removeprefix("frictionwatch.raw.") if schema else ""
        decoders: dict[str, Callable[[bytes], StreamRecord]] = {
            "ToothBatch": lambda d: ToothBatch(np.frombuffer(d, "<i8")),
            "CamBatch": lambda d: CamBatch(np.frombuffer(d, "<i8")),
            "PressureBlock": self._decode_pressure,
            "LoadSample": lambda d: LoadSample(*self._LOAD.unpack(d)),
        }
        return decoders.get(name)

    def _decode_pressure(self, data: bytes) -> PressureBlock:
        cylinder, t0, period, scale, n_invalid = self._PRESSURE.unpack_from(data)
        at = self._PRESSURE.size
        if scale == 0:
            return PressureBlock(cylinder, t0, period, np.frombuffer(data, "<f8", offset=at))
        invalid = np.frombuffer(data, "<u4", count=n_invalid, offset=at)
        values = np.frombuffer(data, "<i4", offset=at + 4 * n_invalid) * scale
        values[invalid] = np.nan
        return PressureBlock(cylinder, t0, period, values)


class ProtobufDoublesCodec(ProtobufCodec):
    """The protobuf format with pressure always as float64 ``values_pa`` (to show what the counts save)."""

    def encode(self, record: StreamRecord) -> tuple[str, bytes]:
        return ms.encode(record, None)


def _payload_bytes(records: list[StreamRecord]) -> int:
    return sum(
        r.ticks.nbytes
        if isinstance(r, ToothBatch | CamBatch)
        else r.values.nbytes + 20
        if isinstance(r, PressureBlock | PressureFrame)
        else 24
        for r in records
    )


def measure(
    records: list[StreamRecord], codec: Codec, folder: Path, seconds: float, chunk_bytes: int, repeats: int = 3
) -> dict[str, float]:
    """Write once, then decode ``repeats`` times through LogReader.records(); best decode time counts."""
    path = folder / f"log-{type(codec).__name__}-{chunk_bytes}.mcap"
    t0 = time.perf_counter()
    with LogWriter(path, ENGINE_TOML, INFO, codec=codec, chunk_bytes=chunk_bytes) as writer:
        for record in records:
            writer.write(record)
    write_s = time.perf_counter() - t0
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        chunks = len(summary.chunk_indexes) if summary is not None else 0
    best, count = float("inf"), 0
    for _ in range(repeats):
        t0 = time.perf_counter()
        with LogReader(path, codec=codec) as reader:
            count = sum(1 for _ in reader.records())
            assert not reader.damage, reader.damage
        best = min(best, time.perf_counter() - t0)
    return {
        "file_mb": size / 1e6,
        "bytes_per_s_of_data": size / seconds,
        "messages": count,
        "write_s": write_s,
        "decode_s": best,
        "records_per_s": count / best,
        "file_mb_per_s": size / 1e6 / best,
        "payload_mb_per_s": _payload_bytes(records) / 1e6 / best,
        "realtime_factor": seconds / best,
        "chunks": chunks,
        "data_s_per_chunk": seconds / max(chunks, 1),
    }


def run(seconds: float = 10.0) -> dict[str, object]:
    records = genset_stream(seconds)
    result: dict[str, object] = {
        "stream": {
            "seconds": seconds,
            "records": len(records),
            "payload_mb": _payload_bytes(records) / 1e6,
            "teeth_per_s": sum(len(r.ticks) for r in records if isinstance(r, ToothBatch)) / seconds,
            "pressure_samples_per_s": sum(len(r.values) for r in records if isinstance(r, PressureBlock)) / seconds,
        },
    }
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        codecs: dict[str, Codec] = {
            "json": JsonCodec(),
            "protobuf": ProtobufCodec(),
            "raw": RawCodec(),
            "protobuf, pressure as doubles": ProtobufDoublesCodec(),
        }
        result["encodings"] = {
            name: measure(records, codec, folder, seconds, DEFAULT_CHUNK_BYTES) for name, codec in codecs.items()
        }
        frames = genset_stream(seconds, frames=True)  # the same samples, 20 cylinders per message
        result["encodings"]["protobuf, pressure frames"] = measure(  # type: ignore[index]
            frames, ProtobufCodec(), folder, seconds, DEFAULT_CHUNK_BYTES
        )
        result["protobuf_chunk_bytes"] = {
            kib: measure(records, ProtobufCodec(), folder, seconds, kib * 1024, repeats=1) for kib in (128, 512, 2048)
        }
    chosen = result["encodings"]["protobuf"]  # type: ignore[index]
    result["chosen"] = "protobuf"
    result["decode_target_x_real_time"] = TARGET_X_REAL_TIME
    result["decode_meets_target"] = chosen["realtime_factor"] >= TARGET_X_REAL_TIME
    print(_table(result))
    return result


def _table(result: dict[str, object]) -> str:
    rows = [
        (
            "| encoding | file MB | MB per hour | decode records/s | decode MB/s (file) | decode MB/s (payload) "
            "| x real time | write s |"
        ),
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, m in result["encodings"].items():  # type: ignore[union-attr]
        rows.append(
            f"| {name} | {m['file_mb']:.2f} | {m['bytes_per_s_of_data'] * 3600 / 1e6:.0f} | "
            f"{m['records_per_s']:,.0f} | {m['file_mb_per_s']:.1f} | {m['payload_mb_per_s']:.1f} | "
            f"{m['realtime_factor']:.0f} | {m['write_s']:.2f} |"
        )
    rows += ["", "| protobuf chunk KiB | file MB | data s per chunk | x real time |", "|---|---|---|---|"]
    for kib, m in result["protobuf_chunk_bytes"].items():  # type: ignore[union-attr]
        rows.append(f"| {kib} | {m['file_mb']:.2f} | {m['data_s_per_chunk']:.3f} | {m['realtime_factor']:.0f} |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    result = run(args.seconds)
    print(json.dumps(result["stream"]))


if __name__ == "__main__":
    main()
