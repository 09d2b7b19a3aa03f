"""Raw DAQ voltage tables -> tooth edges + calibrated pressure, as stream records a live source would give.

Input: a text table (optionally gzip), one row per sample: time [s], analog crank-wheel signal [V], pressure sensor
output [V], in either column order (the TU/e ``group14_*`` files hold wheel, pressure; ``trainingset_*`` hold
pressure, wheel). The wheel column is recognised by its content (thousands of rail-to-rail swings against a few
dozen for pressure), so misnamed files still work; ``columns=`` overrides.

Pipeline (``process_daq``): tooth edges and sync (drivers/daq/teeth.py) -> wheel angle of every sample -> 4-stroke
phase from the pressure -> per-cycle pegging and gain (drivers/daq/pressure.py) -> Pa. ``daq_to_records`` then cuts
the timeline into blocks of ``block_s`` and yields, per block, a ``ToothBatch`` with every edge detected in it (bad
revolutions included: a live sensor would send them too, and the cycle assembler must skip them itself) and a
``PressureBlock`` (NaN where no calibration covers a sample), in acquisition order.

Angles: ``tdc_deg`` is the crank angle of cylinder-1 firing TDC measured forward from the first rising edge after
the gap (tooth 0), so ``AcquisitionInfo.first_tooth_deg = -tdc_deg``. For the TU/e engine (group14_* files):
243.8 deg is the measured motored pressure peak, +0.7 deg thermodynamic loss angle (physics.md §14.6, stated, not
measured) -> 244.5 deg (``TUE_TDC_DEG``). The trainingset_* files peak ~56 deg after their tooth 0 (another
mounting, no motored record): with these defaults every one of their cycles is refused with a counted reason.

Defaults are those of the TU/e group14 set (engine ``tue-4gb10``, ``TUE_TDC_DEG``, sensor gain
``TUE_GAIN_PA_PER_V`` = 12.4 bar/V measured on its motored coast-downs with n = 1.32; fitting n instead gives
n = 1.22 and 10.5 bar/V, so pressures carry about +-15 % gain uncertainty). Other rigs must pass their own.
"""

from __future__ import annotations

import gzip
import logging
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from frictionwatch.core.model.engine import EngineSpec, load_engine
from frictionwatch.core.types import AcquisitionInfo, PressureBlock, StreamRecord, ToothBatch
from frictionwatch.drivers.daq.pressure import (
    CycleCalibration,
    apply_calibration,
    calibrate_cycles,
    firing_turns,
    sortable_angle,
    wheel_angle_of_samples,
)
from frictionwatch.drivers.daq.table_text import numeric_rows
from frictionwatch.drivers.daq.teeth import ToothEdges, WheelPattern, edge_ticks, wheel_pattern
from frictionwatch.drivers.daq.teeth import detect_teeth as _detect_teeth_signal
from frictionwatch.drivers.errors import CorruptLog

log = logging.getLogger(__name__)

TUE_TDC_DEG = 244.5  # group14_* files: motored peak 243.8 deg after tooth 0 + 0.7 deg loss angle
TUE_GAIN_PA_PER_V = 12.4e5  # group14_* sensor: median implied gain of the 40 motored coast-down cycles, n = 1.32


@dataclass(frozen=True)
class DaqTrace:
    """One raw DAQ record. ``wheel_v`` and ``pressure_v`` [V] sampled at ``sample_rate_hz`` from ``t0_s``."""

    name: str
    t0_s: float
    sample_rate_hz: float
    wheel_v: np.ndarray
    pressure_v: np.ndarray
    columns: tuple[int, int]  # 1-based (wheel, pressure) columns used
    notes: tuple[str, ...] = ()  # how the file was read, in words (a dropped cut last line)

    @property
    def n(self) -> int:
        return int(self.wheel_v.shape[0])


def _swings(x: np.ndarray) -> int:
    """Number of rising crossings of the mid level (a wheel signal has thousands, a pressure trace dozens)."""
    mid = 0.5 * (np.percentile(x, 5) + np.percentile(x, 95))
    s = x > mid
    return int(np.count_nonzero(s[1:] & ~s[:-1]))


