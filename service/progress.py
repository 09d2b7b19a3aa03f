"""A progress bar on stderr for long runs (tqdm), quiet when stderr is not a terminal."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

from tqdm import tqdm


class _Bar:
    def __init__(self, bar: tqdm, total: float):
        self._bar, self._total = bar, total

    def set_fraction(self, fraction: float) -> None:
        self._bar.n = min(max(fraction, 0.0), 1.0) * self._total
        self._bar.refresh()

    def update(self, n: float = 1) -> None:
        self._bar.update(n)


@contextmanager
def progress_bar(total: float, desc: str) -> Iterator[_Bar]:
    bar = tqdm(total=total, desc=desc, file=sys.stderr, disable=not sys.stderr.isatty(), leave=False,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}")
    try:
        yield _Bar(bar, total)
    finally:
        bar.close()
