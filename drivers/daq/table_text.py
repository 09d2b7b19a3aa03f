"""The numeric rows of a text table (a DAQ export, a crank-angle CSV), tolerant of one thing only: a last line cut
short. A file copied or read while its writer was still at it ends mid-row (no line end, too few values); that row
is dropped and said, rather than the whole file refused for it. A bad row anywhere else refuses the file."""

from __future__ import annotations

import warnings

import numpy as np
from frictionwatch.drivers.errors import CorruptLog


def numeric_rows(text: str, name: str, what: str, delimiter: str | None = None) -> tuple[np.ndarray, list[str]]:
    """(rows, notes): ``text`` as a float table (``np.loadtxt``, ``ndmin=2``), and a note when its cut last line
    was dropped. CorruptLog "``name``: not a ``what``: <why>" otherwise."""
    lines = text.splitlines()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "input contained no data": the caller's size check says it
        try:
            return np.loadtxt(lines, delimiter=delimiter, ndmin=2), []
        except ValueError as exc:
            first = exc
        if text.endswith(("\n", "\r")) or len(lines) < 2:  # a whole last line: the bad row is a real one
            raise CorruptLog(f"{name}: not a {what}: {' '.join(str(first).split())}") from None
        try:
            rows = np.loadtxt(lines[:-1], delimiter=delimiter, ndmin=2)
        except ValueError as exc:
            raise CorruptLog(f"{name}: not a {what}: {' '.join(str(exc).split())}") from None
    return rows, [f"the last line, cut short ({lines[-1][:40]!r}, no line end), was dropped"]
