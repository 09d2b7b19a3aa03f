"""A progress bar on stderr for long runs (tqdm), quiet when stderr is not a terminal.

A fresh install compiles its numba kernels on first use (tens of seconds; cached on disk afterwards), before the first
cycle can be shown. So that a new user does not stare at a silent terminal, a bar that has seen no progress after
``NOTE_AFTER_S`` says once, on stderr, what is happening (also when stderr is not a terminal: CI logs show it).
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from tqdm import tqdm

NOTE_AFTER_S = 2.0
COMPILING_NOTE = ("compiling the numerical kernels (numba, first run after an install only: about a minute on a "
                  "small machine; later runs load them from the cache)")


class Bar:
    """A tqdm bar that can also be driven by a fraction; ``started`` once any progress was reported."""

    def __init__(self, bar: tqdm, total: float):
        self._bar, self._total = bar, total
        self.started = threading.Event()

    def set_fraction(self, fraction: float) -> None:
        self.started.set()
        self._bar.n = min(max(fraction, 0.0), 1.0) * self._total
        self._bar.refresh()

    def update(self, n: float = 1) -> None:
        self.started.set()
        self._bar.update(n)


@contextmanager
def progress_bar(total: float, desc: str, waiting_note: str | None = COMPILING_NOTE) -> Iterator[Bar]:
    """``waiting_note``: printed once if no progress arrives within NOTE_AFTER_S (None: never)."""
    bar = tqdm(total=total, desc=desc, file=sys.stderr, disable=not sys.stderr.isatty(), leave=False,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}" if total else
               "{desc}: {n_fmt} {unit} {elapsed}", unit="cycles")
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
