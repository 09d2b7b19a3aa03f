"""Streaming zero-phase speed filter across cycles (physics.md §14.7: "on a stream, use padding from neighbouring
cycles"), so chunked == whole.

The pitch samples of consecutive cycles (core.monitor.speed.pitch_samples: 2N per cycle, seamless from one cycle to the
next) form one stream. It is low-passed by a symmetric FIR (Blackman-windowed sinc, 2L+1 taps): zero phase, unit
gain at DC, and a linear trend passes unchanged, so no drift removal is needed. The continuous kernel h(u) is
evaluated between samples too, which resamples straight onto the crank-angle grid; its derivative gives
d omega / d theta with the same band limit (alpha = omega d omega / d theta).

Band. Orders <= n_max pass (the Blackman transition, about 5.5 N / (2L+1) orders wide, starts at n_max); L = N
(one revolution each side) by default, i.e. a transition of ~2.75 orders.

Two levels, each with a chunked == whole test:
- ``fir_stream`` / ``fir_whole``: the sample stream, outputs delayed by L samples (exactly equal for any chunking);
- ``speed_stream_update`` / ``speed_whole``: cycle by cycle. A cycle is output once the next one has arrived (its
  first L+1 samples are the right padding); a cycle without a consecutive neighbour on one side is padded on that
  side by its own periodic extension, in both variants.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np
from frictionwatch.core.monitor.speed import FOUR_PI, CycleSpeed, pitch_samples, tooth_speed, wheel_of
from frictionwatch.core.types import Cycle


@dataclass(frozen=True)
class StreamFilter:
    """n_max_order, positions_per_rev N, half_width L; taps h (2L+1,) and derivative taps dh (2L+1,) [per sample]."""

    n_max_order: float
    positions_per_rev: int
    half_width: int
    h: np.ndarray
    dh: np.ndarray

    @property
    def cutoff(self) -> float:
        """-6 dB frequency [cycles per sample]."""
        return _cutoff(self.n_max_order, self.positions_per_rev, self.half_width)


def _cutoff(n_max: float, n: int, half: int) -> float:
    return (n_max + 0.5 * 5.5 * n / (2 * half + 1)) / n


def _kernel(u: np.ndarray, fc: float, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Windowed sinc h(u) and dh/du at (fractional) sample offsets u; zero for |u| >= half + 1."""
    a = np.pi / (half + 1)
    win = 0.42 + 0.5 * np.cos(a * u) + 0.08 * np.cos(2 * a * u)
    dwin = -0.5 * a * np.sin(a * u) - 0.16 * a * np.sin(2 * a * u)
    z = 2 * fc * u
    s = np.sinc(z)
    with np.errstate(divide="ignore", invalid="ignore"):
        ds = np.where(np.abs(z) < 1e-12, 0.0, (np.cos(np.pi * z) - s) / np.where(z == 0, 1.0, z)) * 2 * fc
    inside = np.abs(u) < half + 1
    h = np.where(inside, 2 * fc * s * win, 0.0)
    dh = np.where(inside, 2 * fc * (ds * win + s * dwin), 0.0)
    return h, dh


def design_stream_filter(n_max_order: float, positions_per_rev: int, half_width: int | None = None) -> StreamFilter:
    """FIR for a wheel of N positions keeping orders <= n_max_order; L defaults to N."""
    n = int(positions_per_rev)
    half = n if half_width is None else int(half_width)
    if not 1 <= half <= 2 * n - 1:
        raise ValueError(f"half_width must be 1..{2 * n - 1} samples (at most one cycle of padding), got {half}")
    fc = _cutoff(n_max_order, n, half)
    if not 0 < n_max_order or fc >= 0.5:
        raise ValueError(f"n_max_order {n_max_order} leaves no stopband below Nyquist for N = {n}, L = {half}")
    k = np.arange(-half, half + 1, dtype=np.float64)
    h, dh = _kernel(k, fc, half)
    h = h / h.sum()  # unit DC gain
    dh = dh - dh.mean()  # antisymmetric: zero DC gain
    dh = dh / -(k * dh).sum()  # exactly 1 on a unit ramp
    return StreamFilter(float(n_max_order), n, half, h, dh)


