"""Cylinder-pressure recordings in the crank-angle domain that the monitor cannot run on: one cylinder of a
multi-cylinder engine, no usable crank-wheel timing. Each reader returns ``PressureCycles``: every complete cycle of
the file on one uniform grid of crank angle from that cylinder's firing TDC, in Pa.

Cycles are TDC-centred, [-360, 360) deg around a firing TDC (gas-exchange TDC, intake, compression, firing TDC,
expansion, exhaust: the whole of one combustion), as ``drivers/daq/pressure.py`` calibrates them.

- ``read_angle_csv``: a table of crank angle [deg, 0 = firing TDC] and absolute pressure [bar] of one cylinder,
  e.g. the PoliTo ICE-lab export (``crank_angle_deg, p_cyl1_bar, ...``; ../shared/realdata/polito-diesel-4cyl-1600rpm).
- ``read_encoder_table``: time, pressure volts, an incremental encoder without a gap (N pulses per revolution) and
  a once-per-revolution TDC marker, e.g. the AUTH bench export (.xlsx, ../shared/realdata/auth-si-4cyl-1200rpm-87Nm).

TDC-marker convention (encoder tables): **the marker's rising edge is TDC, interpolated between encoder edges.**
Each encoder edge is 360/N deg after the one before; the crank angle of any instant is linear in time between the
two edges around it; the marker's rising crossing of its mid level (linearly interpolated between samples) is given
angle 0 of its revolution. So TDC falls between two encoder edges, at the fraction of the pitch the marker's time
says, not on the nearest or the next edge (on the AUTH file the marker lies 0.37 deg before the next edge: taking
that edge as TDC moves IMEP by about -1.3 %; the marker pulse is 1-2 samples wide, so its time is known to about
half a sample, 0.05 deg at 1200 rpm). Of the two markers per cycle, the firing one is where the pressure is higher.

Time stamps: a table whose times were rounded when written (the AUTH export keeps 1 us, so its 13.88 us steps read
13, 14 or 13.84 us) is put back on the uniform clock fitted to them (least squares in the sample index) when the
fit's residual stays within the rounding; otherwise it is refused as not uniformly sampled.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.drivers.daq.pressure import polytropic_zero
from frictionwatch.drivers.daq.table_text import numeric_rows
from frictionwatch.drivers.daq.xlsx import read_sheet
from frictionwatch.drivers.errors import CorruptLog

GRID_POINTS = 7200  # 0.1 deg over the 720 deg cycle


@dataclass(frozen=True)
class PressureCycles:
    """pressure_pa (c, n): cycle k of ``cylinder`` on ``angle_deg`` (n,) = -360 .. 360 - 720/n deg from its firing
    TDC; rpm (c,) the cycle's mean speed (NaN when the file has no time); notes: how the file was read, in words."""

    source: str
    cylinder: int
    angle_deg: np.ndarray
    pressure_pa: np.ndarray
    rpm: np.ndarray
    notes: tuple[str, ...] = field(default=())

    @property
    def cycles(self) -> int:
        return int(self.pressure_pa.shape[0])


def cycle_grid(points: int = GRID_POINTS) -> np.ndarray:
    return -360.0 + np.arange(points) * (720.0 / points)


