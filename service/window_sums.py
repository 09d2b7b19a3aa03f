"""Running sums of each cycle's numbers, so that a window mean over the last N cycles costs the same for any N.

    sums = WindowSums(capacity=5000)
    sums.append(result)          # once per cycle, on the API-state listener's thread (never the ingest thread)
    sums.figures(1000)           # WindowFigures of the newest 1000 cycles: O(columns), not O(cycles)

Prefix sums: position n (mod capacity + 1) holds, for every column of service/window_figures.py's row, the number
of finite values, their sum and their sum of squares over cycles 1..n; a window of w cycles is the difference of
positions n and n - w. Precision: each column is summed about a fixed shift (its first finite value), so the sum of
squares does not lose the scatter to the mean; and every ``capacity`` cycles all positions are rebased on the oldest
one still needed, so the sums never grow past ~2 x capacity cycles' worth (a year of cycles loses nothing).
Flag counts are integers (exact). A cycle without a previous cycle (window_figures.left_out) adds nothing to the
sums and status counts, only its flags: the window says how many it left out. Memory: (capacity + 1) x 3 x columns float64, ~25 MB for genset-v20 at 5000.
"""

from __future__ import annotations

import logging

import numpy as np
from frictionwatch.core.monitor.report.figure_status import STATUSES
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.service.window_figures import (
    NO_PREVIOUS_CYCLE,
    RowLayout,
    WindowFigures,
    left_out,
    result_row,
)

log = logging.getLogger(__name__)


class WindowSums:
    """See the module docstring. Not thread-safe: the owner (listeners.LatestState) holds its lock around both
    ``append`` and ``figures``; ``row_for`` (the costly part) needs no lock."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self.capacity = capacity
        self.layout: RowLayout | None = None
        self.count = 0  # cycles appended since the layout was set
        self.appends = 0  # rows added in all (what a test counts: one per cycle, whatever the requests)

    @staticmethod
    def row_for(result: CycleResult) -> tuple[RowLayout, np.ndarray, np.ndarray, frozenset[str]]:
        """The cycle's row, made once (``to_json`` was the per-cycle cost a window request used to pay N times; the
        row is now made from the result's arrays, ``window_figures.result_row``)."""
        layout, row, status = result_row(result)
        return layout, row, status, frozenset(result.flags)

    def append(self, index: int, made: tuple[RowLayout, np.ndarray, np.ndarray, frozenset[str]]) -> None:
        layout, row, status, flags = made
        if layout != self.layout:
            if self.layout is not None:
                log.info("window sums: the result's shape changed (%s -> %s): windows start again", self.layout,
                         layout)
            self._reset(layout)
        slots = self.capacity + 1
        n = self.count + 1
        prev, pos = (n - 1) % slots, n % slots
        skip = left_out(flags)  # no estimate of its own: only its flags count (window_figures module doc)
        finite = np.isfinite(row) & (not skip)
        new = finite & np.isnan(self._shift)
        self._shift[new] = row[new]  # a column's first finite value: no earlier cycle contributed to it
        x = np.where(finite, row - self._shift, 0.0)
        self._sums[pos] = self._sums[prev] + np.concatenate([finite, x, x * x])
        onehot = np.zeros_like(self._status[0])
        if not skip:
            onehot[np.arange(layout.n_cyl) * len(STATUSES) + status] = 1
        self._status[pos] = self._status[prev] + onehot
        for f in flags - self._flag_col.keys():
            self._flag_col[f] = len(self._flag_col)
            self._flags = np.pad(self._flags, ((0, 0), (0, 1)))
        self._flags[pos] = self._flags[prev]
        for f in flags:
            self._flags[pos, self._flag_col[f]] += 1
        self._index[pos] = index
        self.count, self.appends = n, self.appends + 1
        if n % self.capacity == 0:  # rebase on the oldest position a window can still reach
            self._sums -= self._sums[(n - self.capacity) % slots].copy()

    def figures(self, cycles: int) -> WindowFigures | None:
        """The newest ``cycles`` cycles' figures (fewer when fewer are held); None before the first cycle."""
        if self.layout is None or self.count == 0:
            return None
        w = max(1, min(cycles, self.count, self.capacity))
        slots = self.capacity + 1
        new, old = self.count % slots, (self.count - w) % slots
        d = self._sums[new] - self._sums[old]
        width = self.layout.width
        n, s1, s2 = d[:width], d[width:2 * width], d[2 * width:]
        n = np.rint(n)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(n > 0, self._shift + s1 / n, np.nan)
            var = np.maximum(s2 - s1 * s1 / n, 0.0) / (n - 1)
            sem = np.where(n > 1, np.sqrt(var / n), np.nan)
        status = (self._status[new] - self._status[old]).reshape(self.layout.n_cyl, len(STATUSES))
        flags = self._flag_counts(new, old)
        first = int(self._index[(self.count - w + 1) % slots])
        return WindowFigures(self.layout, w, first, int(self._index[new]), mean, sem, n.astype(np.int64), status,
                             flags, flags.get(NO_PREVIOUS_CYCLE, 0))

    def flag_counts(self, cycles: int) -> dict[str, int] | None:
        """How many of the newest ``cycles`` cycles raised each flag (those raised at all), the same counts as
        ``figures(cycles).flag_counts`` without the means: O(flags). None when fewer than ``cycles`` cycles were
        appended since the layout was set (or ``cycles`` is past the capacity): the counts would not cover them."""
        if self.layout is None or not 1 <= cycles <= min(self.count, self.capacity):
            return None
        slots = self.capacity + 1
        return self._flag_counts(self.count % slots, (self.count - cycles) % slots)

    def _flag_counts(self, new: int, old: int) -> dict[str, int]:
        flag_n = self._flags[new] - self._flags[old]
        return {f: int(flag_n[c]) for f, c in self._flag_col.items() if flag_n[c] > 0}

    def _reset(self, layout: RowLayout) -> None:
        slots = self.capacity + 1
        self.layout, self.count = layout, 0
        self._shift = np.full(layout.width, np.nan)
        self._sums = np.zeros((slots, 3 * layout.width))
        self._status = np.zeros((slots, layout.n_cyl * len(STATUSES)), np.int64)
        self._flags = np.zeros((slots, 0), np.int64)
        self._flag_col: dict[str, int] = {}
        self._index = np.zeros(slots, np.int64)
