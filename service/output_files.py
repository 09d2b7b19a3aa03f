"""Output files that are whole or absent: written to a temporary file beside the target and renamed into place.

A run that is interrupted (SIGINT, a full disk, an exception) leaves no partial file behind; two runs writing the
same target each write their own temporary file and the later rename wins whole (POSIX ``rename`` is atomic within a
folder). ``check_output_path`` finds an unwritable target before a long run starts rather than after it.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import IO


def check_output_path(path: Path) -> None:
    """Raise a one-line ``OSError`` if ``path`` cannot be written: its folder is not creatable or writable, or the
    path is a folder. Creates the missing parent folders (as the write would)."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"output {path} is a folder, expected a file name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OSError(f"cannot create the folder of output {path}: {exc.strerror or exc}") from None
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise PermissionError(f"cannot write output {path}: folder {path.parent} is not writable")
    if path.exists() and not os.access(path, os.W_OK):
        raise PermissionError(f"cannot write output {path}: the file exists and is read-only")


@contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on a clean exit it is flushed to disk and renamed to ``path``, on any
    exception (KeyboardInterrupt included) it is removed. For writers that open the file themselves."""
    path = Path(path)
    check_output_path(path)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    # mkstemp makes the file private (0600); the output gets what a plain open() would give it: the file's own mode
    # when it replaces one, else 0666 less the umask
    os.fchmod(fd, _mode_for(path))
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        _fsync_file(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


@contextmanager
def atomic_output(path: Path, mode: str = "w", newline: str | None = "\n",
                  encoding: str | None = "utf-8") -> Iterator[IO]:
    """Open a temporary file beside ``path`` for writing (text: UTF-8, LF line endings by default; ``mode='wb'`` for
    bytes) and rename it to ``path`` when the block ends without an exception; otherwise nothing is left behind."""
    if "b" in mode:
        newline = encoding = None
    with ExitStack() as stack:
        tmp = stack.enter_context(atomic_path(path))
        fh = stack.enter_context(open(tmp, mode, newline=newline, encoding=encoding))
        yield fh
        fh.flush()


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` whole or not at all."""
    with atomic_output(path) as fh:
        fh.write(text)


def _mode_for(path: Path) -> int:
    try:
        return path.stat().st_mode & 0o7777
    except FileNotFoundError:
        umask = os.umask(0)  # read it back at once: umask can only be read by setting it
        os.umask(umask)
        return 0o666 & ~umask


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(folder: Path) -> None:
    # the rename itself is durable only once the folder entry is on disk; some filesystems refuse a folder fsync
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
