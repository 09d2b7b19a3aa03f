"""Damage-tolerant reader of MCAP replay logs (docs/replay-format.md), and the message codec interface.

``LogReader`` walks the file with drivers/logs/mcap_scan.py (no summary needed), decodes chunk by chunk and merges them
into log-time order. A truncated file, a corrupt chunk or a bad message costs only the damaged part: every intact
record is yielded and ``damage`` counts what was skipped (reason -> count).
"""

from __future__ import annotations

import heapq
import logging
import math
import mmap
from collections import Counter
from collections.abc import Callable, Hashable, Iterator
from pathlib import Path
from typing import Any, Protocol, Self

import frictionwatch.drivers.logs.mcap_schema as ms
from frictionwatch.core.types import AcquisitionInfo, StreamRecord
from frictionwatch.drivers.errors import CorruptLog
from frictionwatch.drivers.logs.mcap_scan import ChunkRef, chunk_records, scan
from mcap.records import Channel, Schema

log = logging.getLogger(__name__)


class Codec(Protocol):
    """How records become MCAP messages. The project's format is ``ProtobufCodec``; bench/bench_log_format.py
    measures alternatives through the same writer and reader."""

    message_encoding: str

    def schemas(self) -> dict[str, tuple[str, str, bytes]]:
        """Message name ("ToothBatch"...) -> (MCAP schema name, schema encoding, schema data)."""
        ...

    def encode(self, record: StreamRecord) -> tuple[str, bytes]:
        """(message name, message bytes)."""
        ...

    def decoder_for(self, message_encoding: str, schema: Schema | None) -> Callable[[bytes], StreamRecord] | None:
        """Same shape as ``mcap.decoder.DecoderFactory.decoder_for``: a decoder, or None if the channel is not ours."""
        ...


class ProtobufCodec:
    """The replay format: protobuf messages whose schema matches docs/replay-format.md."""

    message_encoding = "protobuf"

    def __init__(self) -> None:
        self._counts = ms.PressureCounts()

    def schemas(self) -> dict[str, tuple[str, str, bytes]]:
        data = ms.schema_data()
        return {name: (f"{ms.PACKAGE}.{name}", "protobuf", data) for name in ms.MESSAGES}

    def encode(self, record: StreamRecord) -> tuple[str, bytes]:
        return ms.encode(record, self._counts)

    def decoder_for(self, message_encoding: str, schema: Schema | None) -> Callable[[bytes], StreamRecord] | None:
        if schema is None or message_encoding != "protobuf" or schema.encoding != "protobuf":
            return None
        if schema.name not in ms.DECODERS or not ms.schema_matches(schema.name, schema.data):
            return None
        return ms.DECODERS[schema.name]


def _log_time(item: tuple[int, int, StreamRecord]) -> int:
    return item[0]


