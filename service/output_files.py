"""Output files that are whole or absent: written to a temporary file beside the target and renamed into place.

A run that is interrupted (SIGINT, a full disk, an exception) leaves no partial file behind; two runs writing the
same target each write their own temporary file and the later rename wins whole (POSIX ``rename`` is atomic within a
folder). ``atomic_paths`` does the same for files that belong together, committed as a set. ``check_output_path``
finds an unwritable target before a long run starts rather than after it. POSIX only (flock, signal masks).
"""

from __future__ import annotations

import fcntl
import os
import secrets
import signal
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
    blocker = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
    if blocker is not None:
        raise NotADirectoryError(f"cannot write output {path}: {blocker} is a file, not a folder")
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
    with atomic_paths(path) as (tmp,):
        yield tmp


@contextmanager
def atomic_paths(*paths: Path) -> Iterator[tuple[Path, ...]]:
    """``atomic_path`` for outputs that belong together (a log and its sidecar truth): one temporary beside each
    target; when the block ends without an exception they are flushed to disk and renamed into place in the order
    given, on any exception all are removed and the targets are left as they were.

    The renames run with SIGINT and SIGTERM held (delivered once they are done) and under an exclusive lock of the
    target folders, so two runs writing the same targets commit one after the other and the set on disk is one
    run's, whole. Put the main file last (the log after its truth), so a log on disk always has its own truth
    beside it; only a hard kill or power loss in the instant between two renames can leave a new sidecar beside the
    previous main file."""
    paths = tuple(Path(p) for p in paths)
    for path in paths:
        check_output_path(path)
    if len({p.resolve() for p in paths}) != len(paths):
        raise ValueError(f"the same output twice: {', '.join(map(str, paths))}")
    tmps: list[Path] = []
    try:
        for path in paths:
            tmps.append(_new_temporary(path))
        yield tuple(tmps)
        for tmp in tmps:
            _fsync_file(tmp)
        with _folders_locked({p.parent for p in paths}), _signals_held():
            for tmp, path in zip(tmps, paths):
                os.replace(tmp, path)
    except BaseException:
        for tmp in tmps:
            tmp.unlink(missing_ok=True)
        raise
    for folder in {p.parent for p in paths}:
        _fsync_dir(folder)


def _new_temporary(path: Path) -> Path:
    """An empty new file ``.NAME.RANDOM.part`` beside ``path``, created with the permissions ``open`` would give
    (0666 less the umask, or the replaced file's own; ``tempfile.mkstemp`` would make it 0600)."""
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.part")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        try:
            if path.exists():  # a replaced file keeps its own mode, as an open() for writing would leave it
                os.fchmod(fd, path.stat().st_mode & 0o7777)
        finally:
            os.close(fd)
        return tmp
    raise FileExistsError(f"cannot create a temporary file beside output {path}")


@contextmanager
def _folders_locked(folders: set[Path]) -> Iterator[None]:
    """Exclusive flock(2) of each folder (in a fixed order, so two runs cannot deadlock); released on exit."""
    fds = []
    try:
        for folder in sorted(folders):
            fd = os.open(folder, os.O_RDONLY)
            fds.append(fd)
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        for fd in fds:
            os.close(fd)  # closing the descriptor releases its lock


@contextmanager
def _signals_held() -> Iterator[None]:
    held = {signal.SIGINT, signal.SIGTERM}
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


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
