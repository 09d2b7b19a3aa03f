"""A progress bar on stderr for long runs (tqdm), quiet when stderr is not a terminal.

``analyze`` shows the cycles done and, where the log's time span is known from its chunk index (read when the log
is opened, no decoding), the fraction of the log passed with an estimate of the time left.

A fresh install compiles its numba kernels on first use (tens of seconds; cached on disk afterwards), before the first
cycle can be shown. So that a new user does not stare at a silent terminal, a bar that has seen no progress after
``NOTE_AFTER_S`` says once, on stderr, what is happening (also when stderr is not a terminal: CI logs show it).
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

NOTE_AFTER_S = 2.0
COMPILING_NOTE = ("compiling the numerical kernels (numba, first run after an install only: about a minute on a "
                  "small machine; later runs load them from the cache)")


class Bar:
    """A tqdm bar driven by a count (``update``), a fraction of the total (``set_fraction``), or both
    (``advance``: one more item and where the run is); ``started`` once any progress was reported."""

    def __init__(self, bar: tqdm, total: float, unit: str):
        self._bar, self._total, self._unit = bar, total, unit
        self.count = 0
        self.started = threading.Event()

    def set_fraction(self, fraction: float) -> None:
        self.started.set()
        self._bar.n = min(max(fraction, 0.0), 1.0) * self._total
        self._bar.refresh()

    def update(self, n: float = 1) -> None:
        self.started.set()
        self.count += int(n)
        self._bar.update(n)

    def advance(self, fraction: float | None) -> None:
        """One more item done; ``fraction``: how far through the run it is (None: not known)."""
        self.count += 1
        if fraction is None or not self._total:
            self.started.set()
            self._bar.update(1)
            return
        self._bar.set_postfix_str(f"{self.count} {self._unit}", refresh=False)
        self.set_fraction(fraction)


@contextmanager
def progress_bar(total: float, desc: str, waiting_note: str | None = COMPILING_NOTE,
                 unit: str = "cycles") -> Iterator[Bar]:
    """``total``: the bar's full scale (a fraction bar: 1.0), 0 when unknown (then a count of ``unit`` is shown);
    ``waiting_note``: printed once if no progress arrives within NOTE_AFTER_S (None: never)."""
    bar = tqdm(total=total or None, desc=desc, file=sys.stderr, disable=not sys.stderr.isatty(), leave=False,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {postfix} {elapsed}<{remaining}" if total else
               "{desc}: {n_fmt} {unit} {elapsed}", unit=unit)
    wrapped = Bar(bar, total, unit)
    timer = None
    if waiting_note:
        def note() -> None:
            if not wrapped.started.is_set():
                tqdm.write(f"{desc}: {waiting_note}", file=sys.stderr)
        timer = threading.Timer(NOTE_AFTER_S, note)
        timer.daemon = True
        timer.start()
    try:
        yield wrapped
    finally:
        if timer is not None:
            timer.cancel()
        bar.close()


@dataclass(frozen=True)
class LogExtent:
    """The time span of a log's records [s, in the tick time base of the cycles' ``t_start``]; None: unknown."""

    start_s: float | None = None
    end_s: float | None = None

    @property
    def known(self) -> bool:
        return self.start_s is not None and self.end_s is not None and self.end_s > self.start_s

    def fraction(self, t_s: float) -> float | None:
        """How far through the log time ``t_s`` is (0..1), None when the span is not known."""
        if not self.known:
            return None
        return min(max((t_s - self.start_s) / (self.end_s - self.start_s), 0.0), 1.0)


def log_extent(path: Path) -> LogExtent:
    """The span of an MCAP log from its chunk index (cheap: no record is decoded). Unknown for a log that cannot be
    opened: the analysis itself then says why."""
    from frictionwatch.drivers.logs.mcap_reader import LogReader

    try:
        with LogReader(path) as reader:
            start, end = reader.start_ns, reader.end_ns
    except Exception:  # noqa: BLE001 - only the bar's scale is lost; the run reports the real error
        return LogExtent()
    return LogExtent(None if start is None else start / 1e9, None if end is None else end / 1e9)
