"""A progress bar on stderr for long runs (tqdm), quiet when stderr is not a terminal.

``analyze`` shows the cycles done and, where the log's time span is known from its chunk index (read when the log
is opened, no decoding), the fraction of the log passed, the total number of cycles that implies, and the time left.

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
    """A tqdm bar driven by a fraction of its total (``set_fraction``), a count (``update``), or a count with the
    fraction of the run it has reached (``advance``); ``started`` once any progress was reported."""

    def __init__(self, bar: tqdm, total: float):
        self._bar, self._total = bar, total
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
        """One more item done, ``fraction`` (0..1, None: not known) of the way through the run: the bar shows the
        count against the total it implies (``count / fraction``, refined as the run goes on)."""
        self.started.set()
        self.count += 1
        if fraction is not None and fraction > 0.0:
            self._bar.total = max(self.count, round(self.count / min(fraction, 1.0)))
        self._bar.n = self.count
        self._bar.refresh()


@contextmanager
def progress_bar(total: float, desc: str, waiting_note: str | None = COMPILING_NOTE, unit: str = "cycles",
                 estimated_total: bool = False) -> Iterator[Bar]:
    """``total``: the bar's full scale (a fraction bar: 1.0), 0 when unknown (a count of ``unit`` is shown);
    ``estimated_total``: the total is an estimate that ``Bar.advance`` refines (shown as ``n/~total unit``);
    ``waiting_note``: printed once if no progress arrives within NOTE_AFTER_S (None: never)."""
    if estimated_total:
        fmt = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/~{total_fmt} {unit} {elapsed}<{remaining}"
    elif total:
        fmt = "{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}"
    else:
        fmt = "{desc}: {n_fmt} {unit} {elapsed}"
    bar = tqdm(total=total or None, desc=desc, file=sys.stderr, disable=not sys.stderr.isatty(), leave=False,
               bar_format=fmt, unit=unit)
    wrapped = Bar(bar, total)
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