def read_angle_csv(path: str | Path) -> PressureCycles:
    """A crank-angle pressure table (module docstring). Needs a header naming ``crank_angle_deg`` and one
    ``p_cyl<k>_bar`` column, one 720 deg cycle (several are cut at the -360 deg wrap).

    As Excel and copies leave them: a UTF-8 byte-order mark and quoted header names are read; a last line cut short
    (no line end, too few values: the file was copied while written) is dropped and said, not the whole file. A
    cycle that cannot be an absolute cylinder pressure (``implausible``) is skipped and counted in the notes."""
    p = Path(path)
    try:
        with p.open(encoding="utf-8-sig") as fh:  # -sig: Excel's "CSV UTF-8" starts with a byte-order mark
            header = [h.strip().strip('"').strip() for h in fh.readline().split(",")]
            body = fh.read()
    except UnicodeDecodeError as exc:
        raise CorruptLog(f"{p.name}: not a numeric crank-angle CSV ({' '.join(str(exc).split())})") from None
    data, notes = numeric_rows(body, p.name, "numeric crank-angle CSV", delimiter=",")
    cyl_cols = [i for i, h in enumerate(header) if re.fullmatch(r"p_cyl\d+_bar", h) and int(h[5:-4]) >= 1]
    if "crank_angle_deg" not in header or len(cyl_cols) != 1:
        raise CorruptLog(f"{p.name}: expected a header with crank_angle_deg and one p_cyl<k>_bar column (k the "
                         f"cylinder, from 1), got {', '.join(header)}")
    if data.shape[0] < 360 or data.shape[1] < len(header):
        raise CorruptLog(f"{p.name}: {data.shape[0]} rows; a cycle needs at least 360")
    angle, bar = data[:, header.index("crank_angle_deg")], data[:, cyl_cols[0]]
    if not (np.all(np.isfinite(angle)) and np.all(np.isfinite(bar)) and np.all(np.diff(angle) > 0)):
        raise CorruptLog(f"{p.name}: crank angle must increase and every value be a number")
    cylinder = int(header[cyl_cols[0]][5:-4])
    starts = np.flatnonzero(np.isclose(np.mod(angle + 360.0, 720.0), 0.0))  # each -360 deg (mod 720) opens a cycle
    grid = cycle_grid()
    cycles, skipped = [], Counter()
    for a in starts:
        sel = slice(a, a + np.searchsorted(angle[a:], angle[a] + 720.0))
        th = angle[sel] - angle[a] - 360.0
        step = np.max(np.diff(th)) if th.size > 1 else np.inf
        if th[-1] + step >= 360.0 - 1e-9 and step <= 1.0:  # complete, and no step wider than 1 deg
            why = implausible(bar[sel])
            if why:
                skipped[why] += 1
            else:
                cycles.append(np.interp(grid, th, bar[sel] * 1e5, period=720.0))
    if not cycles:
        what = f"; {_skips(skipped)}" if skipped else f" (angles {angle[0]:g}..{angle[-1]:g})"
        raise CorruptLog(f"{p.name}: no complete 720 deg cycle of absolute pressure from -360 deg{what}")
    notes = [f"{len(cycles)} cycle(s) of absolute pressure [bar] in the crank-angle domain, angle 0 = firing TDC as "
             "the file states", *notes] + ([_skips(skipped)] if skipped else [])
    return PressureCycles(p.name, cylinder, grid, np.array(cycles), np.full(len(cycles), np.nan), tuple(notes))


# An absolute cylinder pressure lies above 0 bar, below any engine's peak (the largest diesels fire at ~300 bar;
# 500 is the bound here, the assembly's 1000 bar in drivers/assembly/ringbuffer.py is a sensor's), and swings by the
# compression at least (a motored engine at cranking speed: > 5 bar; 1 bar is kept as a floor well under that).
# Outside these a trace is a gauge trace stored negated, a dead sensor, or volts or Pa written as bar: an IMEP from
# it would be a number that should not come out.
PLAUSIBLE_BAR = (0.0, 500.0)
MIN_SWING_BAR = 1.0


def implausible(bar: np.ndarray) -> str:
    """Why one cycle's absolute pressure [bar] cannot be a cylinder's ('' if it can)."""
    lo, hi = float(bar.min()), float(bar.max())
    if lo < PLAUSIBLE_BAR[0]:
        return f"below {PLAUSIBLE_BAR[0]:g} bar absolute"
    if hi > PLAUSIBLE_BAR[1]:
        return f"above {PLAUSIBLE_BAR[1]:g} bar"
    if hi - lo < MIN_SWING_BAR:
        return f"flat (swings less than {MIN_SWING_BAR:g} bar: no compression)"
    return ""


def _skips(skipped: Counter) -> str:
    return f"{sum(skipped.values())} cycle(s) skipped: " + ", ".join(f"{n} {why}" for why, n in skipped.items())


def uniform_time(stamps: np.ndarray, name: str) -> np.ndarray:
    """The uniform clock behind (possibly rounded) time stamps (module docstring)."""
    i = np.arange(stamps.shape[0], dtype=np.float64)
    slope, offset = np.polyfit(i, stamps, 1)
    fitted = offset + slope * i
    resolution = _rounding(stamps)
    if not slope > 0 or np.max(np.abs(fitted - stamps)) > max(0.51 * resolution, 0.01 * slope):
        raise CorruptLog(f"{name}: time column is not uniformly sampled (residual "
                         f"{np.max(np.abs(fitted - stamps)):.3g} s against a step of {slope:.4g} s)")
    return fitted


def _rounding(stamps: np.ndarray) -> float:
    """The decimal step most stamps (99 %) were rounded to (1e-6 for '0.199997'; the first few, written as
    '1.388e-05', keep more digits), 0 when they carry full precision."""
    for digits in range(2, 12):
        on_grid = np.isclose(stamps, np.round(stamps, digits), rtol=0, atol=1e-3 * 10.0**-digits)
        if np.mean(on_grid) >= 0.99:
            return 10.0**-digits
    return 0.0


def rising(t: np.ndarray, v: np.ndarray, level: float) -> np.ndarray:
    """Times where ``v`` rises through ``level``, linearly interpolated between samples."""
    i = np.flatnonzero((v[1:] > level) & (v[:-1] <= level))
    return t[i] + (level - v[i]) / (v[i + 1] - v[i]) * (t[i + 1] - t[i])