@numba.njit(cache=True)
def _fir_valid(x, h, out):
    """out[j] = sum_k h[k] x[j + 2L - k] (np.convolve(x, h, 'valid'))."""
    taps = h.shape[0]
    for j in range(out.shape[0]):
        s = 0.0
        for k in range(taps):
            s += h[k] * x[j + taps - 1 - k]
        out[j] = s


def fir_whole(samples: np.ndarray, flt: StreamFilter) -> tuple[np.ndarray, np.ndarray]:
    """Filter a whole record: omega and d omega / d theta [per rad] for samples L .. n-L-1."""
    x = np.ascontiguousarray(samples, dtype=np.float64)
    m = x.shape[0] - 2 * flt.half_width
    if m < 0:
        return np.empty(0), np.empty(0)
    y, dy = np.empty(m), np.empty(m)
    _fir_valid(x, flt.h, y)
    _fir_valid(x, flt.dh, dy)
    return y, dy * (flt.positions_per_rev / (2 * np.pi))


@dataclass(frozen=True)
class FirState:
    """The last 2L input samples and how many samples went in."""

    history: np.ndarray
    consumed: int = 0


def fir_stream(flt: StreamFilter, state: FirState | None, chunk: np.ndarray) -> tuple[FirState, np.ndarray, np.ndarray]:
    """Filter the next chunk; the outputs continue those of earlier calls (sample index consumed - L onwards)."""
    hist = np.empty(0) if state is None else state.history
    buf = np.concatenate([hist, np.ascontiguousarray(chunk, dtype=np.float64)])
    y, dy = fir_whole(buf, flt)
    keep = buf[-2 * flt.half_width:] if buf.shape[0] >= 2 * flt.half_width else buf
    return FirState(keep.copy(), (0 if state is None else state.consumed) + len(chunk)), y, dy


# ---- cycle by cycle -----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GridOperator:
    """Banded maps from the padded samples (L+1 | 2N | rpad) of one cycle to omega and d omega/d theta on the grid:
    row g uses samples start[g] .. start[g] + 2L + 1 with weights band[g] (resp. dband[g]). ``key`` = (n, half,
    cutoff, first sample angle, grid points, rpad): the same every cycle of a steady stream, so the last one is
    kept in the stream state and rebuilt only when the key changes."""

    key: tuple
    start: np.ndarray
    band: np.ndarray
    dband: np.ndarray


def grid_operator(n: int, half: int, fc: float, theta0: float, grid_points: int, rpad: int) -> GridOperator:
    """The ``GridOperator`` of one cycle (see there)."""
    pitch = 2 * np.pi / n
    grid = np.arange(grid_points) * (FOUR_PI / grid_points)
    # sample s of the padded array sits at theta0 + (s - (half + 1) + 1/2) pitch
    width = 2 * half + 2
    start = np.floor((grid - theta0) / pitch - 0.5 + (half + 1)).astype(np.int64) - half
    last = 2 * n + half + 1 + rpad - width
    start = np.clip(start, 0, last)
    idx = start[:, None] + np.arange(width)[None, :]
    pos = theta0 + (idx - (half + 1) + 0.5) * pitch
    u = (grid[:, None] - pos) / pitch
    h, dh = _kernel(u, fc, half)
    # the same normalisation as the sampled taps, so the grid values match them at the sample positions
    k = np.arange(-half, half + 1, dtype=np.float64)
    h0, dh0 = _kernel(k, fc, half)
    dh0 = dh0 - dh0.mean()
    return GridOperator((n, half, fc, theta0, grid_points, rpad), start, np.ascontiguousarray(h / h0.sum()),
                        np.ascontiguousarray(dh / (-(k * dh0).sum() * pitch)))


@numba.njit(cache=True)
def _banded_apply(start, band, x, out):
    for g in range(band.shape[0]):
        s = 0.0
        o = start[g]
        for j in range(band.shape[1]):
            s += band[g, j] * x[o + j]
        out[g] = s


@dataclass(frozen=True)
class _CycleSamples:
    index: int
    theta0: float
    samples: np.ndarray
    omega_mean: float


@dataclass(frozen=True)
class SpeedStreamState:
    """The cycle waiting for its right-hand neighbour and the one before it (for left padding), and the last grid
    operator."""

    pending: _CycleSamples | None = None
    previous: _CycleSamples | None = None
    operator: GridOperator | None = None


