"""Damage-tolerant MCAP scanning: one linear pass over the top-level records, resync after damage, chunk decoding.

Why not mcap's own readers: ``SeekingReader`` needs the summary (gone when a recorder lost power) and
``StreamReader`` raises at the first bad byte and cannot resync, losing every intact chunk after it. This module
uses mcap's record classes to parse, but walks the file itself:

- ``scan(buf, note)`` lists chunks (and runs of un-chunked messages) with their log-time ranges, and collects the
  top-level Schema, Channel and Metadata records (the summary repeats schemas and channels, so a damaged first
  chunk still leaves them known). Every record is checked before its length is trusted (``_check``); one that
  fails, or runs past the end, triggers a resync: the next offset where a record checks out (a Chunk whose inner
  lengths add up exactly, a Schema/Channel/Metadata/index record that parses to exactly its length, or a weaker
  record followed by a plausible one). Nothing found = the file was cut there.
- ``chunk_records(buf, ref)`` decompresses one chunk and checks its CRC; a chunk cut by the end of the file is
  decoded as far as its compressed stream goes (truncation drops bytes but never alters them).

Damage goes to ``note(reason, offset)``; the caller counts each (reason, offset) once.
"""

from __future__ import annotations

import re
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from io import BytesIO
from typing import Any

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    ChunkIndex,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)

try:
    import lz4.frame as lz4_frame
except ImportError:  # pragma: no cover - lz4 is optional in mcap too
    lz4_frame = None

MAGIC = b"\x89MCAP0\r\n"
_HEAD = struct.Struct("<BQ")  # opcode, record length
_CHUNK = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_PARSERS: dict[int, Any] = {  # records checked by parsing them to exactly their length
    Opcode.HEADER: Header,
    Opcode.SCHEMA: Schema,
    Opcode.CHANNEL: Channel,
    Opcode.METADATA: Metadata,
    Opcode.CHUNK_INDEX: ChunkIndex,
    Opcode.METADATA_INDEX: MetadataIndex,
    Opcode.ATTACHMENT: Attachment,
    Opcode.ATTACHMENT_INDEX: AttachmentIndex,
    Opcode.STATISTICS: Statistics,
}
_FIXED_LENGTH = {Opcode.FOOTER: 20, Opcode.DATA_END: 4, Opcode.SUMMARY_OFFSET: 17}
_RESYNC = re.compile(b"[" + re.escape(bytes(range(Opcode.HEADER, Opcode.DATA_END + 1))) + b"]")
_RUN_BYTES = 1 << 20  # un-chunked messages are grouped into runs of about this size
_MAX_CHUNK_BYTES = 1 << 31  # a larger claim is a damaged header, not a chunk (and would exhaust memory)
Note = Callable[[str, int], None]


@dataclass
class ChunkRef:
    """Where a chunk (or a run of top-level messages, ``compression=None``) lies and which log times it holds."""

    offset: int  # file offset of the record (or of the run's first record)
    start_ns: int
    end_ns: int
    data_start: int  # compressed payload [data_start, data_end) in the file
    data_end: int
    compression: str | None = None
    uncompressed_size: int = 0
    crc: int = 0
    truncated: bool = False  # the file ends inside this chunk


@dataclass
class Scan:
    chunks: list[ChunkRef] = field(default_factory=list)
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    metadata: list[tuple[int, Metadata]] = field(default_factory=list)  # (offset, record) in file order
    magic_ok: bool = False
    footer_seen: bool = False


def _parse(op: int, body: bytes) -> Any:
    """A parsed record if ``body`` parses to exactly its length, else None."""
    stream = ReadDataStream(BytesIO(body))
    try:
        record = _PARSERS[op].read(stream)
    except Exception:  # noqa: BLE001 - foreign parser on garbage: EndOfFile, struct.error, UnicodeDecodeError...
        return None
    return record if stream.count == len(body) else None