def read_daq_table(path: str | Path, columns: tuple[int, int] | None = None) -> DaqTrace:
    """Read a whitespace-separated table (``.gz`` decompressed on the fly): time [s] in column 1, then the wheel
    and pressure signals [V] in the order found by content, or as ``columns = (wheel_col, pressure_col)`` (1-based).

    Raises CorruptLog for an unreadable, short or non-uniformly sampled table, FileNotFoundError if absent.
    """
    p = Path(path)
    opener = gzip.open if p.suffix == ".gz" else open
    try:
        with opener(p, "rb") as fh:
            text = fh.read().decode("latin-1")  # numbers are ASCII; any other byte is refused by the parse
    except FileNotFoundError:
        raise
    except (OSError, EOFError) as exc:
        raise CorruptLog(f"{p.name}: not a numeric DAQ table: {' '.join(str(exc).split())}") from exc
    a, notes = numeric_rows(text, p.name, "numeric DAQ table")
    if a.size == 0:
        raise CorruptLog(f"{p.name}: empty file (no data rows)")
    if a.shape[0] < 100 or a.shape[1] < 3:
        raise CorruptLog(f"{p.name}: need >= 100 rows and 3 columns (time, wheel, pressure), got {a.shape}")
    if not np.all(np.isfinite(a[:, :3])):
        raise CorruptLog(f"{p.name}: NaN or inf in the first three columns")
    dt = np.diff(a[:, 0])
    step = float(np.median(dt))
    if not step > 0 or np.max(np.abs(dt - step)) > 0.01 * step:
        raise CorruptLog(f"{p.name}: time column is not uniformly increasing (median step {step:g} s)")
    if columns is None:
        s2, s3 = _swings(a[:, 1]), _swings(a[:, 2])
        columns = (2, 3) if s2 >= s3 else (3, 2)
        if max(s2, s3) < 10 * max(1, min(s2, s3)):
            log.warning("%s: wheel column ambiguous (%d vs %d swings); taking column %d", p.name, s2, s3, columns[0])
    wc, pc = columns
    if {wc, pc} - set(range(2, a.shape[1] + 1)) or wc == pc:
        raise ValueError(f"columns must be two different 1-based data columns (2..{a.shape[1]}), got {columns}")
    return DaqTrace(
        name=p.name,
        t0_s=float(a[0, 0]),
        sample_rate_hz=1.0 / step,
        wheel_v=np.ascontiguousarray(a[:, wc - 1]),
        pressure_v=np.ascontiguousarray(a[:, pc - 1]),
        columns=(wc, pc),
        notes=tuple(notes),
    )


