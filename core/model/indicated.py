"""Indicated quantities from a pressure trace (physics.md §2, §6): net indicated work, IMEP, peak pressure.

Net IMEP = (1/V_d) ∮ p dV over the whole 720 deg cycle (pumping loop included).

Which 720 deg: ``net_imep`` closes the loop over the window it is given (the assembled cycle runs from cylinder 1's
firing TDC to the next). In a steady run any window gives the same work; while the speed or the load changes it
pairs one expansion with the *next* compression (TU/e fired -> motored transition: +0.03 bar against the -0.40
of the motored cycles). ``centred_work`` takes two consecutive cycles and integrates each cylinder over the window
centred on its own firing TDC (-360..+360 deg), i.e. a compression with the expansion that follows it.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from frictionwatch.core.model.kinematics import kinematics_kernel


@numba.njit(cache=True)
def _indicated_work(theta, pressure, params, area, out):
    """∮ p dV per row of pressure (z, n) with theta the local angle of each row's cylinder, (z, n)."""
    z, n = pressure.shape
    x = np.empty(n)
    dx = np.empty(n)
    ddx = np.empty(n)
    for k in range(z):
        kinematics_kernel(theta[k], params, x, dx, ddx)
        w = 0.0
        for i in range(n):
            j = i + 1 if i + 1 < n else 0  # closed cycle: the last sample joins the first
            w += 0.5 * (pressure[k, i] + pressure[k, j]) * area * (x[j] - x[i])
        out[k] = w


def net_imep(theta: np.ndarray, pressure: np.ndarray, phases: np.ndarray, params: np.ndarray, area: float,
             displacement: float) -> np.ndarray:
    """Net IMEP [Pa] of each cylinder.

    theta : (n,) uniform cylinder-1 crank angle grid covering one full 4 pi cycle [rad] (endpoint excluded)
    pressure : (z, n) absolute pressure [Pa]; phases : (z,) firing angles [rad]; params : [R, L, e];
    area : piston area [m^2]; displacement : swept volume of one cylinder [m^3].
    """
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    p = np.ascontiguousarray(np.atleast_2d(pressure), dtype=np.float64)
    ph = np.ascontiguousarray(np.atleast_1d(phases), dtype=np.float64)
    if p.shape != (ph.shape[0], th.shape[0]):
        raise ValueError(f"pressure must have shape (z, n) = ({ph.shape[0]}, {th.shape[0]}), got {p.shape}")
    span = th[-1] - th[0] + (th[1] - th[0])
    if not np.isclose(span, 4 * np.pi, rtol=1e-6):
        raise ValueError(f"theta must cover one 720 deg cycle without its endpoint; it spans {np.degrees(span):.3f} deg")
    if not np.all(np.isfinite(p)):
        raise ValueError("pressure has NaN or inf samples; the cycle must be skipped before IMEP")
    local = np.ascontiguousarray(th[None, :] - ph[:, None])
    out = np.empty(ph.shape[0])
    _indicated_work(local, p, np.ascontiguousarray(params, dtype=np.float64), float(area), out)
    return out / displacement