def _chunk_header(buf: Any, pos: int, length: int, size: int) -> ChunkRef | None:
    """The chunk at ``pos`` if its inner fields are consistent (``length`` may run past EOF when truncated)."""
    body = pos + 9
    if body + _CHUNK.size > size:
        return None
    start, end, usize, crc, clen = _CHUNK.unpack_from(buf, body)
    at = body + _CHUNK.size
    if clen > 16 or at + clen + 8 > size:
        return None
    try:
        compression = bytes(buf[at : at + clen]).decode()
    except UnicodeDecodeError:
        return None
    (dlen,) = struct.unpack_from("<Q", buf, at + clen)
    data_start = at + clen + 8
    if compression not in ("", "zstd", "lz4") or start > end or data_start + dlen != body + length:
        return None
    return ChunkRef(pos, start, end, data_start, data_start + dlen, compression, usize, crc, data_start + dlen > size)


def _plausible_header(buf: Any, pos: int, size: int) -> bool:
    """A known opcode whose record fits in the file, or exactly the end of the file."""
    if pos == size:
        return True
    if pos + 9 > size:
        return False
    op, length = _HEAD.unpack_from(buf, pos)
    return Opcode.HEADER <= op <= Opcode.DATA_END and pos + 9 + length <= size


def _check(buf: Any, pos: int, size: int, channels: dict[int, Channel]) -> tuple[bool, Any]:
    """``(ok, parsed)`` for the record at ``pos``: ok if it is well formed and fits in the file.

    Chunks, parsed records and message indexes account for exactly their length (strong). Fixed-length
    records, top-level messages and unknown opcodes are weak: the record after them must look like one too.
    ``parsed`` is a ChunkRef, a parsed mcap record, or None.
    """
    op, length = _HEAD.unpack_from(buf, pos)
    end = pos + 9 + length
    if end > size:
        return False, None
    if op == Opcode.CHUNK:
        ref = _chunk_header(buf, pos, length, size)
        return ref is not None, ref
    if op in _PARSERS:
        record = _parse(op, bytes(buf[pos + 9 : end]))
        return record is not None, record
    if op == Opcode.MESSAGE_INDEX:
        return length >= 6 and struct.unpack_from("<I", buf, pos + 11)[0] == length - 6 and length % 16 == 6, None
    if op == Opcode.FOOTER and length == 20 and bytes(buf[end : end + 8]) == MAGIC:
        return True, None
    if op in _FIXED_LENGTH and length != _FIXED_LENGTH[op]:
        return False, None
    if op == Opcode.MESSAGE and (length < _MESSAGE.size or _MESSAGE.unpack_from(buf, pos + 9)[0] not in channels):
        return False, None
    return _plausible_header(buf, end, size), None


def _resync(buf: Any, pos: int, size: int, channels: dict[int, Channel]) -> int | None:
    """Offset of the next well-formed record at or after ``pos``; None if there is none."""
    while (m := _RESYNC.search(buf, pos)) is not None:
        at = m.start()
        if at + 9 <= size and _check(buf, at, size, channels)[0]:
            return at
        pos = at + 1
    return None