def _samples_of(cycle: Cycle, correction: np.ndarray | None) -> _CycleSamples:
    n, _ = wheel_of(cycle)
    corr = None if correction is None else np.asarray(correction, dtype=np.float64)[cycle.tooth_index]
    _, omega = tooth_speed(cycle.tooth_ticks, cycle.tooth_angle, cycle.tick_hz, corr)
    theta0, s = pitch_samples(cycle.tooth_angle, omega, n)
    j4 = int(np.searchsorted(cycle.tooth_angle, cycle.tooth_angle[0] + FOUR_PI - 1e-9))
    mean = FOUR_PI * cycle.tick_hz / float(cycle.tooth_ticks[j4] - cycle.tooth_ticks[0])
    return _CycleSamples(cycle.index, theta0, s, mean)


def _neighbour(a: _CycleSamples | None, b: _CycleSamples) -> bool:
    return a is not None and abs(a.index - b.index) == 1 and abs(a.theta0 - b.theta0) < 1e-9


def _output(flt: StreamFilter, cur: _CycleSamples, left: _CycleSamples | None, right: _CycleSamples | None,
            grid_points: int, operator: GridOperator | None) -> tuple[CycleSpeed, GridOperator]:
    s = cur.samples
    n = flt.positions_per_rev
    lpad = flt.half_width + 1
    # the grid runs to 4 pi, i.e. up to -theta0 past the last sample's cycle: pad that much more on the right
    rpad = min(2 * n, flt.half_width + 1 + int(np.ceil(-cur.theta0 / (2 * np.pi / n) - 1e-9)))
    lp = left.samples[-lpad:] if _neighbour(left, cur) else s[-lpad:]  # else: periodic extension
    rp = right.samples[:rpad] if _neighbour(right, cur) else s[:rpad]
    x = np.concatenate([lp, s, rp])
    key = (n, flt.half_width, flt.cutoff, round(cur.theta0, 12), grid_points, rpad)
    if operator is None or operator.key != key:
        operator = grid_operator(*key)
    w, dw = np.empty(grid_points), np.empty(grid_points)
    _banded_apply(operator.start, operator.band, x, w)
    _banded_apply(operator.start, operator.dband, x, dw)
    grid = np.arange(grid_points) * (FOUR_PI / grid_points)
    drift = float(np.mean(dw))
    return CycleSpeed(grid, w, w * dw, cur.omega_mean, cur.omega_mean * 30.0 / np.pi, drift), operator


def speed_stream_update(flt: StreamFilter, state: SpeedStreamState, cycle: Cycle | None,
                        correction: np.ndarray | None = None, grid_points: int = 720
                        ) -> tuple[SpeedStreamState, list[tuple[int, CycleSpeed]]]:
    """Feed the next assembled cycle (None = end of stream); returns [(cycle index, CycleSpeed)] now complete."""
    cur = None if cycle is None else _samples_of(cycle, correction)
    if cur is not None and cur.samples.shape[0] != 2 * flt.positions_per_rev:
        raise ValueError(f"cycle has {cur.samples.shape[0] // 2} positions per revolution; the filter was designed "
                         f"for {flt.positions_per_rev}")
    out = []
    operator = state.operator
    if state.pending is not None:
        right = cur if cur is not None and _neighbour(state.pending, cur) and cur.index > state.pending.index \
            else None
        speed, operator = _output(flt, state.pending, state.previous, right, grid_points, operator)
        out.append((state.pending.index, speed))
    return replace(state, pending=cur, previous=state.pending, operator=operator), out


def speed_whole(flt: StreamFilter, cycles: list[Cycle], correction: np.ndarray | None = None,
                grid_points: int = 720) -> list[tuple[int, CycleSpeed]]:
    """All cycles at once (the reference for ``speed_stream_update``)."""
    cs = [_samples_of(c, correction) for c in cycles]
    out = []
    operator = None
    for i, c in enumerate(cs):
        left = cs[i - 1] if i > 0 and cs[i - 1].index < c.index else None
        right = cs[i + 1] if i + 1 < len(cs) and cs[i + 1].index > c.index else None
        speed, operator = _output(flt, c, left, right, grid_points, operator)
        out.append((c.index, speed))
    return out
