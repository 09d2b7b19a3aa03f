"""Pressure-based ring indicators of every cylinder, from the first cycle (issue 19 item 4, issue 17 item 4).

A leak past the rings (blow-by, worn rings) loses trapped mass while the valves are shut. Over the compression the
pressure then rises less steeply, over the expansion it falls more steeply than the siblings'. Per cycle and
cylinder, from the pressure on fixed crank-angle windows relative to the cylinder's own firing TDC:

    compression_ratio   ln p_k(theta_c) - median_j ln p_j(theta_c), theta_c = ``compression_deg`` before TDC (before
                        the start of combustion): the compression pressure against the siblings. A common load or
                        speed change and a gain drift common to every sensor cancel; a single cylinder's gain error
                        g does NOT: it reads ln g exactly like a leak of that size
    n_compression       polytropic exponent of the compression, the slope of ln p on -ln V over the compression window
    n_expansion         the same over the expansion window (after combustion, before EVO)
    expansion_deficit   ln p at the end of the expansion window minus the polytrope through its start with the
                        siblings' median exponent: < 0 when the pressure falls faster than the siblings' would
    *_dev               each exponent minus the siblings' median (a common change, load or speed, cancels)

Both exponents and the deficit are differences of ln p within one cylinder's trace: a gain error of that cylinder's
sensor adds the same ln g to every sample and cancels exactly; a leak moves n_compression down and n_expansion up
(mass leaves in both strokes). A pegging offset moves both exponents DOWN (an offset weighs less where p is high), a
TDC error shifts the trace against V. So the service separates: compression ratio low with both exponents unchanged
is a gain error or a leak too small to bend the polytropes (ambiguous: a sensor check, never a ring alert);
n_compression down with n_expansion up is the leak's signature. Nothing here decides; service.alerts does (with a
commissioning baseline per cylinder, since a healthy cylinder's heat transfer and fuel spread leave it a persistent
offset from its siblings).

Each cylinder is read on the flywheel encoder's angle while its piston follows its own throw: the shaft's twist
(static and vibratory) shifts its TDC on the grid, and the exponents are steep in that shift. On genset-v20's windows
0.1 deg moves n_compression by -0.0019 and n_expansion by +0.0023 (a 3 % leak's size); the twist changes with the
load, and a step 0.75 -> 0.45 moved single cylinders' sibling-relative leak effect (-dn_c + dn_e) / 2 by up to
0.0028 (0.0006 with the same simulator's shaft made rigid; K9K, a short stiff crank: 0.0002). The service therefore
keeps its commissioning baseline per load band (service.alert_baseline) rather than reading a load change as a leak.
Where the monitor's harmonic balance gives the throws' motion (``ThrowMotion``: each throw's static twist and
node-minus-flywheel angle harmonics of the cycle), each window sample is read where the cylinder's own throw is at
the window's angle, not the flywheel (``moved_tables``): the twist's share of each cylinder's sibling offset goes
(design note 32: healthy genset-v20 seed 7, the leak effect's sibling spread SD 0.0037 at the flywheel's angle,
0.00044 at the throws', as on a rigid shaft).

Arrays in, arrays out, no state: the windows are fixed by the engine spec, so each cycle stands alone. What the grid
fixes (every window sample's grid columns, -ln V there) is made once per grid (``ring_tables``, carried by the caller;
a cycle's throw motion moves the columns, ``moved_tables``, one kernel ``moved_kernel``); the per-cycle numbers come
from one kernel (``ring_kernel``), checked against the plain numpy
``ring_indicators_reference`` (tests/core/test_condition_kernels.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.kinematics import kinematics

FOUR_PI = 4.0 * np.pi
RESTART = 32  # moved_kernel: its terms recomputed directly at least this often (rounding of the rotations)
STEP_DEG = 1.0  # the windows are sampled every degree (np.interp on the cycle's grid: any grid resolution)


@dataclass(frozen=True)
class RingWindows:
    """Crank-angle windows [deg from firing TDC]: compression fit [comp_start, comp_end] with the compression
    pressure read at comp_end; expansion fit [exp_start, exp_end]; ``edge_deg``: the expansion deficit compares the
    mean ln p over the last ``edge_deg`` of the expansion window with the polytrope through its first ``edge_deg``."""

    comp_start: float
    comp_end: float
    exp_start: float
    exp_end: float
    edge_deg: float = 10.0


def ring_windows(spec: EngineSpec, compression_deg: float = 30.0, comp_span_deg: float = 70.0,
                 expansion_deg: float = 70.0, evo_margin_deg: float = 15.0, combustion_margin_deg: float = 10.0
                 ) -> RingWindows:
    """The engine's windows: the compression window ends ``compression_deg`` before TDC or ``combustion_margin_deg``
    before the start of combustion, whichever is earlier, and spans ``comp_span_deg`` (never before IVC + 10 deg);
    the expansion window starts ``expansion_deg`` after TDC (the burn is over on every preset: start + duration
    <= 60 deg) and ends ``evo_margin_deg`` before EVO."""
    cb = spec.combustion
    end = -max(compression_deg, combustion_margin_deg - cb.start_deg)
    start = max(end - comp_span_deg, cb.ivc_deg + 10.0)
    exp_end = cb.evo_deg - evo_margin_deg
    exp_start = min(expansion_deg, exp_end - 30.0)
    if not (start < end - 20.0 and exp_start < exp_end - 20.0):
        raise ValueError(f"{spec.name}: no room for the ring-indicator windows (IVC {cb.ivc_deg}, start of "
                         f"combustion {cb.start_deg}, EVO {cb.evo_deg} deg)")
    return RingWindows(start, end, exp_start, exp_end)


@dataclass(frozen=True)
class RingIndicators:
    """One cycle's ring indicators (z,) each (module doc); NaN where a cylinder's pressure is not positive in a
    window. ``compression_pa`` (z,) the compression pressure read at theta_c [Pa]."""

    compression_pa: np.ndarray
    compression_ratio: np.ndarray
    n_compression: np.ndarray
    n_expansion: np.ndarray
    n_compression_dev: np.ndarray
    n_expansion_dev: np.ndarray
    expansion_deficit: np.ndarray

    def compared(self) -> np.ndarray:
        """(4, z) what the alerts compare with a commissioning baseline, rows: compression_ratio, n_compression_dev,
        n_expansion_dev, expansion_deficit. A single cylinder has no siblings: its rows are the absolute ln
        compression pressure and exponents (a load or speed change moves them like a fault would)."""
        if self.n_compression.shape[0] == 1:
            return np.array([np.log(self.compression_pa), self.n_compression, self.n_expansion,
                             self.expansion_deficit])
        return np.array([self.compression_ratio, self.n_compression_dev, self.n_expansion_dev,
                         self.expansion_deficit])

    def to_json(self) -> dict:
        """Per-cylinder lists (None for NaN); dimensionless except compression_bar."""
        def col(a: np.ndarray, scale: float = 1.0) -> list:
            return [float(v) / scale if np.isfinite(v) else None for v in a]
        return {"compression_bar": col(self.compression_pa, 1e5), "compression_ratio_ln": col(self.compression_ratio),
                "n_compression": col(self.n_compression), "n_expansion": col(self.n_expansion),
                "n_compression_dev": col(self.n_compression_dev), "n_expansion_dev": col(self.n_expansion_dev),
                "expansion_deficit_ln": col(self.expansion_deficit)}


def _sibling_median(x: np.ndarray) -> np.ndarray:
    """(z,) x_k minus the median of the finite entries (z >= 3), minus the other one (z = 2), 0 for one cylinder."""
    z = x.shape[0]
    ok = np.isfinite(x)
    if z < 2 or ok.sum() < 2:
        return np.where(ok, 0.0, np.nan) if z < 2 else np.full(z, np.nan)
    if z == 2:
        return x - x[::-1]
    return x - np.median(x[ok])


def _window(spec: EngineSpec, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Angles [rad] from TDC every STEP_DEG over [lo, hi] deg and -ln V there (V from the slider-crank; the constant
    clearance volume cancels in a slope, so the units do not matter)."""
    local = np.radians(np.arange(lo, hi + 0.5 * STEP_DEG, STEP_DEG))
    x, _, _ = kinematics(local, np.asarray(spec.kinematics_params(), dtype=np.float64))
    vol = spec.clearance_volume + spec.piston_area * x
    return local, -np.log(vol)


