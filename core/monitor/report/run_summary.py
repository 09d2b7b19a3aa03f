"""Run-level bookkeeping over a sequence of cycle results: which cycles an accumulated estimate stands for, which
flags apply to it, per-window flag counts and run means (plain sequences in, plain values out; no I/O).

The smoothed estimate is the end of an exponentially forgetting accumulation: cycle i counts lambda**(folds after
i), so under a changing load it stands for the last ~``effective_cycles`` cycles, centred on ``centre_cycle``,
not for the mean of the run. ``estimate_window`` says which.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.monitor.report.figure_status import FrictionStatus, friction_status, split_flag

FLAG_WINDOW_CYCLES = 100  # flag counts per consecutive window of this many cycle indices (and for the whole run)
ACTIVE_SHARE = 0.1  # a flag applies to an accumulated estimate when raised in >= this share of its window


@dataclass(frozen=True)
class EstimateWindow:
    """The cycles an accumulated estimate stands for.

    first_cycle: the first accumulated cycle among those held (None: nothing accumulated, the estimate is the
    prior); last_cycle: the newest cycle; effective_cycles: the accumulated weight (sum of lambda**age);
    centre_cycle: the weight-averaged cycle index; forgetting: lambda per accumulated cycle (None: fewer than two
    accumulated cycles)."""

    first_cycle: int | None
    last_cycle: int
    effective_cycles: float
    centre_cycle: float | None
    forgetting: float | None


def estimate_window(indices: Sequence[int], weights: Sequence[float]) -> EstimateWindow:
    """From each held result's cycle index and the accumulated weight of its smoothed estimate (in order). The
    monitor accumulates every cycle after its warm-up, so every result from the first with a weight on counts, back
    to the newest restart of the accumulation (a weight back to one cycle's), if any. (Not
    "where the weight changed": the weight reaches its fixed point 1 / (1 - lambda) exactly in floating point after
    some 12,000 cycles of a 400-cycle window and stops changing.)"""
    idx = np.asarray(indices, dtype=np.int64)
    w = np.asarray(weights, dtype=np.float64)
    if idx.shape != w.shape or idx.size == 0:
        raise ValueError(f"need one weight per cycle index and at least one, got {idx.shape} and {w.shape}")
    last = int(idx[-1])
    started = np.flatnonzero(w > 0)
    if started.size == 0:
        return EstimateWindow(None, last, float(w[-1]), None, None)
    pos = np.arange(started[0], idx.size)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = (w[pos[1:]] - 1.0) / w[pos[1:] - 1]  # each cycle's factor on what came before it (lambda: forgot)
    # a restart of the accumulation (its weight back to one cycle's: factor 0) begins the window again: the cycles
    # before it carry nothing of the estimate (a served demo read "cycles 20-1320" of an estimate restarted at ~1085)
    restarts = np.flatnonzero(~(ratios > 0.0))
    if restarts.size:
        pos, ratios = pos[restarts[-1] + 1:], ratios[restarts[-1] + 1:]
    lam = float(np.median(ratios)) if ratios.size else None
    # each cycle's share of the estimate: the product of the factors after it (lambda ** age where the weight only
    # forgot; less where it was cut back part way)
    cw = np.r_[np.cumprod(ratios[::-1])[::-1], 1.0]
    centre = float(np.sum(cw * idx[pos]) / np.sum(cw))
    return EstimateWindow(int(idx[pos[0]]), last, float(w[-1]), centre, lam)


def active_flags(flags: Sequence[Sequence[str]], window_cycles: float) -> frozenset[str]:
    """The flags that apply to an estimate over the last ``window_cycles`` results (``flags``: one tuple per
    result, in order): those of the newest result, and any raised in at least ACTIVE_SHARE of the window."""
    if not flags:
        return frozenset()
    n = max(1, min(len(flags), round(window_cycles)))
    counts: dict[str, int] = {}
    for fl in flags[-n:]:
        for f in set(fl):
            counts[f] = counts.get(f, 0) + 1
    return frozenset(flags[-1]) | {f for f, c in counts.items() if c >= ACTIVE_SHARE * n}


def end_of_run_status(results: Sequence) -> tuple[EstimateWindow, frozenset[str], FrictionStatus]:
    """The window of the newest smoothed estimate, the flags that apply to it and the status of its figures, from a
    run's results in order (``CycleResult``: index, smoothed.weight, flags): what `analyze` reports, its table,
    JSON and plots alike."""
    window = estimate_window([r.index for r in results], [r.smoothed.weight for r in results])
    active = active_flags([r.flags for r in results], window.effective_cycles)
    return window, active, friction_status(results[-1].smoothed, active)


def flag_kinds(flags: Sequence[Sequence[str]]) -> list[str]:
    """The flag kinds raised anywhere in the run, sorted (``misfire_cyl2`` and ``misfire_cyl3`` are one kind)."""
    return sorted({split_flag(f)[0] for fl in flags for f in fl})


def flag_summary(indices: Sequence[int], flags: Sequence[Sequence[str]],
                 window_cycles: int = FLAG_WINDOW_CYCLES) -> dict:
    """Per-flag counts for the whole run and per window of ``window_cycles`` consecutive cycle indices (window j
    covers [first + j N, first + (j+1) N); windows without an analysed cycle are left out), and the cycles
    flagged, per flag string."""
    if window_cycles < 1:
        raise ValueError(f"window_cycles must be >= 1, got {window_cycles}")
    run: dict[str, int] = {}
    cycles: dict[str, list[int]] = {}
    windows: dict[int, dict] = {}
    first = int(indices[0]) if len(indices) else 0
    for i, fl in zip(indices, flags):
        j = (int(i) - first) // window_cycles
        win = windows.setdefault(j, {"first_cycle": first + j * window_cycles,
                                     "last_cycle": first + (j + 1) * window_cycles - 1, "cycles": 0, "counts": {}})
        win["cycles"] += 1
        for f in sorted(set(fl)):
            run[f] = run.get(f, 0) + 1
            win["counts"][f] = win["counts"].get(f, 0) + 1
            cycles.setdefault(f, []).append(int(i))
    return {"window_cycles": window_cycles, "kinds": flag_kinds(flags), "run": dict(sorted(run.items())),
            "windows": [windows[j] for j in sorted(windows)], "cycles": dict(sorted(cycles.items()))}


def mean_and_sem(values: Sequence[float]) -> tuple[float, float, int]:
    """Mean of the finite values, the 1-sigma of that mean from their scatter (std / sqrt(n), NaN for n < 2), n."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    n = int(v.size)
    if n == 0:
        return math.nan, math.nan, 0
    return float(v.mean()), float(v.std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan, n


def smoothed_mean_and_sigma(values: np.ndarray, forgetting: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Running exponentially weighted mean of ``values`` (n, ...) along axis 0 with factor ``forgetting`` per row
    (None or 1: the plain running mean), and the 1-sigma of that mean from the weighted scatter of the values
    (NaN while fewer than two rows count): what the friction estimate's window does to a measured quantity."""
    from scipy.signal import lfilter

    x = np.asarray(values, dtype=np.float64)
    lam = 1.0 if forgetting is None else float(forgetting)
    ones = np.ones(x.shape[0])
    w = lfilter([1.0], [1.0, -lam], ones)
    w2 = lfilter([1.0], [1.0, -lam * lam], ones)
    shape = (-1,) + (1,) * (x.ndim - 1)
    s = lfilter([1.0], [1.0, -lam], x, axis=0)
    q = lfilter([1.0], [1.0, -lam], x * x, axis=0)
    mean = s / w.reshape(shape)
    n_eff = (w * w / w2).reshape(shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        var = np.maximum(q / w.reshape(shape) - mean * mean, 0.0) * n_eff / (n_eff - 1.0)
        sigma = np.where(n_eff > 1.0 + 1e-9, np.sqrt(var / n_eff), np.nan)
    return mean, sigma