def piston_positions(theta: np.ndarray, phases: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Piston displacement from top [m] of each cylinder (z, n) at the cylinder-1 grid angles theta (n,) [rad]:
    cylinder k at its own angle theta - phases[k]. x is 4 pi periodic, so the table serves any 720 deg window."""
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    local = np.ascontiguousarray(th[None, :] - np.atleast_1d(np.asarray(phases, dtype=np.float64))[:, None])
    x = np.empty_like(local)
    _positions(local, np.ascontiguousarray(params, dtype=np.float64), x)
    return x


@numba.njit(cache=True)
def _positions(local, params, x):
    n = local.shape[1]
    dx = np.empty(n)
    ddx = np.empty(n)
    for k in range(local.shape[0]):
        kinematics_kernel(local[k], params, x[k], dx, ddx)


@numba.njit(cache=True)
def _window_works(x, previous, current, starts, alone_starts, out, out_alone):
    """Trapezoid sum of p dx (z rows) over n samples from starts[w, k] in the joined pressure [previous | current]
    (2n samples), the last sample joined to the first (a closed loop), into out (w, z); and from alone_starts[w, k]
    in [current | current] into out_alone (w', z; w' = 0: none); x (z, n) the 4 pi periodic positions. Each
    cylinder's terms (p_a + p_a+1)(x_a+1 - x_a) along the joined cycles are formed once (for [current | current]
    only the first n, the rest are [previous | current]'s), and a window's sum runs in four interleaved partial sums
    (no per-sample branch, no chain of dependent additions): the same sum as numpy's reference to rounding
    (window_works_reference, tests/core/test_indicated.py), and the same bits as two calls, one per pair."""
    z, n = x.shape
    p = np.empty(2 * n)
    xx = np.empty(2 * n)
    t = np.empty(2 * n - 1)
    for k in range(z):
        for a in range(n):  # element loops: a slice assignment compiles ten times longer
            p[a] = previous[k, a]
            p[n + a] = current[k, a]
            xx[a] = x[k, a]
            xx[n + a] = x[k, a]
        for a in range(2 * n - 1):
            t[a] = (p[a] + p[a + 1]) * (xx[a + 1] - xx[a])
        for w in range(starts.shape[0]):
            out[w, k] = _window_sum(p, xx, t, starts[w, k], n)
        if alone_starts.shape[0] == 0:
            continue
        for a in range(n):
            p[a] = current[k, a]
        for a in range(n):  # t[n - 1] joins current's last sample to its first (p[n])
            t[a] = (p[a] + p[a + 1]) * (xx[a + 1] - xx[a])
        for w in range(alone_starts.shape[0]):
            out_alone[w, k] = _window_sum(p, xx, t, alone_starts[w, k], n)


@numba.njit(cache=True)
def _window_sum(p, xx, t, s, n):
    """The closed trapezoid over the n samples from s of the joined p (2n,), xx, with their terms t (2n - 1,)."""
    e = s + n - 1  # the window's last sample (< 2n), joined to its first
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    a = s
    while a + 3 < e:
        s0 += t[a]
        s1 += t[a + 1]
        s2 += t[a + 2]
        s3 += t[a + 3]
        a += 4
    while a < e:
        s0 += t[a]
        a += 1
    return 0.5 * ((s0 + s1) + (s2 + s3) + (p[e] + p[s]) * (xx[s] - xx[e]))


def window_works(theta: np.ndarray, positions: np.ndarray, previous: np.ndarray, current: np.ndarray,
                 centres: np.ndarray, area: float) -> np.ndarray:
    """∮ p dV [J] (w, z) of each cylinder over the 720 deg windows [c - 2 pi, c + 2 pi) of the cylinder-1 angle, one
    row per row of centres (w, z) [rad] (each in [-2 pi, 2 pi], rounded to the grid: a window a fraction of a step
    off moves it around gas-exchange TDC, where p dV is smallest).

    theta : (n,) the cycles' uniform grid over [0, 4 pi) (endpoint excluded); positions : (z, n) ``piston_positions``
    on it; previous, current : (z, n) absolute pressure [Pa] of two consecutive cycles (previous spans [-4 pi, 0)).
    """
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    prev = np.ascontiguousarray(np.atleast_2d(previous), dtype=np.float64)
    cur = np.ascontiguousarray(np.atleast_2d(current), dtype=np.float64)
    c = np.atleast_2d(np.asarray(centres, dtype=np.float64))
    n = th.shape[0]
    if prev.shape != cur.shape or positions.shape != cur.shape or cur.shape[1] != n or c.shape[1] != cur.shape[0]:
        raise ValueError(f"previous, current and positions must have shape (z, n) = ({c.shape[1]}, {n}) and "
                         f"centres (w, z); got {prev.shape}, {cur.shape}, {positions.shape}, {c.shape}")
    if not math.isfinite(prev.sum() + cur.sum()):  # NaN and inf propagate into the sum
        raise ValueError("pressure has NaN or inf samples; the cycle must be skipped before IMEP")
    return works_at(np.ascontiguousarray(positions, dtype=np.float64), prev, cur, window_starts(th, c), area)


def window_starts(theta: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(w, z) int64: each window's first sample in [previous | current] (2n samples) for ``window_works``' centres
    (w, z) [rad] on the uniform grid theta (n,) (fixed by the grid: a caller with a fixed grid makes them once)."""
    n = theta.shape[0]
    step = theta[1] - theta[0]
    if abs(step * n - 4 * np.pi) > 4e-6 * np.pi or np.abs(centres).max() > 2 * np.pi + 0.5 * step:
        raise ValueError("theta must cover one 720 deg cycle and every centre lie within +-360 deg")
    # rounding may put a centre at +-360 deg half a step out
    return np.clip(np.rint((centres - 2 * np.pi - theta[0]) / step).astype(np.int64) + n, 0, n)


def works_at(positions: np.ndarray, previous: np.ndarray, current: np.ndarray, starts: np.ndarray,
             area: float) -> np.ndarray:
    """``window_works`` from the windows' first samples ``starts`` (w, z) (``window_starts``), the arrays already
    checked: positions, previous, current C-contiguous float64 (z, n), the pressures finite (as the monitor's
    checked pressure is). One kernel call."""
    out = np.empty(starts.shape)
    _window_works(positions, previous, current, starts, _NO_WINDOWS, out, _NO_WORKS)
    return out * area


def works_with_alone(positions: np.ndarray, previous: np.ndarray, current: np.ndarray, starts: np.ndarray,
                     alone_starts: np.ndarray, area: float) -> tuple[np.ndarray, np.ndarray]:
    """``works_at(positions, previous, current, starts, area)`` and ``works_at(positions, current, current,
    alone_starts, area)`` by one kernel call (the transient balance's two, the second's terms half taken from the
    first's: ~2 % of a genset-v20 cycle less), the same numbers bit for bit (tests/core/test_indicated.py)."""
    out, alone = np.empty(starts.shape), np.empty(alone_starts.shape)
    _window_works(positions, previous, current, starts, alone_starts, out, alone)
    return out * area, alone * area


_NO_WINDOWS = np.zeros((0, 0), dtype=np.int64)  # works_at's empty alone_starts (read only, never written)
_NO_WORKS = np.zeros((0, 0))


def window_works_reference(theta: np.ndarray, positions: np.ndarray, previous: np.ndarray, current: np.ndarray,
                           centres: np.ndarray, area: float) -> np.ndarray:
    """Plain numpy ``window_works`` (the kernel's reference, tests/core/test_indicated.py): each window's n samples
    of [previous | current] and their positions, closed on the first sample, integrated by the trapezoid rule."""
    n = theta.shape[0]
    step = theta[1] - theta[0]
    c = np.atleast_2d(np.asarray(centres, dtype=np.float64))
    starts = np.clip(np.rint((c - 2 * np.pi - theta[0]) / step).astype(np.int64) + n, 0, n)
    joined, x2 = np.concatenate((previous, current), axis=1), np.concatenate((positions, positions), axis=1)
    out = np.empty(c.shape)
    for w, k in np.ndindex(*c.shape):
        idx = np.arange(starts[w, k], starts[w, k] + n)
        p, x = joined[k, idx], x2[k, idx]
        out[w, k] = np.sum(0.5 * (p + np.roll(p, -1)) * (np.roll(x, -1) - x))
    return out * area


def centred_work(theta: np.ndarray, previous: np.ndarray, current: np.ndarray, phases: np.ndarray,
                 centres: np.ndarray, params: np.ndarray, area: float) -> np.ndarray:
    """∮ p dV [J] of each cylinder over the 720 deg window [c_k - 2 pi, c_k + 2 pi) of the cylinder-1 angle.

    theta : (n,) the cycles' uniform grid over [0, 4 pi) (endpoint excluded); previous, current : (z, n) absolute
    pressure [Pa] of two consecutive cycles on it (previous spans [-4 pi, 0)); phases : (z,) firing angles [rad];
    centres : (z,) window centres c_k in [-2 pi, 2 pi] [rad] (``window_works``). ``centred_work(..., phases,
    tdc_centres(phases))`` is the work of each cylinder's own latest complete firing cycle; ``centres = 0`` the
    engine's work over the window centred on cylinder 1's firing TDC.
    """
    ph = np.atleast_1d(np.asarray(phases, dtype=np.float64))
    c = np.atleast_1d(np.asarray(centres, dtype=np.float64))
    if c.shape != ph.shape:
        raise ValueError(f"centres must have shape (z,) = {ph.shape}; got {c.shape}")
    x = piston_positions(theta, ph, params)
    return window_works(theta, x, previous, current, c[None, :], area)[0]


def tdc_centres(phases: np.ndarray) -> np.ndarray:
    """Centre [rad] of each cylinder's latest firing cycle that two consecutive cycles hold whole: its firing TDC in
    the current cycle if that is at most 360 deg in, else the one a cycle earlier."""
    ph = np.mod(np.asarray(phases, dtype=np.float64), 4 * np.pi)
    return np.where(ph <= 2 * np.pi + 1e-9, ph, ph - 4 * np.pi)


@numba.njit(cache=True)
def _peak_pressure(theta, pressure, phases, pmax, angle):
    """Per row of pressure (z, n): the first maximum sample, refined by the parabola through it and its two
    periodic neighbours; writes the refined peak and its angle relative to phases[k], wrapped to [-2pi, 2pi).
    The arithmetic is that of the numpy reference (tests/core/test_peak_pressure_kernel.py)."""
    z, n = pressure.shape
    step = theta[1] - theta[0]
    for k in range(z):
        i = 0
        best = pressure[k, 0]
        if best == best:
            for j in range(1, n):  # np.argmax: the first maximum, or the first NaN
                v = pressure[k, j]
                if v > best:
                    best = v
                    i = j
                elif v != v:
                    i = j
                    break
        y0 = pressure[k, (i - 1) % n]
        y1 = pressure[k, i]
        y2 = pressure[k, (i + 1) % n]
        denom = y0 - 2 * y1 + y2
        frac = 0.5 * (y0 - y2) / denom if denom < 0 else 0.0
        ang = theta[i] + frac * step - phases[k]
        angle[k] = (ang + 2 * np.pi) % (4 * np.pi) - 2 * np.pi
        pmax[k] = y1 - 0.25 * (y0 - y2) * frac


@numba.njit(cache=True, fastmath={"reassoc"})
def _all_finite(flat):
    """Whether every sample is finite: x * 0 is 0 for a finite x and NaN for NaN or inf, so the sum is NaN iff one
    is not (reassociation only lets the sum vectorise; it cannot turn a NaN into a number)."""
    acc = 0.0
    for i in range(flat.shape[0]):
        acc += flat[i] * 0.0
    return acc == 0.0


@numba.njit(cache=True)
def _peak_pressure_finite(theta, pressure, phases, pmax, angle):
    """``_peak_pressure`` and the number of non-finite samples of pressure (z, n) (C-contiguous). The count is made
    only when ``_all_finite`` (a vectorised test) says there is something to count."""
    flat = pressure.ravel()
    bad = 0
    if not _all_finite(flat):
        for i in range(flat.shape[0]):
            if not np.isfinite(flat[i]):
                bad += 1
    _peak_pressure(theta, pressure, phases, pmax, angle)
    return bad


def peak_pressure(theta: np.ndarray, pressure: np.ndarray, phases: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Peak pressure [Pa] per cylinder and its angle [rad] relative to that cylinder's firing TDC, in [-2pi, 2pi).

    The angle is refined by a parabola through the three samples around the maximum.
    theta : (n,) uniform crank-angle grid [rad]; pressure : (z, n) [Pa] (a row with a NaN gives NaN, as with
    np.argmax); phases : (z,) firing angles [rad] (or one for every row).
    """
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    p = np.ascontiguousarray(np.atleast_2d(pressure), dtype=np.float64)
    ph = np.ascontiguousarray(phases, dtype=np.float64).ravel()
    if ph.shape[0] == 1 and p.shape[0] > 1:
        ph = np.full(p.shape[0], ph[0])
    if p.shape[1] != th.shape[0] or th.shape[0] < 2 or ph.shape[0] != p.shape[0]:
        raise ValueError(f"pressure (z, n) needs n = {th.shape[0]} grid angles and z phases, got {p.shape} and "
                         f"{ph.shape[0]} phases")
    pmax = np.empty(p.shape[0])
    angle = np.empty(p.shape[0])
    _peak_pressure(th, p, ph, pmax, angle)
    return pmax, angle