class ThrowMotion(NamedTuple):
    """Each cylinder's throw against the flywheel in one cycle (the monitor's harmonic balance): ``static`` (z,)
    [rad] the static twist (throw minus flywheel), ``relative`` (z, M) complex the node-minus-flywheel angle
    harmonics [rad] (harmonic j at 0.5 (j + 1) times the mean speed, time from the cycle's first edge: its flywheel
    angle ``theta_start`` [rad])."""

    static: np.ndarray
    relative: np.ndarray
    theta_start: float


def throw_lag_reference(motion: ThrowMotion, angles: np.ndarray) -> np.ndarray:
    """(z, m) each throw's angle minus the flywheel's [rad] at flywheel angles (z, m) [rad], the harmonic sum as
    written: static + Re sum_j b_j exp(i (j + 1) (theta - theta_start) / 2) (the flywheel's own ripple in the
    angle-to-time map left out: a tenth of a degree moves a harmonic's phase by less than its order in tenths)."""
    u = 0.5 * (np.asarray(angles, dtype=np.float64) - motion.theta_start)
    orders = np.arange(1, motion.relative.shape[1] + 1)
    waves = np.exp(1j * u[:, :, None] * orders[None, None, :])  # (z, m, M)
    return motion.static[:, None] + np.real((waves * motion.relative[:, None, :]).sum(axis=2))