def _wheel(wheel: str) -> tuple[int, int]:
    try:
        n, k = (int(x) for x in wheel.split("-"))
    except ValueError as exc:
        raise ValueError(f"wheel must look like '60-2', got {wheel!r}") from exc
    if not (4 <= n <= 2000 and 1 <= k < n // 2):
        raise ValueError(f"implausible wheel {wheel!r}")
    return n, k


def trace_wheel(trace: DaqTrace, wheel: str | None) -> tuple[str, WheelPattern | None]:
    """The wheel to use for ``trace`` as 'N-K' and the pattern its edges show (drivers.daq.teeth.wheel_pattern).

    ``wheel`` None: the detected one (ValueError if none can be seen). A given wheel must match the detected
    pattern: ValueError naming both otherwise. A record too short to show two gaps keeps the given wheel."""
    ticks, _, _ = edge_ticks(trace.wheel_v, trace.sample_rate_hz)
    seen = wheel_pattern(ticks)
    if wheel is None:
        if seen is None:
            raise ValueError(f"{trace.name}: no repeating missing-tooth gap found in the wheel signal "
                             f"({ticks.shape[0]} edges); name the wheel with --wheel")
        return f"{seen.teeth}-{seen.missing}", seen
    n, k = _wheel(wheel)
    if seen is not None and (seen.present, seen.missing) != (n - k, k):
        raise ValueError(f"--wheel {wheel} but the file's wheel has {seen}")
    return wheel, seen


def detect_teeth(trace: DaqTrace, wheel: str = "60-2", tick_hz: float = 10e6, **kw: float) -> ToothEdges:
    """Tooth edges (integer ticks of a ``tick_hz`` timer) and missing-tooth sync of a trace's wheel signal.
    Keyword options go to drivers.daq.teeth.detect_teeth (level, arm_frac, fire_frac, weak_frac)."""
    n, k = _wheel(wheel)
    t0 = round(trace.t0_s * tick_hz)
    return _detect_teeth_signal(trace.wheel_v, trace.sample_rate_hz, tick_hz, t0, n, k, **kw)


@dataclass(frozen=True)
class DaqResult:
    """Everything ``process_daq`` derived from one trace (per-sample arrays have the trace's length).

    sample_ticks  (n,) int64 timer tick of each sample
    phi_deg       (n,) unwrapped wheel angle [deg] (360 * turn + angle after tooth 0), NaN outside verified turns
    pressure_pa   (n,) absolute pressure [Pa], NaN where no calibration covers the sample
    tdc_phi_deg   (c,) wheel angle of every calibrated firing TDC (= phi of TDC, use phi_deg - tdc for theta)
    """

    trace: DaqTrace
    edges: ToothEdges
    tdc_deg: float
    sample_ticks: np.ndarray
    phi_deg: np.ndarray
    pressure_pa: np.ndarray
    calibrations: list[CycleCalibration]
    damage: Counter = field(default_factory=Counter)

    @property
    def tdc_phi_deg(self) -> np.ndarray:
        return np.array([c.tdc_phi for c in self.calibrations])

    def complete_cycles(self) -> list[int]:
        """Indices k of calibrations whose TDC-centred cycle [TDC_k - 360, TDC_k + 360) deg is fully covered."""
        key = sortable_angle(self.phi_deg)
        out = []
        for k, c in enumerate(self.calibrations):
            lo, hi = np.searchsorted(key, [c.tdc_phi - 360.0, c.tdc_phi + 360.0])
            inside = 0 < lo and hi < key.shape[0] and np.isfinite(self.phi_deg[[lo - 1, hi]]).all()
            if inside and np.all(np.isfinite(self.pressure_pa[lo:hi])):
                out.append(k)
        return out

    def cycle_on_grid(self, k: int, grid_deg: np.ndarray) -> np.ndarray:
        """Pressure [Pa] of TDC-centred cycle k on ``grid_deg`` (deg from firing TDC, within [-360, 360))."""
        c = self.calibrations[k]
        key = sortable_angle(self.phi_deg)
        lo, hi = np.searchsorted(key, [c.tdc_phi - 360.0, c.tdc_phi + 360.0])
        return np.interp(grid_deg, self.phi_deg[lo:hi] - c.tdc_phi, self.pressure_pa[lo:hi])

    def verified_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """(phi_deg, ticks) of every edge of the verified revolutions, closing teeth included, in order.
        phi is the nominal unwrapped wheel angle (360 * turn + tooth * 360/N)."""
        e = self.edges
        present = e.wheel_teeth - e.wheel_missing
        step = 360.0 / e.wheel_teeth
        idx = [np.arange(a, a + present) for a in e.rev_start] + [e.rev_end]
        phi = [360.0 * t + np.arange(present) * step for t in e.rev_turn] + [360.0 * (e.rev_turn + 1)]
        if not e.rev_start.size:
            return np.zeros(0), np.zeros(0, dtype=np.int64)
        i, f = np.concatenate(idx), np.concatenate(phi)
        order = np.argsort(f, kind="stable")
        i, f = i[order], f[order]
        keep = np.concatenate([[True], np.diff(f) > 0])  # a closing tooth 0 that also opens the next revolution
        return f[keep], e.ticks[i[keep]]

    def tdc_ticks(self) -> np.ndarray:
        """Timer tick of every calibrated firing TDC (interpolated in the wheel angle)."""
        key = sortable_angle(self.phi_deg)
        ok = np.isfinite(self.phi_deg)
        return np.rint(np.interp(self.tdc_phi_deg, key[ok], self.sample_ticks[ok].astype(np.float64))).astype(np.int64)


def pressure_peak_deg(trace: DaqTrace, wheel: str = "60-2", tick_hz: float = 10e6) -> tuple[float, int]:
    """(wheel angle [deg] after tooth 0, mod 360, of the pressure peak of the firing revolutions, how many) — a
    starting point for finding TDC from the pressure (service.daq_tdc), NaN when no two consecutive revolutions are
    verified. Of two consecutive revolutions the one with the higher peak holds the firing (or motored) TDC; the
    median over those revolutions is returned."""
    edges = detect_teeth(trace, wheel, tick_hz)
    ticks_per_sample = tick_hz / trace.sample_rate_hz
    sample_ticks = round(trace.t0_s * tick_hz) + np.rint(np.arange(trace.n) * ticks_per_sample).astype(np.int64)
    phi = wheel_angle_of_samples(sample_ticks, edges.ticks, edges.rev_start, edges.rev_end, edges.rev_turn,
                                 edges.wheel_teeth, edges.wheel_missing)
    key = sortable_angle(phi)
    peaks: dict[int, tuple[float, float]] = {}
    for turn in edges.rev_turn.tolist():
        lo, hi = np.searchsorted(key, [360.0 * turn, 360.0 * (turn + 1)])
        if hi - lo > 10 and np.all(np.isfinite(phi[lo:hi])):
            i = lo + int(np.argmax(trace.pressure_v[lo:hi]))
            peaks[turn] = (float(trace.pressure_v[i]), float(phi[i] - 360.0 * turn))
    firing = [a for t, (v, a) in peaks.items() if all(v > peaks[n][0] for n in (t - 1, t + 1) if n in peaks)
              and any(n in peaks for n in (t - 1, t + 1))]
    if not firing:
        return math.nan, 0
    # angles near 0/360 wrap: take the median about the circular mean
    ang = np.radians(firing)
    centre = math.atan2(np.sin(ang).mean(), np.cos(ang).mean())
    dev = np.angle(np.exp(1j * (ang - centre)))
    return float(np.degrees(centre + np.median(dev)) % 360.0), len(firing)


def process_daq(
    trace: DaqTrace,
    engine: EngineSpec | str = "tue-4gb10",
    *,
    wheel: str = "60-2",
    tdc_deg: float = TUE_TDC_DEG,
    tick_hz: float = 10e6,
    gain_pa_per_v: float | None = TUE_GAIN_PA_PER_V,
    peg: str = "polytropic",
    peg_pa: float = 1.0e5,
    n_poly: float = 1.32,
    window_deg: tuple[float, float] = (-100.0, -60.0),
) -> DaqResult:
    """Teeth, phase, calibrated pressure of one trace (module docstring; pegging in drivers/daq/pressure.py).

    gain_pa_per_v : sensor gain [Pa/V]; default: the TU/e group14 sensor (``TUE_GAIN_PA_PER_V``, measured on its
        motored coast-downs). None = self-calibrate from p(intake BDC) = ``peg_pa``: valid only at wide-open throttle
        (motored coast-downs); a throttled fired file would come out 1.8-3.4x too high.
    """
    eng = load_engine(engine) if isinstance(engine, str) else engine
    if not 0.0 <= tdc_deg < 720.0:
        raise ValueError(f"tdc_deg must be in [0, 720) deg after tooth 0, got {tdc_deg}")
    edges = detect_teeth(trace, wheel, tick_hz)
    damage = Counter(edges.damage)
    ticks_per_sample = tick_hz / trace.sample_rate_hz
    sample_ticks = round(trace.t0_s * tick_hz) + np.rint(np.arange(trace.n) * ticks_per_sample).astype(np.int64)
    phi = wheel_angle_of_samples(
        sample_ticks,
        edges.ticks,
        edges.rev_start,
        edges.rev_end,
        edges.rev_turn,
        edges.wheel_teeth,
        edges.wheel_missing,
    )
    fire, dmg = firing_turns(phi, trace.pressure_v, edges.rev_turn, tdc_deg % 360.0)
    damage.update(dmg)
    tdc_phis = 360.0 * fire + (tdc_deg % 360.0)
    cals, dmg = calibrate_cycles(
        phi,
        trace.pressure_v,
        tdc_phis,
        eng,
        n_poly=n_poly,
        window_deg=window_deg,
        peg=peg,
        peg_pa=peg_pa,
        gain_pa_per_v=gain_pa_per_v,
    )
    damage.update(dmg)
    p = apply_calibration(phi, trace.pressure_v, cals)
    return DaqResult(trace, edges, float(tdc_deg), sample_ticks, phi, p, cals, damage)


def daq_to_records(
    path: str | Path,
    wheel: str = "60-2",
    tdc_deg: float = TUE_TDC_DEG,
    *,
    engine: EngineSpec | str = "tue-4gb10",
    tick_hz: float = 10e6,
    gain_pa_per_v: float | None = TUE_GAIN_PA_PER_V,
    peg: str = "polytropic",
    peg_pa: float = 1.0e5,
    n_poly: float = 1.32,
    block_s: float = 0.01,
    columns: tuple[int, int] | None = None,
) -> tuple[AcquisitionInfo, list[StreamRecord]]:
    """A raw DAQ file as (AcquisitionInfo, records in acquisition order): ToothBatch + PressureBlock (cylinder 1)
    per ``block_s`` of signal, exactly what a live source yields. Options as in ``process_daq``."""
    _wheel(wheel)  # a malformed wheel is refused before the file is read
    return trace_to_records(read_daq_table(path, columns), wheel, tdc_deg, engine=engine, tick_hz=tick_hz,
                            gain_pa_per_v=gain_pa_per_v, peg=peg, peg_pa=peg_pa, n_poly=n_poly, block_s=block_s)


def trace_to_records(
    trace: DaqTrace,
    wheel: str = "60-2",
    tdc_deg: float = TUE_TDC_DEG,
    *,
    engine: EngineSpec | str = "tue-4gb10",
    tick_hz: float = 10e6,
    gain_pa_per_v: float | None = TUE_GAIN_PA_PER_V,
    peg: str = "polytropic",
    peg_pa: float = 1.0e5,
    n_poly: float = 1.32,
    block_s: float = 0.01,
) -> tuple[AcquisitionInfo, list[StreamRecord]]:
    """``daq_to_records`` of a trace already read."""
    if not block_s > 0:
        raise ValueError(f"block_s must be > 0 s, got {block_s}")
    _wheel(wheel)
    res = process_daq(
        trace,
        engine,
        wheel=wheel,
        tdc_deg=tdc_deg,
        tick_hz=tick_hz,
        gain_pa_per_v=gain_pa_per_v,
        peg=peg,
        peg_pa=peg_pa,
        n_poly=n_poly,
    )
    return result_to_records(res, wheel, block_s)


def result_to_records(res: DaqResult, wheel: str = "60-2", block_s: float = 0.01
                      ) -> tuple[AcquisitionInfo, list[StreamRecord]]:
    """(AcquisitionInfo, records) of a processed trace (``trace_to_records`` after ``process_daq``)."""
    if not block_s > 0:
        raise ValueError(f"block_s must be > 0 s, got {block_s}")
    n_teeth, n_missing = _wheel(wheel)
    if res.damage:
        log.info("%s: skipped %s", res.trace.name, dict(res.damage))
    first = -(res.tdc_deg % 360.0)  # tooth 0 precedes firing TDC by tdc_deg mod 360 (no cam: phase from pressure)
    info = AcquisitionInfo(
        tick_hz=float(res.edges.tick_hz),
        wheel_teeth=n_teeth,
        wheel_missing=n_missing,
        first_tooth_deg=first,
        cam_deg=None,
        pressure_cylinders=(1,),
    )
    return info, _blocks(res, block_s, res.edges.tick_hz)


def _blocks(res: DaqResult, block_s: float, tick_hz: float) -> list[StreamRecord]:
    per_block = max(1, round(block_s * res.trace.sample_rate_hz))
    period = tick_hz / res.trace.sample_rate_hz
    out: list[StreamRecord] = []
    edge_ticks = res.edges.ticks
    for i0 in range(0, res.trace.n, per_block):
        i1 = min(i0 + per_block, res.trace.n)
        t_lo = res.sample_ticks[i0]
        t_hi = res.sample_ticks[i1] if i1 < res.trace.n else res.sample_ticks[-1] + 1
        e0, e1 = np.searchsorted(edge_ticks, [t_lo, t_hi])
        if e1 > e0:
            out.append(ToothBatch(ticks=edge_ticks[e0:e1].copy()))
        out.append(
            PressureBlock(cylinder=1, t0_ticks=int(t_lo), period_ticks=period, values=res.pressure_pa[i0:i1].copy())
        )
    return out
