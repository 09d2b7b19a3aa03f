"""Running sums of window means (service/window_sums.py) against the plain mean over every cycle of the window."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.core.monitor.report.figure_status import STATUSES
from frictionwatch.service.window_figures import RowLayout
from frictionwatch.service.window_sums import WindowSums
from numpy.testing import assert_allclose, assert_array_equal


def synthetic(n: int, layout: RowLayout, seed: int = 0):
    """Rows like a long run's: offsets far from zero, small scatter, some nulls, statuses and flags that vary."""
    rng = np.random.default_rng(seed)
    rows = 1000.0 + rng.normal(0.0, 0.01, (n, layout.width)) * (1 + np.arange(layout.width))
    rows[rng.random((n, layout.width)) < 0.05] = np.nan
    status = rng.integers(0, len(STATUSES), (n, layout.n_cyl))
    flags = [frozenset(f"flag{j}" for j in range(3) if rng.random() < 0.2 * (j + 1)) for _ in range(n)]
    return rows, status, flags


def reference(rows, status, flags, end: int, w: int, layout: RowLayout):
    win = rows[end - w:end]
    n = np.isfinite(win).sum(axis=0)
    mean = np.nanmean(np.where(n > 0, win, 0.0), axis=0)
    sem = np.where(n > 1, np.nanstd(win, axis=0, ddof=1) / np.sqrt(np.maximum(n, 1)), np.nan)
    counts = np.zeros((layout.n_cyl, len(STATUSES)), int)
    for st in status[end - w:end]:
        counts[np.arange(layout.n_cyl), st] += 1
    fl: dict[str, int] = {}
    for f in flags[end - w:end]:
        for x in f:
            fl[x] = fl.get(x, 0) + 1
    return np.where(n > 0, mean, np.nan), sem, n, counts, fl


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("capacity", [1, 7, 50])
def test_every_window_equals_the_plain_mean(capacity: int) -> None:
    layout = RowLayout(n_cyl=3, n_coefs=2)
    rows, status, flags = synthetic(400, layout)
    sums = WindowSums(capacity)
    for i in range(len(rows)):
        sums.append(100 + i, (layout, rows[i], status[i], flags[i]))
        for w in {1, 2, capacity, capacity + 5, 1000}:
            got = sums.figures(w)
            w_used = min(w, i + 1, capacity)
            mean, sem, n, counts, fl = reference(rows, status, flags, i + 1, w_used, layout)
            assert got.cycles == w_used and got.first_cycle == 100 + i + 1 - w_used and got.last_cycle == 100 + i
            assert_array_equal(got.count, n)
            assert_allclose(got.mean, mean, rtol=1e-12, equal_nan=True)  # values ~1000: 1e-12 is ~1e-9 absolute
            assert_allclose(got.sem, sem, rtol=1e-6, atol=1e-12, equal_nan=True)
            assert_array_equal(got.status_counts, counts)
            assert got.flag_counts == fl


def test_a_long_run_keeps_the_scatter() -> None:
    """Sums rebased every ``capacity`` cycles: after 100,000 cycles whose level is far from the column's shift (its
    first value, 0 here), the scatter of a short window is still right to 1e-6; sums that grew for the whole run
    (~1e11 in the squares) would have lost it to rounding (~1e-5 of a window's ~0.1)."""
    layout = RowLayout(n_cyl=1, n_coefs=0)
    rng = np.random.default_rng(1)
    capacity, n = 100, 100_000
    sums = WindowSums(capacity)
    status, flags = np.zeros(1, np.int64), frozenset()
    sums.append(0, (layout, np.zeros(layout.width), status, flags))
    rows = 1000.0 + 0.1 * rng.normal(size=(n, layout.width))
    for i, row in enumerate(rows):
        sums.append(i + 1, (layout, row, status, flags))
    got = sums.figures(10)
    ref = rows[-10:]
    assert_allclose(got.mean, ref.mean(axis=0), rtol=1e-12)
    assert_allclose(got.sem, ref.std(axis=0, ddof=1) / np.sqrt(10), rtol=1e-6)
    assert sums.appends == n + 1


def test_a_new_shape_starts_the_windows_again() -> None:
    sums = WindowSums(10)
    a, b = RowLayout(2, 1), RowLayout(2, 2)
    for i in range(5):
        sums.append(i, (a, np.ones(a.width), np.zeros(2, np.int64), frozenset()))
    sums.append(5, (b, np.full(b.width, 2.0), np.zeros(2, np.int64), frozenset()))
    got = sums.figures(10)
    assert got.cycles == 1 and got.layout == b and got.mean[0] == 2.0
    assert WindowSums(3).figures(5) is None


def test_a_cycle_without_a_previous_cycle_is_left_out_and_counted() -> None:
    """Its row (here 1e6, far from the others, so that any part of it in the sums would show) adds nothing to the
    means, counts or statuses; its flags still count, and the window says how many it left out."""
    layout = RowLayout(n_cyl=2, n_coefs=1)
    rows, status, _ = synthetic(30, layout, seed=2)
    seams = {0, 11, 23}
    flags = [frozenset({"no_previous_cycle"}) if i in seams else frozenset() for i in range(30)]
    sums = WindowSums(50)
    for i in range(30):
        sums.append(i, (layout, np.full(layout.width, 1e6) if i in seams else rows[i], status[i], flags[i]))
    for w in (1, 5, 7, 19, 30):
        got = sums.figures(w)
        kept = [i for i in range(30 - w, 30) if i not in seams]
        plain = WindowSums(50)
        for i in kept:
            plain.append(i, (layout, rows[i], status[i], frozenset()))
        want = plain.figures(len(kept)) if kept else None
        assert got.cycles == w and got.left_out == w - len(kept) and got.counted == len(kept)
        assert got.flag_counts == ({"no_previous_cycle": got.left_out} if got.left_out else {})
        if want is None:
            assert_array_equal(got.count, 0) and assert_array_equal(got.status_counts, 0)
            continue
        assert_array_equal(got.count, want.count)
        assert_allclose(got.mean, want.mean, rtol=1e-12, equal_nan=True)
        assert_allclose(got.sem, want.sem, rtol=1e-6, atol=1e-12, equal_nan=True)
        assert_array_equal(got.status_counts, want.status_counts)