def _sample(spec: EngineSpec, grid: np.ndarray, pressure: np.ndarray, local: np.ndarray,
            motion: ThrowMotion | None = None) -> np.ndarray:
    """(z, m) ln p of each cylinder at ``local`` angles from its firing TDC (of its throw where ``motion`` is given:
    at the flywheel angle minus the throw's lag there), linear between grid points and periodic over 4 pi (NaN
    where p <= 0). One searchsorted for all cylinders on the grid extended by one point at each end (np.interp's
    period mode sorts per call)."""
    z, n = pressure.shape
    at = local[None, :] + spec.firing_angles[:, None]
    if motion is not None:
        at = at - throw_lag_reference(motion, at)
    at = np.mod(at, FOUR_PI).ravel()
    ext = np.concatenate(([grid[-1] - FOUR_PI], grid, [grid[0] + FOUR_PI]))
    j = np.searchsorted(ext, at, side="right") - 1  # ext[j] <= at < ext[j + 1], j in 0..n
    frac = (at - ext[j]) / (ext[j + 1] - ext[j])
    cols = (j - 1) % n  # ext index i is grid index i - 1 (mod n)
    rows = np.repeat(np.arange(z), local.shape[0])
    p0 = pressure[rows, cols]
    p = p0 + (pressure[rows, (cols + 1) % n] - p0) * frac
    return np.log(np.where(p > 0.0, p, np.nan)).reshape(z, local.shape[0])


