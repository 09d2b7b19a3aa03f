"""Replay-log schema (docs/replay-format.md): protobuf messages built at run time, metadata keys, the log-time rule.

Every stream record becomes one protobuf message (proto3, package ``frictionwatch``), chosen over JSON and a raw
numpy layout by bench/bench_log_format.py: Foxglove decodes it, packed repeated fields keep it compact, and upb
parses it at C speed. The descriptors are built here with ``descriptor_pb2`` -- no ``protoc`` step -- and the
MCAP schema data is the serialized ``FileDescriptorSet`` (what Foxglove and ``mcap_protobuf`` expect).

Time: ticks inside the message are the truth. An MCAP ``log_time`` (integer ns) is derived from the tick of the
message's LAST element, ``round_half_up(ticks * 1e9 / tick_hz)`` in exact rational arithmetic; it serves ordering,
seeking and Foxglove's time axis only.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable
from fractions import Fraction
from functools import partial

import numpy as np
from frictionwatch.core.types import (
    AcquisitionInfo,
    CamBatch,
    FreeEndToothBatch,
    LoadSample,
    PressureBlock,
    PressureFrame,
    StreamRecord,
    ToothBatch,
    WheelInfo,
)
from frictionwatch.drivers.logs.mcap_frame_kernel import decode_frame, decode_ticks
from frictionwatch.drivers.source import StreamRestart
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.message import DecodeError

FORMAT = "frictionwatch.replay/1"
PACKAGE = "frictionwatch"
META_ENGINE = "engine"  # metadata record name; key ENGINE_KEY holds the engine TOML text verbatim
ENGINE_KEY = "engine_toml"
META_ACQUISITION = "acquisition"  # metadata record name; keys = AcquisitionInfo fields + "format" (+ "crc32")
CRC_KEY = "crc32"

_F = descriptor_pb2.FieldDescriptorProto
# message name -> topic, [(field, number, type, repeated)]; the wire contract of docs/replay-format.md
MESSAGES: dict[str, tuple[str, list[tuple[str, int, int, bool]]]] = {
    "ToothBatch": ("teeth", [("ticks", 1, _F.TYPE_INT64, True)]),
    "CamBatch": ("cam", [("ticks", 1, _F.TYPE_INT64, True)]),
    "PressureBlock": (
        "pressure",
        [
            ("cylinder", 1, _F.TYPE_UINT32, False),
            ("t0_ticks", 2, _F.TYPE_INT64, False),
            ("period_ticks", 3, _F.TYPE_DOUBLE, False),
            ("values_pa", 4, _F.TYPE_DOUBLE, True),  # either values_pa ...
            ("scale_pa", 5, _F.TYPE_DOUBLE, False),  # ... or counts * scale_pa (ADC counts, exact)
            ("counts", 6, _F.TYPE_SINT32, True),
            ("invalid", 7, _F.TYPE_UINT32, True),  # indices of NaN (saturated / invalid) samples in counts form
        ],
    ),
    "LoadSample": (
        "load",
        [
            ("ticks", 1, _F.TYPE_INT64, False),
            ("torque_nm", 2, _F.TYPE_DOUBLE, False),
            ("power_w", 3, _F.TYPE_DOUBLE, False),
        ],
    ),
    "PressureFrame": (  # appended: the message numbering of older logs stays
        "pressure_frames",
        [
            ("cylinders", 1, _F.TYPE_UINT32, True),  # k distinct cylinders, row order
            ("t0_ticks", 2, _F.TYPE_INT64, False),
            ("period_ticks", 3, _F.TYPE_DOUBLE, False),
            ("samples", 4, _F.TYPE_UINT32, False),  # n samples per cylinder
            ("values_pa", 5, _F.TYPE_DOUBLE, True),  # either k * n values, row by row ...
            ("scale_pa", 6, _F.TYPE_DOUBLE, True),  # ... or counts * scale_pa[row] (one ADC step per cylinder)
            ("counts", 7, _F.TYPE_SINT32, True),
            ("invalid", 8, _F.TYPE_UINT32, True),  # flat indices row * n + i of NaN samples in counts form
        ],
    ),
    "FreeEndToothBatch": ("free_end_teeth", [("ticks", 1, _F.TYPE_INT64, True)]),  # the second wheel's edges (last: older indices kept)
    "StreamRestart": (  # not data: where the stream starts again (drivers/source.py), a hole it dropped said
        "restarts",
        [
            ("ticks", 1, _F.TYPE_INT64, False),
            ("reason", 2, _F.TYPE_STRING, False),
            ("dropped_from_ticks", 3, _F.TYPE_INT64, False),  # read only where dropped_records > 0
            ("dropped_records", 4, _F.TYPE_INT64, False),
            ("dropped_cycles", 5, _F.TYPE_DOUBLE, False),
            ("assembly", 6, _F.TYPE_STRING, False),  # "" = "all"
        ],
    ),
}
TOPICS = {name: topic for name, (topic, _) in MESSAGES.items()}


def file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    """The ``frictionwatch.proto`` file (proto3) as a descriptor, built from ``MESSAGES``."""
    fdp = descriptor_pb2.FileDescriptorProto(name="frictionwatch.proto", package=PACKAGE, syntax="proto3")
    for name, (_, fields) in MESSAGES.items():
        msg = fdp.message_type.add(name=name)
        for field, number, ftype, repeated in fields:
            label = _F.LABEL_REPEATED if repeated else _F.LABEL_OPTIONAL
            msg.field.add(name=field, number=number, type=ftype, label=label)  # proto3 packs repeated scalars
    return fdp


def schema_data() -> bytes:
    """MCAP schema data for every channel: a serialized FileDescriptorSet holding ``frictionwatch.proto``."""
    return descriptor_pb2.FileDescriptorSet(file=[file_descriptor()]).SerializeToString()


_POOL = descriptor_pool.DescriptorPool()
_POOL.Add(file_descriptor())
_CLASSES = {
    name: message_factory.GetMessageClass(_POOL.FindMessageTypeByName(f"{PACKAGE}.{name}")) for name in MESSAGES
}


def schema_matches(name: str, data: bytes) -> bool:
    """True if the MCAP schema ``data`` (a FileDescriptorSet) defines message ``name`` of package frictionwatch
    with no field that contradicts ours (same number, other type or cardinality). Fields it leaves out decode
    as proto3 defaults (a writer may omit the counts form of PressureBlock); fields we do not know are ignored."""
    short = name.removeprefix(PACKAGE + ".")
    if short not in MESSAGES or not name.startswith(PACKAGE + "."):
        return False
    try:
        fds = descriptor_pb2.FileDescriptorSet.FromString(data)
    except DecodeError:
        return False
    ours = {number: (ftype, repeated) for _, number, ftype, repeated in MESSAGES[short][1]}
    for fdp in fds.file:
        if fdp.package != PACKAGE:
            continue
        for msg in fdp.message_type:
            if msg.name == short:
                return all(
                    ours.get(f.number, (f.type, f.label == _F.LABEL_REPEATED)) == (f.type, f.label == _F.LABEL_REPEATED)
                    for f in msg.field
                )
    return False


# ---- records <-> protobuf bytes -------------------------------------------------------------------------------


class PressureCounts:
    """Finds the ADC step of each cylinder's pressure so blocks can be stored as integer counts.

    Lossless by construction: a block is stored as ``counts * scale_pa`` only if that float64 product reproduces
    every finite value bit for bit (NaN samples listed in ``invalid``); otherwise as ``values_pa`` doubles.
    The step is inferred from the data (smallest gap between distinct values) and remembered per cylinder.
    """

    def __init__(self) -> None:
        self.scales: dict[int, float] = {}

    @staticmethod
    def _counts(values: np.ndarray, finite: np.ndarray, scale: float) -> np.ndarray | None:
        counts = np.rint(np.where(finite, values, 0.0) / scale)
        if np.abs(counts).max(initial=0) >= 2**31 or not np.array_equal(counts[finite] * scale, values[finite]):
            return None
        return counts.astype(np.int32)

    def fields(self, block: PressureBlock) -> dict[str, object]:
        values = block.values
        finite = np.isfinite(values)
        scale = self.scales.get(block.cylinder)
        counts = None if scale is None else self._counts(values, finite, scale)
        if counts is None:
            distinct = np.unique(values[finite])
            step = float(np.diff(distinct).min()) if distinct.size > 1 else 0.0
            if step > 0 and math.isfinite(step):
                counts = self._counts(values, finite, step)
                if counts is not None:
                    self.scales[block.cylinder] = scale = step
        if counts is None or scale is None:
            return {"values_pa": values}
        return {"scale_pa": scale, "counts": counts, "invalid": np.flatnonzero(~finite)}


    def frame_fields(self, frame: PressureFrame) -> dict[str, object]:
        """Counts form of a frame (each row with its cylinder's step) if every row has one, else values_pa."""
        parts = [self.fields(PressureBlock(c, frame.t0_ticks, frame.period_ticks, row))
                 for c, row in zip(frame.cylinders, frame.values)]
        if not all("counts" in f for f in parts):
            return {"values_pa": frame.values.ravel()}
        n = frame.values.shape[1]
        return {"scale_pa": [f["scale_pa"] for f in parts], "counts": np.concatenate([f["counts"] for f in parts]),
                "invalid": np.flatnonzero(~np.isfinite(frame.values.ravel())) if n else []}


def encode(record: StreamRecord, counts: PressureCounts | None = None) -> tuple[str, bytes]:
    """``(message name, protobuf bytes)`` of one validated record; pressure as counts where ``counts`` can."""
    if isinstance(record, ToothBatch | CamBatch | FreeEndToothBatch):
        name = type(record).__name__
        return name, _CLASSES[name](ticks=record.ticks).SerializeToString()
    if isinstance(record, PressureBlock):
        values = counts.fields(record) if counts is not None else {"values_pa": record.values}
        msg = _CLASSES["PressureBlock"](
            cylinder=record.cylinder, t0_ticks=record.t0_ticks, period_ticks=record.period_ticks, **values
        )
        return "PressureBlock", msg.SerializeToString()
    if isinstance(record, PressureFrame):
        values = counts.frame_fields(record) if counts is not None else {"values_pa": record.values.ravel()}
        msg = _CLASSES["PressureFrame"](
            cylinders=record.cylinders, t0_ticks=record.t0_ticks, period_ticks=record.period_ticks,
            samples=record.values.shape[1], **values
        )
        return "PressureFrame", msg.SerializeToString()
    if isinstance(record, LoadSample):
        msg = _CLASSES["LoadSample"](ticks=record.ticks, torque_nm=record.torque, power_w=record.power)
        return "LoadSample", msg.SerializeToString()
    if isinstance(record, StreamRestart):
        hole = record.dropped_records > 0
        msg = _CLASSES["StreamRestart"](
            ticks=record.ticks, reason=record.reason, dropped_from_ticks=record.dropped_from_ticks if hole else 0,
            dropped_records=record.dropped_records, dropped_cycles=record.dropped_cycles,
            assembly="" if record.assembly == "all" else record.assembly,
        )
        return "StreamRestart", msg.SerializeToString()
    raise TypeError(f"not a stream record: {type(record).__name__}")


def teeth_ticks_reference(name: str, data: bytes) -> np.ndarray:
    """The int64 ticks of a ToothBatch / CamBatch / FreeEndToothBatch message (``name``) by upb: the reference of
    the compiled pass (drivers/logs/mcap_frame_kernel.py ``ticks_kernel``)."""
    return np.array(_CLASSES[name].FromString(data).ticks, dtype=np.int64)


def _decode_teeth(cls: type[ToothBatch | CamBatch | FreeEndToothBatch], name: str) -> Callable[[bytes], StreamRecord]:
    reference = partial(teeth_ticks_reference, name)

    def decode(data: bytes) -> StreamRecord:
        return cls(decode_ticks(data, reference))

    return decode


def _decode_pressure(data: bytes) -> PressureBlock:
    msg = _CLASSES["PressureBlock"].FromString(data)
    period = msg.period_ticks
    if msg.cylinder < 1 or not (period > 0 and math.isfinite(period)):
        raise ValueError(f"invalid PressureBlock: cylinder {msg.cylinder}, period_ticks {period}")
    if msg.values_pa:
        if msg.counts or msg.invalid:
            raise ValueError("invalid PressureBlock: both values_pa and counts are set")
        return PressureBlock(msg.cylinder, msg.t0_ticks, period, np.array(msg.values_pa, dtype=np.float64))
    scale = msg.scale_pa
    if not (scale > 0 and math.isfinite(scale)) and (msg.counts or msg.invalid):
        raise ValueError(f"invalid PressureBlock: counts need scale_pa > 0, got {scale}")
    values = np.array(msg.counts, dtype=np.float64) * scale
    if msg.invalid:
        invalid = np.array(msg.invalid, dtype=np.int64)
        if invalid.max() >= values.size:
            raise ValueError("invalid PressureBlock: an invalid-sample index lies past the samples")
        values[invalid] = np.nan
    return PressureBlock(msg.cylinder, msg.t0_ticks, period, values)


def _decode_frame(data: bytes) -> PressureFrame:
    msg = _CLASSES["PressureFrame"].FromString(data)
    period = msg.period_ticks
    cylinders = tuple(msg.cylinders)
    k, n = len(cylinders), msg.samples
    if k == 0 or min(cylinders) < 1 or len(set(cylinders)) != k or not (period > 0 and math.isfinite(period)):
        raise ValueError(f"invalid PressureFrame: cylinders {cylinders}, period_ticks {period}")
    if msg.values_pa:
        if msg.counts or msg.invalid or msg.scale_pa:
            raise ValueError("invalid PressureFrame: both values_pa and counts are set")
        if len(msg.values_pa) != k * n:
            raise ValueError(f"invalid PressureFrame: {len(msg.values_pa)} values for {k} x {n} samples")
        return PressureFrame(cylinders, msg.t0_ticks, period, np.array(msg.values_pa, dtype=np.float64).reshape(k, n))
    scale_pa = msg.scale_pa
    if len(msg.counts) != k * n or (n and len(scale_pa) != k):
        raise ValueError(f"invalid PressureFrame: {len(msg.counts)} counts, {len(scale_pa)} scales for {k} x {n}")
    if not n:
        values = np.zeros((k, 0))
    elif not all(s > 0 and math.isfinite(s) for s in scale_pa):  # k scales: plain Python is quicker than 4 ufuncs
        raise ValueError("invalid PressureFrame: counts need scale_pa > 0")
    else:  # the same products as counts * scale, scaled in place (one array of k x n made, not two)
        values = np.array(msg.counts, dtype=np.float64).reshape(k, n)
        values *= np.array(scale_pa, dtype=np.float64).reshape(k, 1)
    if msg.invalid:
        invalid = np.array(msg.invalid, dtype=np.int64)
        if invalid.max() >= values.size:
            raise ValueError("invalid PressureFrame: an invalid-sample index lies past the samples")
        values.reshape(-1)[invalid] = np.nan
    return PressureFrame(cylinders, msg.t0_ticks, period, values)


def _decode_frame_fast(data: bytes) -> PressureFrame:
    """``_decode_frame`` by one compiled pass over the bytes where the message is as our writer makes it, by
    ``_decode_frame`` itself otherwise (drivers/logs/mcap_frame_kernel.py): the same record or the same error."""
    return decode_frame(data, _decode_frame)


def _decode_restart(data: bytes) -> StreamRestart:
    msg = _CLASSES["StreamRestart"].FromString(data)
    hole = msg.dropped_records > 0
    if msg.ticks < 0 or msg.dropped_records < 0 or (hole and msg.dropped_from_ticks > msg.ticks):
        raise ValueError(f"a restart mark at {msg.ticks} with {msg.dropped_records} records dropped from "
                         f"{msg.dropped_from_ticks}")
    assembly = msg.assembly or "all"
    if assembly not in RESTART_ASSEMBLIES:
        raise ValueError(f"a restart mark's assembly {assembly!r}: not one of {RESTART_ASSEMBLIES}")
    return StreamRestart(msg.ticks, msg.reason or "loop_restart", msg.dropped_from_ticks if hole else None,
                         int(msg.dropped_records), float(msg.dropped_cycles), assembly)


def _decode_load(data: bytes) -> LoadSample:
    msg = _CLASSES["LoadSample"].FromString(data)
    return LoadSample(msg.ticks, msg.torque_nm, msg.power_w)


DECODERS: dict[str, Callable[[bytes], StreamRecord]] = {
    f"{PACKAGE}.ToothBatch": _decode_teeth(ToothBatch, "ToothBatch"),
    f"{PACKAGE}.CamBatch": _decode_teeth(CamBatch, "CamBatch"),
    f"{PACKAGE}.FreeEndToothBatch": _decode_teeth(FreeEndToothBatch, "FreeEndToothBatch"),
    f"{PACKAGE}.PressureBlock": _decode_pressure,
    f"{PACKAGE}.PressureFrame": _decode_frame_fast,
    f"{PACKAGE}.LoadSample": _decode_load,
    f"{PACKAGE}.StreamRestart": _decode_restart,
}
RESTART_ASSEMBLIES = ("all", "second_wheel", "none")
DECODE_ERRORS = (DecodeError, ValueError, TypeError)  # what a decoder raises on a bad message


# ---- time base ------------------------------------------------------------------------------------------------


class TickClock:
    """Exact ticks -> integer nanoseconds: ``floor(ticks * 1e9 / tick_hz + 1/2)`` (round half up), rational math."""

    def __init__(self, tick_hz: float) -> None:
        if not (tick_hz > 0 and math.isfinite(tick_hz)):
            raise ValueError(f"tick_hz must be a positive finite frequency [Hz], got {tick_hz!r}")
        self._ns_per_tick = Fraction(10**9) / Fraction(tick_hz)

    def ns(self, ticks: float | Fraction) -> int:
        return math.floor(Fraction(ticks) * self._ns_per_tick + Fraction(1, 2))


def last_tick(record: StreamRecord) -> Fraction:
    """Tick of the record's last element (the moment the record was complete); exact."""
    if isinstance(record, ToothBatch | CamBatch | FreeEndToothBatch):
        return Fraction(int(record.ticks[-1]))
    if isinstance(record, PressureBlock):
        return Fraction(record.t0_ticks) + (len(record.values) - 1) * Fraction(record.period_ticks)
    if isinstance(record, PressureFrame):
        return Fraction(record.t0_ticks) + (record.values.shape[1] - 1) * Fraction(record.period_ticks)
    return Fraction(record.ticks)


# ---- metadata -------------------------------------------------------------------------------------------------


def metadata_crc(data: dict[str, str]) -> str:
    """CRC-32 (zlib) of ``key=value`` lines sorted by key, without the crc32 key itself, as 8 lower-case hex digits."""
    text = "\n".join(f"{k}={data[k]}" for k in sorted(data) if k != CRC_KEY)
    return f"{zlib.crc32(text.encode()):08x}"


def with_crc(data: dict[str, str]) -> dict[str, str]:
    return {**data, CRC_KEY: metadata_crc(data)}


def crc_ok(data: dict[str, str]) -> bool:
    """True if the record has no crc32 key (it is optional) or the key matches the content."""
    return CRC_KEY not in data or data[CRC_KEY] == metadata_crc(data)


def acquisition_metadata(info: AcquisitionInfo) -> dict[str, str]:
    """AcquisitionInfo -> MCAP metadata map (floats in repr form, so they round-trip exactly)."""
    data = {
        "format": FORMAT,
        "tick_hz": repr(float(info.tick_hz)),
        "wheel_teeth": str(int(info.wheel_teeth)),
        "wheel_missing": str(int(info.wheel_missing)),
        "first_tooth_deg": repr(float(info.first_tooth_deg)),
        "pressure_cylinders": ",".join(str(int(c)) for c in info.pressure_cylinders),
    }
    if info.cam_deg is not None:
        data["cam_deg"] = repr(float(info.cam_deg))
    if info.second_wheel is not None:  # keys absent = no second wheel (every log before it)
        w = info.second_wheel
        data.update(wheel2_teeth=str(int(w.teeth)), wheel2_missing=str(int(w.missing)),
                    wheel2_first_tooth_deg=repr(float(w.first_tooth_deg)))
    return with_crc(data)


def acquisition_from_metadata(data: dict[str, str]) -> AcquisitionInfo:
    """MCAP metadata map -> AcquisitionInfo; ValueError naming the bad key."""
    if not crc_ok(data):
        raise ValueError("acquisition metadata fails its crc32")
    if not data.get("format", "").startswith("frictionwatch.replay/"):
        raise ValueError(f"acquisition metadata has format {data.get('format')!r}, expected {FORMAT!r}")
    try:
        tick_hz = float(data["tick_hz"])
        teeth, missing = int(data["wheel_teeth"]), int(data["wheel_missing"])
        first = float(data["first_tooth_deg"])
        cam = float(data["cam_deg"]) if data.get("cam_deg", "") != "" else None
        wheel2 = (WheelInfo(int(data["wheel2_teeth"]), int(data["wheel2_missing"]),
                            float(data["wheel2_first_tooth_deg"])) if data.get("wheel2_teeth", "") != "" else None)
        cyls = data.get("pressure_cylinders", "")
        cylinders = tuple(int(c) for c in cyls.split(",")) if cyls.strip() else ()
    except (KeyError, ValueError) as exc:
        raise ValueError(f"acquisition metadata: bad or missing key ({exc})") from exc
    if not (tick_hz > 0 and math.isfinite(tick_hz)):
        raise ValueError(f"acquisition metadata: tick_hz {tick_hz} must be > 0 Hz")
    if not (teeth > 0 and 0 <= missing < teeth):
        raise ValueError(f"acquisition metadata: wheel {teeth}-{missing} is impossible")
    if any(c < 1 for c in cylinders) or not math.isfinite(first):
        raise ValueError("acquisition metadata: cylinders must be >= 1 and first_tooth_deg finite")
    if wheel2 is not None and not (wheel2.teeth > 0 and 0 <= wheel2.missing < wheel2.teeth
                                   and math.isfinite(wheel2.first_tooth_deg)):
        raise ValueError(f"acquisition metadata: second wheel {wheel2.teeth}-{wheel2.missing} at "
                         f"{wheel2.first_tooth_deg} deg is impossible")
    return AcquisitionInfo(tick_hz, teeth, missing, first, cam, cylinders, wheel2)