def read_encoder_table(path: str | Path, engine: EngineSpec, gain_pa_per_v: float, n_poly: float = 1.32,
                       columns: tuple[int, int, int, int] = (0, 1, 2, 3)) -> PressureCycles:
    """An encoder table (.xlsx; module docstring). ``columns``: 0-based (time, pressure V, encoder, TDC marker).

    The pressure is relative (a piezo charge amplifier): its zero is pegged per cycle by the polytropic fit of the
    compression (drivers/daq/pressure.py, -100..-60 deg, ``n_poly``); IMEP does not depend on it, the peak does."""
    p = Path(path)
    header, data = read_sheet(p)
    if data.shape[1] < 4 or data.shape[0] < 1000:
        raise CorruptLog(f"{p.name}: expected >= 1000 rows of time, pressure, encoder, TDC marker; got "
                         f"{data.shape} ({', '.join(header)})")
    data = data[:, list(columns)]
    if not np.all(np.isfinite(data)):
        raise CorruptLog(f"{p.name}: empty cells inside the time, pressure, encoder or marker columns")
    t = uniform_time(data[:, 0], p.name)
    volts, encoder, marker = data[:, 1], data[:, 2], data[:, 3]
    edges = rising(t, encoder, 0.5 * (np.percentile(encoder, 5) + np.percentile(encoder, 95)))
    base = float(np.median(marker))  # the marker is a pulse of 1-2 samples: percentiles do not see it, its peak does
    marks = rising(t, marker, base + 0.5 * (float(marker.max()) - base))
    if marks.size < 2 or edges.size < 100:
        raise CorruptLog(f"{p.name}: {marks.size} TDC marker(s) and {edges.size} encoder edges; need two markers "
                         "and the encoder pulses between them")
    per_rev = np.diff(np.searchsorted(edges, marks))
    ppr = int(per_rev[0])
    if np.any(per_rev != ppr) or ppr < 36:
        raise CorruptLog(f"{p.name}: encoder edges between TDC markers vary ({sorted(set(per_rev.tolist()))}); "
                         "a missed or extra pulse")
    pitch = 360.0 / ppr
    edge_deg = np.arange(edges.size) * pitch
    mark_deg = np.interp(marks, edges, edge_deg)  # the convention: TDC at the marker's interpolated time
    # firing TDC: the markers with the compression pressure, every other one (gas-exchange TDC reads near manifold)
    at_marks = np.interp(marks, t, volts)
    high = at_marks > 0.5 * (at_marks.max() + at_marks.min())
    if np.any(high[1:] == high[:-1]):
        raise CorruptLog(f"{p.name}: the pressure at the TDC markers does not alternate high/low "
                         f"({np.round(at_marks, 3).tolist()} V): the firing TDC cannot be told")
    # a whole cycle lies between the gas-exchange markers either side of its firing marker, where the pulse count
    # was checked above; a firing marker at either end of the record has no whole cycle
    firing = mark_deg[1:-1][high[1:-1]]
    sample_deg = np.interp(t, edges, edge_deg, left=np.nan, right=np.nan)
    grid = cycle_grid()
    comp = (grid >= -100.0) & (grid <= -60.0)
    cycles, rpm, notes = [], [], []
    for f in firing:
        u = np.interp(grid + f, sample_deg[np.isfinite(sample_deg)], volts[np.isfinite(sample_deg)])
        peak = grid[np.argmax(u)]
        if not -20.0 <= peak <= 50.0:  # as drivers/daq/pressure.py: elsewhere the marker is not this cylinder's TDC
            raise CorruptLog(f"{p.name}: pressure peak {peak:.1f} deg from the firing TDC marker; the marker is not "
                             "the measured cylinder's TDC")
        zero, _, _ = polytropic_zero(grid[comp], u[comp], engine, n_poly)
        cycles.append(gain_pa_per_v * (u - zero))
        rpm.append(120.0 / (np.interp(f + 360.0, edge_deg, edges) - np.interp(f - 360.0, edge_deg, edges)))
    if not cycles:
        raise CorruptLog(f"{p.name}: no complete TDC-centred cycle ({marks.size} markers, {edges.size} edges)")
    notes.append(f"encoder {ppr} pulses/rev without a gap, {marks.size} TDC markers; TDC = the marker's rising edge "
                 "interpolated between encoder edges")
    notes.append(f"pressure = {gain_pa_per_v / 1e5:g} bar/V x (volts - zero), zero pegged per cycle by a polytropic "
                 f"fit of the compression (n = {n_poly:g})")
    return PressureCycles(p.name, 1, grid, np.array(cycles), np.array(rpm), tuple(notes))
