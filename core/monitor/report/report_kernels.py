"""Numba kernels of the result's traces and speed series (core.monitor.report.cycle_report): the per-cylinder friction traces on the
crank-angle grid (report_traces), and the speed residual, the ripple power and both inverse series on the time grid in
one call (speed_series), with the cosine/sine tables of the grid built once per (M, n_t) and kept by the caller
(core.monitor.state.MonitorState.report_tables).

The plain-numpy reference (speed_residual + speed_power + harmonic_series by irfft) is in
tests/core/test_report_kernels.py. The direct sums differ from the inverse FFT by rounding only (~1e-16 of the
speed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np


@dataclass(frozen=True)
class TrigTables:
    """table (2, m, n): cos and sin of 2 pi (h k mod n) / n for harmonics h = 1..m and samples k = 0..n-1
    (harmonic_series' convention: x_k = sum_h Re(X_h exp(i 2 pi h k / n)))."""

    table: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        """(m harmonics, n samples)."""
        return self.table.shape[1:]


def trig_tables(m: int, n: int) -> TrigTables:
    """The tables for m harmonics on n samples (read-only arrays)."""
    h = np.arange(1, m + 1)[:, None]
    k = np.arange(n)[None, :]
    ang = (2.0 * np.pi / n) * ((h * k) % n)
    table = np.stack([np.cos(ang), np.sin(ang)])
    table.flags.writeable = False
    return TrigTables(table)


@numba.njit(cache=True)
def abs2(z):
    """|z|^2 of a complex number (hypot, then the square)."""
    v = math.hypot(z.real, z.imag)
    return v * v


@numba.njit(cache=True)
def residual_into(design, target, params, out):
    """out (M,) = target - design @ params for complex design (M, P) and real params (P,), real and imaginary parts
    summed over P in order."""
    m, p = design.shape
    for i in range(m):
        sr = 0.0
        si = 0.0
        for j in range(p):
            sr += design[i, j].real * params[j]
            si += design[i, j].imag * params[j]
        out[i] = complex(target[i].real - sr, target[i].imag - si)


@numba.njit(cache=True)
def speed_series(design, target, params, p_f, drift, use_drift, freq, harmonics, omega_fly, table, resid,
                 extra):
    """Residual harmonics resid (M,) complex (measured - model, this cycle's best-fitting drift taken out if
    ``use_drift``), extra[0] = measured speed omega_fly (n_t,) minus the fitted tooth-pattern part
    design[:, p_f:] @ params[p_f:] and extra[1] = that minus the residual (the model speed), both on the time
    grid; table (2, M, n_t): ``TrigTables.table``. Returns (sum |resid|^2, sum |i freq harmonics|^2)."""
    m = design.shape[0]
    series = np.empty((2, m), dtype=np.complex128)
    resid_sq = speed_residual(design, target, params, p_f, drift, use_drift, series)
    power = speed_power(freq, harmonics)
    n = omega_fly.shape[0]
    pat = np.zeros(n)
    res = np.zeros(n)
    for h in range(m):
        pr = series[0, h].real
        pi = series[0, h].imag
        rr = series[1, h].real
        ri = series[1, h].imag
        for k in range(n):
            c = table[0, h, k]
            s = table[1, h, k]
            pat[k] += pr * c - pi * s
            res[k] += rr * c - ri * s
    for h in range(m):
        resid[h] = series[1, h]
    for k in range(n):
        v = omega_fly[k] - pat[k]
        extra[0, k] = v
        extra[1, k] = v - res[k]
    return resid_sq, power


# ---- the result's traces (core.monitor.report.cycle_report) -----------------------------------------------------------------


@numba.njit(cache=True)
def speed_residual(design, target, params, p_f, drift, use_drift, out):
    """out[0] = the tooth-pattern part design[:, p_f:] @ params[p_f:], out[1] = target - design @ params with the
    best-fitting drift (if used) taken out; returns sum |resid|^2."""
    m, p = design.shape
    residual_into(design, target, params, out[1])
    for i in range(m):
        pr = 0.0
        pi = 0.0
        for j in range(p_f, p):
            pr += design[i, j].real * params[j]
            pi += design[i, j].imag * params[j]
        out[0, i] = complex(pr, pi)
    if use_drift:
        dd = 0.0
        dr = 0.0
        for i in range(m):
            dd += drift[i].real * drift[i].real + drift[i].imag * drift[i].imag
            dr += drift[i].real * out[1, i].real + drift[i].imag * out[1, i].imag
        if dd > 0:
            f = dr / dd
            for i in range(m):
                out[1, i] = out[1, i] - drift[i] * f
    sq = np.empty(m)
    for i in range(m):
        sq[i] = abs2(out[1, i])
    return np.sum(sq)


@numba.njit(cache=True)
def speed_power(freq, harmonics):
    """np.sum(np.abs(1j * freq * harmonics) ** 2)."""
    m = freq.shape[0]
    sq = np.empty(m)
    for i in range(m):
        h = harmonics[i]
        sq[i] = abs2(complex(0.0 * h.real - freq[i] * h.imag, 0.0 * h.imag + freq[i] * h.real))
    return np.sum(sq)


@numba.njit(cache=True)
def _grid_brackets(grid, theta):
    """The brackets of the crank-angle ``grid`` (ng,) in the flywheel angles ``theta`` (n,) of the time samples
    (periodic in 4 pi: theta spans one cycle from the first edge), as np.interp finds them.

    Returns (js, dxs, special, n_special, dxp): grid point i lies dxs[i] after theta[js[i]]; ``special`` marks the
    points that np.interp puts on y0 (an exact hit on theta[0] or outside the period); dxp (n,) the bracket widths
    (the last one wraps to theta[0] + 4 pi). One forward walk over the sorted angles (restarted where the grid wraps
    past theta[0] + 4 pi); a theta that is not increasing falls back to bisection."""
    n = theta.shape[0]
    four_pi = 4.0 * np.pi
    th0 = theta[0]
    x_end = th0 + four_pi
    increasing = True
    for t in range(1, n):
        if not theta[t] >= theta[t - 1]:
            increasing = False
    ng = grid.shape[0]
    js = np.empty(ng, dtype=np.int64)
    dxs = np.empty(ng)
    special = np.zeros(ng, dtype=np.bool_)
    n_special = 0
    lo = 0
    prev_x = -np.inf
    for i in range(ng):
        x = grid[i] - th0
        if x > 0.0 and x < four_pi:  # Python's float % is the identity here
            x = th0 + x
        else:
            x = th0 + x % four_pi
        if x >= x_end or x <= th0:  # an exact hit on theta[0] or outside: y0 (through dx = 0, dxp = 1)
            js[i] = 0
            dxs[i] = 0.0
            special[i] = True
            n_special += 1
            continue
        if increasing:
            if x < prev_x:
                lo = 0
            prev_x = x
            while lo + 1 < n and theta[lo + 1] <= x:  # the largest lo with theta[lo] <= x
                lo += 1
        else:
            lo = 0
            hi = n
            while hi - lo > 1:  # theta[lo] <= x < theta[hi] (theta[n] = x_end)
                mid = (lo + hi) >> 1
                if theta[mid] <= x:
                    lo = mid
                else:
                    hi = mid
        js[i] = lo
        dxs[i] = x - theta[lo]
    dxp = np.empty(n)
    for t in range(n - 1):
        dxp[t] = theta[t + 1] - theta[t]
    dxp[n - 1] = x_end - theta[n - 1]
    return js, dxs, special, n_special, dxp


@numba.njit(cache=True)
def _interp_rows(vals, js, dxs, special, n_special, dxp, out):
    """out (r, ng) = every row of vals (r, n) at the grid brackets of ``_grid_brackets``, as np.interp does.

    np.interp's arithmetic is (y1 - y0) / dxp * dx + y0 with dxp the width of the bracket: the quotient depends on
    the bracket only, so it is formed once per bracket and row (n divisions per row instead of one per grid
    point), bit for bit the same numbers."""
    rows, n = vals.shape
    ng = js.shape[0]
    slope = np.empty((rows, n))
    for k in range(rows):
        for t in range(n - 1):
            slope[k, t] = (vals[k, t + 1] - vals[k, t]) / dxp[t]
        slope[k, n - 1] = (vals[k, 0] - vals[k, n - 1]) / dxp[n - 1]
    # four rows per sweep: the bracket index and offset of a grid point are loaded once for all four
    k = 0
    while k < rows:
        if k + 4 <= rows:
            o0, o1, o2, o3 = out[k], out[k + 1], out[k + 2], out[k + 3]
            v0, v1, v2, v3 = vals[k], vals[k + 1], vals[k + 2], vals[k + 3]
            s0, s1, s2, s3 = slope[k], slope[k + 1], slope[k + 2], slope[k + 3]
            for i in range(ng):
                j = js[i]
                d = dxs[i]
                o0[i] = s0[j] * d + v0[j]
                o1[i] = s1[j] * d + v1[j]
                o2[i] = s2[j] * d + v2[j]
                o3[i] = s3[j] * d + v3[j]
            k += 4
        else:
            o = out[k]
            v = vals[k]
            s = slope[k]
            for i in range(ng):
                j = js[i]
                o[i] = s[j] * dxs[i] + v[j]
            k += 1
    if n_special:
        for k in range(rows):
            o = out[k]
            y0 = vals[k, 0]
            for i in range(ng):
                if special[i]:
                    o[i] = (y0 - y0) / 1.0 * 0.0 + y0


@numba.njit(cache=True)
def report_traces(grid, theta, coef, basis_terms, extra, cyl_time, out):
    """The friction traces of one cycle: per cylinder sum_l coef[k, l] basis_terms[l, k, :] on the time grid into
    cyl_time (z, n_t) (kept in the result; onto the crank-angle grid only when asked for, ``rows_on_grid``), and onto
    the crank-angle ``grid`` (ng,): out[0] = their sum over cylinders, out[1:] = the rows ``extra`` (r, n_t); all
    sampled at the flywheel angles ``theta`` (n_t,) (periodic in 4 pi: theta spans one cycle from the first edge),
    interpolated as np.interp does. The engine total is summed on the time grid (interpolation is linear: the sum of
    the per-cylinder grid traces up to rounding). basis_terms (L, z, n_t) is the term-major block the balance fills
    (C order on every engine: Excitation.basis is its (z, L, n_t) view, C order on one cylinder only, and each
    layout was another compiled specialisation, ~1.5 s of cold compile)."""
    n_terms, z, n = basis_terms.shape
    r = extra.shape[0]
    vals = np.empty((1 + r, n))  # the rows to interpolate: engine total, then the extra rows
    for k in range(z):
        row = cyl_time[k]
        for t in range(n):
            row[t] = coef[k, 0] * basis_terms[0, k, t]
        for term in range(1, n_terms):
            c = coef[k, term]
            for t in range(n):
                row[t] += c * basis_terms[term, k, t]
    for t in range(n):
        vals[0, t] = cyl_time[0, t]
    for k in range(1, z):
        for t in range(n):
            vals[0, t] += cyl_time[k, t]
    for k in range(r):
        for t in range(n):
            vals[1 + k, t] = extra[k, t]
    js, dxs, special, n_special, dxp = _grid_brackets(grid, theta)
    _interp_rows(vals, js, dxs, special, n_special, dxp, out)


@numba.njit(cache=True)
def rows_on_grid(grid, theta, vals, out):
    """out (r, ng) = the rows vals (r, n_t), sampled at the flywheel angles ``theta``, on the crank-angle ``grid``
    (periodic in 4 pi), exactly as ``report_traces`` puts its rows there."""
    js, dxs, special, n_special, dxp = _grid_brackets(grid, theta)
    _interp_rows(vals, js, dxs, special, n_special, dxp, out)