def _slopes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(z,) least-squares slope of each row of y (z, m) on x (m,) (NaN where a row has a NaN)."""
    xc = x - x.mean()
    return (y - y.mean(axis=1, keepdims=True)) @ xc / (xc @ xc)


def ring_indicators_reference(spec: EngineSpec, grid: np.ndarray, pressure: np.ndarray,
                              windows: RingWindows | None = None, motion: ThrowMotion | None = None
                              ) -> RingIndicators:
    """This cycle's ring indicators from the pressure (z, n) [Pa] on ``grid`` (n,) [rad, cylinder 1's 0..4 pi], each
    cylinder read at its throw's angle where ``motion`` is given: the plain numpy reference of ``ring_indicators``
    (the module doc's definitions, step by step)."""
    win = windows or ring_windows(spec)
    c_ang, c_x = _window(spec, win.comp_start, win.comp_end)
    e_ang, e_x = _window(spec, win.exp_start, win.exp_end)
    both = _sample(spec, grid, pressure, np.concatenate((c_ang, e_ang)), motion)  # one pass for the two windows
    c_lnp, e_lnp = both[:, :c_ang.shape[0]], both[:, c_ang.shape[0]:]
    n_c, n_e = _slopes(c_x, c_lnp), _slopes(e_x, e_lnp)
    comp_ln = c_lnp[:, -1]
    n_e_dev = _sibling_median(n_e)
    # the siblings' polytrope through the window's first edge_deg, read over its last edge_deg
    m = max(1, int(round(win.edge_deg / STEP_DEG)))
    n_sib = n_e - n_e_dev if spec.n_cyl > 1 else n_e
    deficit = (e_lnp[:, -m:].mean(axis=1) - e_lnp[:, :m].mean(axis=1)
               - n_sib * (e_x[-m:].mean() - e_x[:m].mean()))
    return RingIndicators(compression_pa=np.exp(comp_ln), compression_ratio=_sibling_median(comp_ln),
                          n_compression=n_c, n_expansion=n_e, n_compression_dev=_sibling_median(n_c),
                          n_expansion_dev=n_e_dev, expansion_deficit=deficit)


# ---- the kernel: what the grid fixes once, the rest per cycle ---------------------------------------------------


class RingTables(NamedTuple):
    """What the cycles' grid fixes of the ring indicators (``ring_tables``): the grid's first angle [rad] and size (a
    cycle on another grid makes them anew), each window sample's grid column (z, m) int64 and fraction towards the
    next column (z, m) (linear, periodic), -ln V at the samples (m,): the compression window's first ``n_comp``, then
    the expansion window's, and ``edge`` samples at each end of the expansion window for the deficit."""

    first_angle: float
    size: int
    cols: np.ndarray
    frac: np.ndarray
    neg_log_volume: np.ndarray
    n_comp: int
    edge: int
    local: np.ndarray | None = None  # (m,) the window samples' angles from firing TDC [rad] (``moved_tables``)

    def fits(self, grid: np.ndarray) -> bool:
        return grid.shape[0] == self.size and float(grid[0]) == self.first_angle


def ring_tables(spec: EngineSpec, grid: np.ndarray, windows: RingWindows | None = None) -> RingTables:
    """The sample columns and fractions of both windows on ``grid`` (n,) [rad] (exactly ``_sample``'s: one
    searchsorted on the grid extended by one point at each end) and -ln V there."""
    win = windows or ring_windows(spec)
    c_ang, c_x = _window(spec, win.comp_start, win.comp_end)
    e_ang, e_x = _window(spec, win.exp_start, win.exp_end)
    local = np.concatenate((c_ang, e_ang))
    cols, frac = _columns(grid, local[None, :] + spec.firing_angles[:, None])
    edge = max(1, int(round(win.edge_deg / STEP_DEG)))
    return RingTables(float(grid[0]), int(grid.shape[0]), cols, frac, np.concatenate((c_x, e_x)),
                      int(c_ang.shape[0]), edge, local)


def moved_tables(spec: EngineSpec, grid: np.ndarray, tables: RingTables, motion: ThrowMotion) -> RingTables:
    """``tables`` (made by ``ring_tables`` for ``grid``) with every window sample moved to where the cylinder's
    throw, not the flywheel, is at the sample's angle from its firing TDC this cycle (to first order in the lag, a
    few tenths of a degree): ``_sample``'s columns with ``throw_lag_reference`` by one kernel (``moved_kernel``;
    numpy's 94,000 complex exponentials and a searchsorted took 1.6 ms a genset-v20 cycle)."""
    z, m = tables.cols.shape
    cols, frac = np.empty((z, m), dtype=np.int64), np.empty((z, m))
    moved_kernel(np.ascontiguousarray(grid, dtype=np.float64), tables.local,
                  np.ascontiguousarray(spec.firing_angles, dtype=np.float64),
                  np.ascontiguousarray(motion.static, dtype=np.float64),
                  np.ascontiguousarray(motion.relative, dtype=np.complex128), float(motion.theta_start), cols, frac)
    return tables._replace(cols=cols, frac=frac)


@numba.njit(cache=True)
def moved_kernel(grid, local, phases, static, rel, theta_start, cols, frac):
    """cols/frac (z, m) in place: each sample at flywheel angle a = local + phase minus the throw's lag there
    (static + Re sum_j rel_j exp(i (j + 1) (a - theta_start) / 2)), then its bracket on the grid extended by one
    point at each end, periodic over 4 pi (``_columns``; ``_bracket``, from the cylinder's last one). The samples
    are evenly spaced: along a run of them each harmonic's term is turned by its own fixed rotation, recomputed
    directly every RESTART samples and wherever the spacing changes (a window's start), so rounding never
    accumulates over more than RESTART products. Rotation and restarts depend on the sample only, so the cylinders
    step together: each lag is still its own terms summed in order (the same bits), but z sums run side by side,
    not one serial chain of additions per sample (design note 37: 62 -> 37 us a genset-v20 cycle)."""
    z, m = cols.shape
    n_h = rel.shape[1]
    qr, qi = np.empty((n_h, z)), np.empty((n_h, z))  # each harmonic's term at the sample (re, im), (j, cylinder)
    rr, ri = np.empty(n_h), np.empty(n_h)  # its rotation from one sample to the next
    lag = np.empty(z)
    last = np.full(z, -1)  # each cylinder's last bracket (-1: none yet)
    spacing = np.nan
    for i in range(m):
        d = local[i] - local[i - 1] if i > 0 else np.nan
        restart = i % RESTART == 0 or not abs(d - spacing) <= 1e-12
        if restart:  # the terms from scratch (and the rotations)
            for k in range(z):
                u = 0.5 * (local[i] + phases[k] - theta_start)
                step = complex(np.cos(u), np.sin(u))
                w = step
                for j in range(n_h):
                    q = rel[k, j] * w
                    qr[j, k], qi[j, k] = q.real, q.imag
                    w *= step
            if i + 1 < m:
                spacing = local[i + 1] - local[i]
                h = 0.5 * spacing
                rot = complex(np.cos(h), np.sin(h))
                v = rot
                for j in range(n_h):
                    rr[j], ri[j] = v.real, v.imag
                    v *= rot
        for k in range(z):
            lag[k] = static[k]
        for j in range(n_h):
            c, s = rr[j], ri[j]
            if restart:
                for k in range(z):
                    lag[k] += qr[j, k]
            else:
                for k in range(z):  # q *= rot, as complex multiplication forms it: (ac - bd) + i (ad + bc)
                    a, b = qr[j, k], qi[j, k]
                    qr[j, k] = a * c - b * s
                    qi[j, k] = a * s + b * c
                    lag[k] += qr[j, k]
        for k in range(z):
            at = local[i] + phases[k] - lag[k]
            at -= FOUR_PI * np.floor(at / FOUR_PI)
            cols[k, i], frac[k, i], last[k] = _bracket(grid, at, last[k])


@numba.njit(cache=True)
def _bracket(grid, at, guess):
    """(column, fraction, lo) of the angle ``at`` in [0, 4 pi): the last index e of the grid extended by one point at each
    end (ext = [grid[-1] - 4 pi, grid..., grid[0] + 4 pi]) with ext[e] <= at, as a grid column, and the fraction
    towards the next. Inside the grid the bracket grid[lo] <= at < grid[lo + 1] is unique: it is tried at ``guess``
    and the one after (window samples 1 deg apart on a ~1 deg grid) before a bisection; lo is -1 outside it."""
    n = grid.shape[0]
    if at < grid[0]:
        return n - 1, (at - (grid[n - 1] - FOUR_PI)) / (grid[0] - (grid[n - 1] - FOUR_PI)), -1
    if at >= grid[n - 1]:
        return n - 1, (at - grid[n - 1]) / (grid[0] + FOUR_PI - grid[n - 1]), -1
    lo = guess
    if not (0 <= lo < n - 1 and grid[lo] <= at < grid[lo + 1]):
        lo = guess + 1
        if not (0 <= lo < n - 1 and grid[lo] <= at < grid[lo + 1]):
            lo, hi = 0, n - 1  # grid[lo] <= at < grid[hi]
            while hi - lo > 1:
                mid = (lo + hi) >> 1
                if grid[mid] <= at:
                    lo = mid
                else:
                    hi = mid
    return lo, (at - grid[lo]) / (grid[lo + 1] - grid[lo]), lo


def _columns(grid: np.ndarray, angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grid column (z, m) int64 and fraction towards the next column of every angle (z, m) [rad], periodic over
    4 pi: exactly ``_sample``'s (one searchsorted on the grid extended by one point at each end)."""
    n = grid.shape[0]
    at = np.mod(angles, FOUR_PI).ravel()
    ext = np.concatenate(([grid[-1] - FOUR_PI], grid, [grid[0] + FOUR_PI]))
    j = np.searchsorted(ext, at, side="right") - 1
    frac = (at - ext[j]) / (ext[j + 1] - ext[j])
    cols = (j - 1) % n
    return cols.reshape(angles.shape).astype(np.int64), frac.reshape(angles.shape)


def ring_indicators(spec: EngineSpec, grid: np.ndarray, pressure: np.ndarray, windows: RingWindows | None = None,
                    tables: RingTables | None = None) -> RingIndicators:
    """This cycle's ring indicators from the pressure (z, n) [Pa] on ``grid`` (n,) [rad, cylinder 1's 0..4 pi];
    ``tables`` from ``ring_tables`` for this grid (made here when None or made for another grid)."""
    tab = tables if tables is not None and tables.fits(grid) else ring_tables(spec, grid, windows)
    p = np.asarray(pressure, dtype=np.float64)
    if p.shape != (spec.n_cyl, tab.size):
        raise ValueError(f"pressure must have shape ({spec.n_cyl}, {tab.size}) on the cycle's grid; got {p.shape}")
    out = ring_kernel(p, tab.cols, tab.frac, tab.neg_log_volume, tab.n_comp, tab.edge)
    return RingIndicators(compression_pa=out[0], compression_ratio=out[1], n_compression=out[2],
                          n_expansion=out[3], n_compression_dev=out[4], n_expansion_dev=out[5],
                          expansion_deficit=out[6])


@numba.njit(cache=True)
def _slope(x, y):
    """Least-squares slope of y (m,) on x (m,) (NaN where y has a NaN)."""
    m = x.shape[0]
    xm = 0.0
    ym = 0.0
    for i in range(m):
        xm += x[i]
        ym += y[i]
    xm /= m
    ym /= m
    sxy = 0.0
    sxx = 0.0
    for i in range(m):
        d = x[i] - xm
        sxy += (y[i] - ym) * d
        sxx += d * d
    return sxy / sxx


@numba.njit(cache=True)
def median_of_first(buf, n):
    """The median of buf[:n] (n >= 1, no NaN) as np.median takes it. One compiled sort shared by the checks'
    kernels (core.monitor.checks.condition calls it too)."""
    s = np.sort(buf[:n])
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


@numba.njit(cache=True)
def _sibling_median_kernel(x, out):
    """``_sibling_median`` into out (z,) (element loops: slice assignment and mask indexing compile slowly)."""
    z = x.shape[0]
    buf = np.empty(z)
    n_ok = np.int64(0)  # typed int64 from the start: a literal 0 compiles median_of_first once more
    for k in range(z):
        if np.isfinite(x[k]):
            buf[n_ok] = x[k]
            n_ok += 1
    for k in range(z):
        if z < 2:
            out[k] = 0.0 if np.isfinite(x[k]) else np.nan
        elif n_ok < 2:
            out[k] = np.nan
        elif z == 2:
            out[k] = x[k] - x[1 - k]
    if z > 2 and n_ok >= 2:
        med = median_of_first(buf, n_ok)
        for k in range(z):
            out[k] = x[k] - med


@numba.njit(cache=True)
def ring_kernel(pressure, cols, frac, neg_log_volume, n_comp, edge):
    """(7, z): compression_pa, compression_ratio, n_compression, n_expansion, n_compression_dev, n_expansion_dev,
    expansion_deficit (``ring_indicators_reference``) from the pressure (z, n) sampled at cols/frac (z, m)."""
    z, n = pressure.shape
    m = cols.shape[1]
    lnp = np.empty((z, m))
    for k in range(z):
        for i in range(m):
            c = cols[k, i]
            p0 = pressure[k, c]
            p = p0 + (pressure[k, (c + 1) % n] - p0) * frac[k, i]
            lnp[k, i] = np.log(p) if p > 0.0 else np.nan
    out = np.empty((7, z))
    x_c, x_e = neg_log_volume[:n_comp], neg_log_volume[n_comp:]
    comp_ln = np.empty(z)
    for k in range(z):
        comp_ln[k] = lnp[k, n_comp - 1]
        out[0, k] = np.exp(comp_ln[k])
        out[2, k] = _slope(x_c, lnp[k, :n_comp])
        out[3, k] = _slope(x_e, lnp[k, n_comp:])
    _sibling_median_kernel(comp_ln, out[1])
    _sibling_median_kernel(out[2], out[4])
    _sibling_median_kernel(out[3], out[5])
    m_e = m - n_comp
    x_late = 0.0
    x_early = 0.0
    for i in range(edge):
        x_late += x_e[m_e - edge + i]
        x_early += x_e[i]
    dx = x_late / edge - x_early / edge
    for k in range(z):
        n_sib = out[3, k] - out[5, k] if z > 1 else out[3, k]
        late = 0.0
        early = 0.0
        for i in range(edge):
            late += lnp[k, m - edge + i]
            early += lnp[k, n_comp + i]
        out[6, k] = late / edge - early / edge - n_sib * dx
    return out