class LogReader:
    """Read a replay log, tolerating truncation and corrupt chunks (every intact record is yielded).

    ``damage`` counts what was skipped (reason -> count); structural damage is known after opening, chunk damage
    after ``records()`` has passed it. Raises CorruptLog if the file holds nothing readable (not an MCAP, or no
    acquisition metadata), and from ``records()`` if a full pass found damage and no record at all.
    """

    def __init__(self, path: str | Path, *, codec: Codec | None = None) -> None:
        self.path = Path(path)
        self.damage: Counter[str] = Counter()
        self._noted: set[tuple[str, Hashable]] = set()
        self._codec = codec if codec is not None else ProtobufCodec()
        try:
            self._file = open(self.path, "rb")  # noqa: SIM115 - closed in close()
        except FileNotFoundError as exc:  # one line for the user (serve's mcap: source), not "[Errno 2] ..."
            raise FileNotFoundError(f"no such log: {self.path}") from exc
        except IsADirectoryError as exc:
            raise IsADirectoryError(f"{self.path} is a folder, not a log") from exc
        try:
            try:
                self._buf: Any = mmap.mmap(self._file.fileno(), 0, access=mmap.ACCESS_READ)
            except ValueError as exc:  # empty file
                raise CorruptLog(f"{self.path}: empty file, not an MCAP log") from exc
            self._scan = scan(self._buf, self._note)
            self.metadata = self._pick_metadata()
            if not self._scan.magic_ok and not self._scan.chunks and not self.metadata:
                raise CorruptLog(f"{self.path}: not an MCAP file (no magic, no readable record)")
            if ms.META_ACQUISITION not in self.metadata:
                raise CorruptLog(
                    f"{self.path}: no readable '{ms.META_ACQUISITION}' metadata (tick_hz, wheel); "
                    "the ticks cannot be interpreted"
                )
        except BaseException:
            self.close()
            raise
        self.info: AcquisitionInfo = ms.acquisition_from_metadata(self.metadata[ms.META_ACQUISITION])
        self.engine_toml: str | None = self.metadata.get(ms.META_ENGINE, {}).get(ms.ENGINE_KEY)
        self._schemas: dict[int, Schema] = dict(self._scan.schemas)
        self._channels: dict[int, Channel] = dict(self._scan.channels)
        self._decoders: dict[int, Callable[[bytes], StreamRecord] | None] = {}
        self._defs_scanned: set[int] = set()

    def _note(self, reason: str, key: Hashable) -> None:
        if (reason, key) in self._noted:
            return
        self._noted.add((reason, key))
        if self.damage[reason] == 0:
            log.warning("%s: %s (at %s)", self.path, reason, key)
        self.damage[reason] += 1

    def _pick_metadata(self) -> dict[str, dict[str, str]]:
        """The first intact copy of each metadata record (crc32 checked where present)."""
        picked: dict[str, dict[str, str]] = {}
        for offset, record in self._scan.metadata:
            if record.name in picked:
                continue
            if not ms.crc_ok(record.metadata):
                self._note("corrupt metadata", offset)
                continue
            if record.name == ms.META_ACQUISITION:
                try:
                    ms.acquisition_from_metadata(record.metadata)
                except ValueError:
                    self._note("bad acquisition metadata", offset)
                    continue
            picked[record.name] = dict(record.metadata)
        return picked

    @property
    def start_ns(self) -> int | None:
        """Earliest log time [ns] of any chunk (None if the log holds none)."""
        return min((c.start_ns for c in self._scan.chunks), default=None)

    @property
    def end_ns(self) -> int | None:
        return max((c.end_ns for c in self._scan.chunks), default=None)

    def _register(self, record: Schema | Channel) -> None:
        """A definition met inside a chunk (CRC-checked) replaces the summary's copy."""
        if isinstance(record, Schema):
            self._schemas[record.id] = record
        else:
            self._channels[record.id] = record
        self._decoders.clear()  # rare: definitions come once per file

    def _decoder(self, channel_id: int) -> Callable[[bytes], StreamRecord] | None:
        if channel_id in self._decoders:
            return self._decoders[channel_id]
        if channel_id not in self._channels and len(self._defs_scanned) < len(self._scan.chunks):
            for ref in self._scan.chunks:  # summary lost and definitions not met yet: look in the other chunks
                if channel_id in self._channels:
                    break
                if ref.offset not in self._defs_scanned:
                    self._defs_scanned.add(ref.offset)
                    for item in chunk_records(self._buf, ref, self._note):
                        if isinstance(item, Schema | Channel):
                            self._register(item)
        channel = self._channels.get(channel_id)
        if channel is None:
            return None
        decoder = self._codec.decoder_for(channel.message_encoding, self._schemas.get(channel.schema_id))
        self._decoders[channel_id] = decoder
        return decoder

    def _decode_chunk(self, ref: ChunkRef, lo: int, hi: float) -> list[tuple[int, int, StreamRecord]]:
        """``(log_time, index in chunk, record)`` of the chunk's messages in [lo, hi), sorted by log time."""
        out: list[tuple[int, int, StreamRecord]] = []
        decoders = self._decoders
        for index, item in enumerate(chunk_records(self._buf, ref, self._note)):
            if not isinstance(item, tuple):
                self._register(item)
                continue
            channel_id, _, log_time, data = item
            if log_time < lo or log_time >= hi:
                continue
            decoder = decoders[channel_id] if channel_id in decoders else self._decoder(channel_id)
            if decoder is None:
                channel = self._channels.get(channel_id)
                reason = "unknown channel" if channel is None else f"unknown schema on topic '{channel.topic}'"
                self._note(f"skipped message ({reason})", (ref.offset, index))
                continue
            try:
                out.append((log_time, index, decoder(data)))
            except Exception as exc:  # noqa: BLE001 - a bad message is counted, the replay goes on
                self._note(f"undecodable message ({type(exc).__name__})", (ref.offset, index))
        out.sort(key=_log_time)
        return out

    def iter_timed(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[tuple[int, StreamRecord]]:
        """``(log_time_ns, record)`` with ``start_ns <= log_time < end_ns``, in log-time order (file order on ties).

        A k-way merge over chunks keyed by their start time; a chunk's messages that precede every pending
        chunk or message are yielded at once, only the overlap goes through the heap.
        """
        lo = 0 if start_ns is None else start_ns
        hi = math.inf if end_ns is None else end_ns
        heap: list[tuple[int, int, Any, Any]] = [
            (ref.start_ns, seq, None, ref)
            for seq, ref in enumerate(self._scan.chunks)
            if ref.end_ns >= lo and ref.start_ns < hi
        ]
        heapq.heapify(heap)
        seq = len(self._scan.chunks)
        last, count = -1, 0
        while heap:
            log_time, _, key, item = heapq.heappop(heap)
            if isinstance(item, ChunkRef):
                bound = heap[0][0] if heap else math.inf
                for t, index, record in self._decode_chunk(item, lo, hi):
                    if t >= bound:
                        seq += 1
                        heapq.heappush(heap, (t, seq, (item.offset, index), record))
                    elif t < last:  # only a damaged chunk header (start time too late) can cause this
                        self._note("out of order (dropped)", (item.offset, index))
                    else:
                        last = t
                        count += 1
                        yield t, record
                continue
            if log_time < last:
                self._note("out of order (dropped)", key)
                continue
            last = log_time
            count += 1
            yield log_time, item
        if count == 0 and start_ns is None and end_ns is None and self.damage:
            raise CorruptLog(f"{self.path}: no readable record; damage {dict(self.damage)}")

    def records(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[StreamRecord]:
        """Stream records with ``start_ns <= log_time < end_ns`` in log-time order; damage is counted, not raised."""
        for _, record in self.iter_timed(start_ns, end_ns):
            yield record

    def close(self) -> None:
        buf = getattr(self, "_buf", None)
        if buf is not None and not buf.closed:
            buf.close()
        self._file.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
