"""Black-box recorder: the raw input of a live session into rotating, size-bounded MCAP replay logs.

    with Recorder("blackbox/", engine_toml, info, max_file_bytes=64 << 20, max_files=16) as rec:
        for record in source_records:          # whatever the live drivers yield, in acquisition order
            rec.write(record)

Files are ``<prefix>-<sequence>-<UTC time>.mcap`` (sequence continues across restarts). Each is a complete replay
log with its own metadata, so any one of them replays alone (``mcap:blackbox/rec-000042-....mcap``). A file is
closed before it would pass ``max_file_bytes``; when more than ``max_files`` exist the oldest is deleted, so the
folder never holds more than ``max_files * max_file_bytes``. Chunks go to the OS as soon as they are written; a
crash loses at most the open chunk, and the cut file still reads (LogReader tolerates the missing summary).
Not thread-safe: call from the ingest thread.
"""

from __future__ import annotations

import logging
import re
import time
from collections import Counter
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Self

from frictionwatch.core.types import AcquisitionInfo, StreamRecord
from frictionwatch.drivers.logs.mcap_log import DEFAULT_CHUNK_BYTES, LogWriter

log = logging.getLogger(__name__)

MIN_FILE_BYTES = 128 * 1024


class Recorder:
    """Rotating MCAP recorder.

    Parameters
    ----------
    directory : folder of the files (created).
    engine_toml, info : as for ``LogWriter``; stored in every file.
    max_file_bytes : upper bound of one file [bytes] (>= 128 KiB).
    max_files : files kept, the one being written included (>= 1).
    prefix : file name prefix.
    chunk_bytes : uncompressed chunk size; default min(128 KiB, max_file_bytes / 8).
    """

    def __init__(
        self,
        directory: str | Path,
        engine_toml: str | None,
        info: AcquisitionInfo,
        *,
        max_file_bytes: int = 64 << 20,
        max_files: int = 16,
        prefix: str = "rec",
        compression: str = "zstd",
        chunk_bytes: int | None = None,
        utc: Callable[[], float] = time.time,
    ) -> None:
        if max_file_bytes < MIN_FILE_BYTES:
            raise ValueError(f"max_file_bytes must be >= {MIN_FILE_BYTES} bytes, got {max_file_bytes}")
        if max_files < 1:
            raise ValueError(f"max_files must be >= 1, got {max_files}")
        if not re.fullmatch(r"[A-Za-z0-9_.]+", prefix):
            raise ValueError(f"prefix must be letters, digits, '_' or '.', got {prefix!r}")
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.engine_toml, self.info = engine_toml, info
        self.max_file_bytes, self.max_files = max_file_bytes, max_files
        self.prefix, self.compression = prefix, compression
        self.chunk_bytes = chunk_bytes or max(16 * 1024, min(DEFAULT_CHUNK_BYTES, max_file_bytes // 8))
        self._utc = utc
        self._pattern = re.compile(re.escape(prefix) + r"-(\d{6,})-.*\.mcap")
        existing = self.files
        self._sequence = self._number(existing[-1]) + 1 if existing else 0
        self._writer: LogWriter | None = None
        self._path: Path | None = None
        self.skipped: Counter[str] = Counter()
        self._closed = False

    def _number(self, path: Path) -> int:
        match = self._pattern.fullmatch(path.name)
        return int(match.group(1)) if match else -1

    @property
    def files(self) -> list[Path]:
        """The recorder's files in the folder, oldest first (the open one last)."""
        found = [p for p in self.directory.iterdir() if self._pattern.fullmatch(p.name)]
        return sorted(found, key=self._number)

    @property
    def current(self) -> Path | None:
        return self._path

    def _open(self) -> LogWriter:
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(self._utc()))
        self._path = self.directory / f"{self.prefix}-{self._sequence:06d}-{stamp}.mcap"
        self._sequence += 1
        self._writer = LogWriter(
            self._path, self.engine_toml, self.info, compression=self.compression, chunk_bytes=self.chunk_bytes
        )
        for old in self.files[: -self.max_files]:  # the new file counts towards max_files
            old.unlink(missing_ok=True)
            log.info("recorder: deleted %s (more than %d files)", old.name, self.max_files)
        return self._writer

    def write(self, record: StreamRecord) -> None:
        """Record one stream record; one that cannot be logged is counted in ``skipped``, never raised."""
        if self._closed:
            raise ValueError("write to a closed Recorder")
        writer = self._writer or self._open()
        try:
            writer.write(record)
        except (ValueError, TypeError) as exc:
            reason = f"unloggable {type(record).__name__}: {exc}"
            if not self.skipped[reason]:
                log.warning("recorder: %s", reason)
            self.skipped[reason] += 1
            return
        if writer.bytes_written + writer.growth_bound() >= self.max_file_bytes:
            self._rotate()

    def write_many(self, records: Iterable[StreamRecord]) -> None:
        for record in records:
            self.write(record)

    def _rotate(self) -> None:
        if self._writer is not None:
            self._writer.close()
            assert self._path is not None
            size = self._path.stat().st_size
            if size > self.max_file_bytes:  # the reserve estimate failed; say so rather than hide it
                log.warning("recorder: %s is %d bytes, over the %d bound", self._path.name, size, self.max_file_bytes)
        self._writer = None
        self._path = None

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._rotate()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
