"""MCAP replay logs: ``LogWriter`` and the damage-tolerant ``LogReader`` (format: docs/replay-format.md).

    with LogWriter("run.mcap", engine_toml, info) as log:     # info: core.types.AcquisitionInfo
        for record in stream:                    # ToothBatch | CamBatch | PressureBlock | PressureFrame | LoadSample
                                                 # | FreeEndToothBatch | StreamRestart (a mark, drivers/source.py)
            log.write(record)
    log = LogReader("run.mcap")                              # CorruptLog if nothing at all is readable
    log.info, log.engine_toml, log.metadata
    for record in log.records(start_ns=None, end_ns=None):   # log-time order, half-open [start_ns, end_ns)
        ...
    log.damage                                               # Counter: reason -> count (truncated, corrupt chunk...)

The writer is here; ``LogReader`` lives in drivers/logs/mcap_reader.py (importable from here too), the scanner
that survives damage in drivers/logs/mcap_scan.py, the protobuf schema in drivers/logs/mcap_schema.py, and
``McapSource`` (the ``mcap:`` URL scheme of drivers/source.py) in drivers/logs/mcap_replay.py.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Any, Self

import frictionwatch.drivers.logs.mcap_schema as ms
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
)
from frictionwatch.drivers.logs.mcap_batching import Batcher
from frictionwatch.drivers.logs.mcap_reader import Codec, LogReader, ProtobufCodec
from frictionwatch.drivers.source import StreamRestart
from mcap.writer import CompressionType, Writer

DEFAULT_CHUNK_BYTES = 128 * 1024  # uncompressed; ~0.12 s of genset-v20 data: the most one damaged chunk loses
DEFAULT_BATCH_S = 0.01  # records are joined / split into messages of about this span
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


def _checked(record: Any) -> StreamRecord | None:
    """The record with canonical dtypes, None if it holds no data; ValueError/TypeError if it cannot be logged."""
    if isinstance(record, ToothBatch | CamBatch | FreeEndToothBatch):
        ticks = np.asarray(record.ticks)
        if ticks.ndim != 1 or not (ticks.size == 0 or np.issubdtype(ticks.dtype, np.integer)):
            raise ValueError(
                f"{type(record).__name__}.ticks must be a 1-D integer array, got {ticks.dtype} {ticks.shape}"
            )
        if ticks.size == 0:
            return None
        if ticks[0] < 0:
            raise ValueError(f"{type(record).__name__}: ticks must be >= 0 (the log time base), got {ticks[0]}")
        return type(record)(np.ascontiguousarray(ticks, dtype=np.int64))
    if isinstance(record, PressureBlock):
        values = np.asarray(record.values, dtype=np.float64)
        period = float(record.period_ticks)
        if values.ndim != 1:
            raise ValueError(f"PressureBlock.values must be 1-D, got shape {values.shape}")
        if int(record.cylinder) != record.cylinder or record.cylinder < 1:
            raise ValueError(f"PressureBlock.cylinder must be an integer >= 1, got {record.cylinder!r}")
        if int(record.t0_ticks) != record.t0_ticks or record.t0_ticks < 0:
            raise ValueError(f"PressureBlock.t0_ticks must be an integer >= 0, got {record.t0_ticks!r}")
        if not (period > 0 and math.isfinite(period)):
            raise ValueError(f"PressureBlock.period_ticks must be > 0 and finite, got {period!r}")
        if values.size == 0:
            return None
        return PressureBlock(int(record.cylinder), int(record.t0_ticks), period, np.ascontiguousarray(values))
    if isinstance(record, PressureFrame):
        return _checked_frame(record)
    if isinstance(record, LoadSample):
        if int(record.ticks) != record.ticks or record.ticks < 0:
            raise ValueError(f"LoadSample.ticks must be an integer >= 0, got {record.ticks!r}")
        return LoadSample(int(record.ticks), float(record.torque), float(record.power))
    raise TypeError(f"not a stream record: {type(record).__name__}")


def _checked_mark(mark: StreamRestart) -> StreamRestart:
    """A restart mark as the format holds it (docs/replay-format.md, ``restarts``); ValueError if it cannot be."""
    if int(mark.ticks) != mark.ticks or mark.ticks < 0:
        raise ValueError(f"StreamRestart.ticks must be an integer >= 0, got {mark.ticks!r}")
    if mark.dropped_records < 0 or (mark.dropped_records and (
            mark.dropped_from_ticks is None or not 0 <= mark.dropped_from_ticks <= mark.ticks)):
        raise ValueError(f"StreamRestart: {mark.dropped_records} records dropped from {mark.dropped_from_ticks}, "
                         f"the mark at {mark.ticks}")
    if mark.assembly not in ms.RESTART_ASSEMBLIES:
        raise ValueError(f"StreamRestart.assembly must be one of {ms.RESTART_ASSEMBLIES}, got {mark.assembly!r}")
    return mark


def _checked_frame(record: PressureFrame) -> PressureFrame | None:
    values = np.asarray(record.values, dtype=np.float64)
    period = float(record.period_ticks)
    try:
        cylinders = tuple(int(c) for c in record.cylinders)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"PressureFrame.cylinders must be integers, got {record.cylinders!r}") from exc
    if not cylinders or min(cylinders) < 1 or len(set(cylinders)) != len(cylinders) or \
            any(int(c) != c for c in record.cylinders):
        raise ValueError(f"PressureFrame.cylinders must be distinct integers >= 1, got {record.cylinders!r}")
    if values.ndim != 2 or values.shape[0] != len(cylinders):
        raise ValueError(f"PressureFrame.values must be ({len(cylinders)}, n), got shape {values.shape}")
    if int(record.t0_ticks) != record.t0_ticks or record.t0_ticks < 0:
        raise ValueError(f"PressureFrame.t0_ticks must be an integer >= 0, got {record.t0_ticks!r}")
    if not (period > 0 and math.isfinite(period)):
        raise ValueError(f"PressureFrame.period_ticks must be > 0 and finite, got {period!r}")
    if values.shape[1] == 0:
        return None
    return PressureFrame(cylinders, int(record.t0_ticks), period, np.ascontiguousarray(values))


class LogWriter:
    """Write stream records to an MCAP replay log (protobuf messages in zstd chunks; docs/replay-format.md).

    Parameters
    ----------
    path : output file (overwritten).
    engine_toml : the engine TOML text, stored verbatim as metadata (None if unknown).
    info : acquisition description (tick clock, wheel, pressure channels), stored as metadata.
    compression : "zstd" (default), "lz4" or "none".
    chunk_bytes : uncompressed chunk size [bytes]; a damaged chunk loses at most this much.
    batch_s : consecutive records of one stream are joined (and long ones split) into messages of about this
        span [s] to keep per-message overhead small; None writes one message per record.
    codec : message encoding; only the default (protobuf) is the project's format.
    """

    def __init__(
        self,
        path: str | Path,
        engine_toml: str | None,
        info: AcquisitionInfo,
        *,
        compression: str = "zstd",
        chunk_bytes: int = DEFAULT_CHUNK_BYTES,
        batch_s: float | None = DEFAULT_BATCH_S,
        codec: Codec | None = None,
    ) -> None:
        if compression not in _COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(_COMPRESSION)}, got {compression!r}")
        if engine_toml is not None and not isinstance(engine_toml, str):
            raise ValueError("engine_toml must be the TOML text (str) or None")
        if batch_s is not None and not batch_s > 0:
            raise ValueError(f"batch_s must be > 0 s or None, got {batch_s!r}")
        self._clock = ms.TickClock(info.tick_hz)
        self._acquisition = ms.acquisition_metadata(info)
        ms.acquisition_from_metadata(self._acquisition)  # the same checks a reader will apply
        self._engine = ms.with_crc({ms.ENGINE_KEY: engine_toml}) if engine_toml is not None else None
        self._batcher = Batcher(batch_s * info.tick_hz) if batch_s is not None else None
        self._file = open(path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file, chunk_size=chunk_bytes, compression=_COMPRESSION[compression])
        self._writer.start(profile="", library=ms.FORMAT)
        self._write_metadata()
        self._codec = codec if codec is not None else ProtobufCodec()
        self._channels = {}
        for name, (schema_name, schema_encoding, schema_data) in self._codec.schemas().items():
            schema_id = self._writer.register_schema(schema_name, schema_encoding, schema_data)
            self._channels[name] = self._writer.register_channel(
                ms.TOPICS[name], self._codec.message_encoding, schema_id
            )
        self._sequence: Counter[str] = Counter()
        self._flushed_at = 0
        self.messages = 0
        self.chunks_written = 0
        self.max_message_bytes = 0
        self._open_messages = 0
        self._chunk_bytes = chunk_bytes
        self._summary_bytes = sum(len(s[2]) + len(s[0]) + 64 for s in self._codec.schemas().values()) + 4096
        self._metadata_bytes = (
            sum(len(k) + len(v) + 8 for d in (self._engine or {}, self._acquisition) for k, v in d.items()) + 256
        )
        self._closed = False

    def _write_metadata(self) -> None:
        if self._engine is not None:
            self._writer.add_metadata(ms.META_ENGINE, self._engine)
        self._writer.add_metadata(ms.META_ACQUISITION, self._acquisition)

    def write(self, record: StreamRecord) -> None:
        """Log one record (empty ones are skipped). ValueError / TypeError if it cannot be represented."""
        if self._closed:
            raise ValueError("write to a closed LogWriter")
        if isinstance(record, StreamRestart):  # what is held for batching goes first: it all came before the mark
            for message in self._batcher.drain() if self._batcher is not None else ():
                self._emit(message)
            self._emit(_checked_mark(record))
            return
        checked = _checked(record)
        if checked is None:
            return
        for message in self._batcher.add(checked) if self._batcher is not None else (checked,):
            self._emit(message)
        position = self._file.tell()
        if position != self._flushed_at:  # a chunk went out: push it to the OS so a crash keeps it
            self._file.flush()
            self._flushed_at = position
            self.chunks_written += 1
            self._open_messages = 0

    def _emit(self, record: StreamRecord) -> None:
        name, data = self._codec.encode(record)
        log_time = self._clock.ns(ms.last_tick(record))
        self._sequence[name] += 1
        self._writer.add_message(self._channels[name], log_time, data, log_time, self._sequence[name] & 0xFFFFFFFF)
        self.messages += 1
        self._open_messages += 1
        self.max_message_bytes = max(self.max_message_bytes, len(data) + 31)

    @property
    def bytes_written(self) -> int:
        """Bytes in the file so far (the open chunk is still in memory, at most ``chunk_bytes`` + one message)."""
        return self._file.tell()

    def growth_bound(self) -> int:
        """Upper estimate [bytes] of what the file still grows by until closed (if nothing more is written): the
        open chunk, records held for batching, their indexes, the summary and the second metadata copy."""
        pending = self._batcher.pending_bytes if self._batcher is not None else 0
        open_data = self._chunk_bytes + self.max_message_bytes + pending
        chunks_left = 2 + open_data // self._chunk_bytes
        return (
            open_data
            + 16 * (self._open_messages + 64)
            + 200 * (self.chunks_written + chunks_left)
            + self._summary_bytes
            + self._metadata_bytes
        )

    def close(self) -> None:
        """Flush batched records, repeat the metadata (so one damaged copy is survivable), write the summary."""
        if self._closed:
            return
        self._closed = True
        try:
            for message in self._batcher.drain() if self._batcher is not None else ():
                self._emit(message)
            self._write_metadata()
            self._writer.finish()
        finally:
            self._file.close()

    def abort(self) -> None:
        """Stop writing after a failure: the chunks already out stay, no summary or footer is added, so a reader
        reports the log as truncated rather than as a complete recording (and a full disk is not written to again)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._file.close()
        except OSError:  # flushing the buffer failed too (a full disk): the error being handled already says so
            pass

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        """A clean exit closes the log; an exception (KeyboardInterrupt included) aborts it."""
        if exc_type is None:
            self.close()
        else:
            self.abort()


__all__ = ["Codec", "LogReader", "LogWriter", "ProtobufCodec"]