def scan(buf: Any, note: Note) -> Scan:
    """Index a possibly damaged MCAP held in ``buf`` (bytes or mmap); damage goes to ``note``."""
    out = Scan()
    size = len(buf)
    out.magic_ok = bytes(buf[:8]) == MAGIC
    pos: int | None = 8
    if not out.magic_ok:
        note("bad magic", 0)
        pos = _resync(buf, 0, size, out.channels)
    run: ChunkRef | None = None
    while pos is not None and pos < size:
        if pos + 9 > size:
            note("truncated", pos)
            break
        op, length = _HEAD.unpack_from(buf, pos)
        if op != Opcode.MESSAGE and run is not None:
            out.chunks.append(run)
            run = None
        ok, parsed = _check(buf, pos, size, out.channels)
        if not ok:
            nxt = _resync(buf, pos + 1, size, out.channels)
            if nxt is None:  # nothing valid follows: the file was cut here (or its tail is garbage)
                if op == Opcode.CHUNK and pos + 9 + length > size:
                    ref = _chunk_header(buf, pos, length, size)
                    if ref is not None:
                        out.chunks.append(ref)  # cut inside this chunk: decode what is there
                note("truncated", pos)
                break
            note("damaged record", pos)
            pos = nxt
            continue
        end = pos + 9 + length
        if isinstance(parsed, ChunkRef):
            out.chunks.append(parsed)
        elif isinstance(parsed, Schema):
            out.schemas[parsed.id] = parsed
        elif isinstance(parsed, Channel):
            out.channels[parsed.id] = parsed
        elif isinstance(parsed, Metadata):
            out.metadata.append((pos, parsed))
        elif op == Opcode.MESSAGE:
            log_time = _MESSAGE.unpack_from(buf, pos + 9)[2]
            if run is None:
                run = ChunkRef(pos, log_time, log_time, pos, end)
            run.start_ns, run.end_ns, run.data_end = min(run.start_ns, log_time), max(run.end_ns, log_time), end
            if run.data_end - run.data_start > _RUN_BYTES:
                out.chunks.append(run)
                run = None
        elif op == Opcode.FOOTER:
            out.footer_seen = True
            if bytes(buf[end : end + 8]) != MAGIC:
                note("truncated", end)
            break
        pos = end
    if run is not None:
        out.chunks.append(run)
    if not out.footer_seen and pos is not None and pos >= size:
        note("truncated", size)  # ended on a record boundary, but before the footer
    return out


def _decompress(buf: Any, ref: ChunkRef) -> bytes:
    data = buf[ref.data_start : min(ref.data_end, len(buf))]
    if ref.uncompressed_size > _MAX_CHUNK_BYTES:
        raise ValueError(f"chunk claims {ref.uncompressed_size} bytes uncompressed")
    if ref.compression == "zstd":
        if ref.truncated:
            return zstandard.ZstdDecompressor().decompressobj().decompress(data)
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=ref.uncompressed_size)
    if ref.compression == "lz4":
        if lz4_frame is None:
            raise RuntimeError("lz4 chunk but the lz4 package is missing")
        if ref.truncated:
            return lz4_frame.LZ4FrameDecompressor().decompress(data)
        return lz4_frame.decompress(data)
    return bytes(data)


def chunk_records(buf: Any, ref: ChunkRef, note: Note) -> list[Any]:
    """Schema / Channel records and ``(channel_id, sequence, log_time, data)`` message tuples of one chunk, in order.

    A chunk that fails to decompress or fails its CRC yields nothing (note ``corrupt chunk``); a truncated one yields
    its complete leading records (note ``partial chunk``).
    """
    if ref.compression is None:
        data, crc_checked = bytes(buf[ref.data_start : ref.data_end]), True
    else:
        try:
            data = _decompress(buf, ref)
        except (zstandard.ZstdError, RuntimeError, ValueError, OSError, MemoryError) as exc:  # lz4 raises RuntimeError
            note(f"corrupt chunk ({type(exc).__name__})", ref.offset)
            return []
        if ref.truncated:
            note("partial chunk", ref.offset)
            crc_checked = False
        elif len(data) != ref.uncompressed_size or (ref.crc and zlib.crc32(data) != ref.crc):
            note("corrupt chunk (crc)", ref.offset)
            return []
        else:
            crc_checked = True
    out: list[Any] = []
    pos, size = 0, len(data)
    while pos + 9 <= size:
        op, length = _HEAD.unpack_from(data, pos)
        end = pos + 9 + length
        if end > size:
            break
        if op == Opcode.MESSAGE and length >= _MESSAGE.size:
            channel_id, sequence, log_time, _ = _MESSAGE.unpack_from(data, pos + 9)
            out.append((channel_id, sequence, log_time, data[pos + 9 + _MESSAGE.size : end]))
        elif op in (Opcode.SCHEMA, Opcode.CHANNEL):
            record = _parse(op, data[pos + 9 : end])
            if record is None:
                break
            out.append(record)
        pos = end
    if pos != size and crc_checked:
        note("bad record in chunk", ref.offset)  # CRC was fine: the writer made it so
    return out
