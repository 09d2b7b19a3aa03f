"""Assemble the ``CycleResult`` of one cycle: traces on the crank-angle grid, measured vs model speed, residuals.

The report's kernels, at the top of this file (from report_kernels.py, design note 87): the speed residual, the ripple
power and both inverse series on the time grid in one call (speed_series), with the cosine/sine tables of the grid
built once per (M, n_t) (trig_tables, kept in core.monitor.state.MonitorState.report_tables), and the per-cylinder
friction traces (report_traces, onto the crank-angle grid by core.monitor.report.grid_rows). The plain-numpy
reference of speed_series (speed_residual + speed_power + harmonic_series by irfft) is in
tests/core/test_report_kernels.py: the direct sums differ from the inverse FFT by rounding only (~1e-16 of the speed).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
from frictionwatch.core.model.dynamics import rigid_friction_torque
from frictionwatch.core.model.engine import EngineSpec, mep_per_torque
from frictionwatch.core.monitor.balance.excitation import Excitation
from frictionwatch.core.monitor.balance.mean_balance import MeanBalance
from frictionwatch.core.monitor.identify.identification import Identification
from frictionwatch.core.monitor.identify.parameters import CycleRows, ParameterLayout
from frictionwatch.core.monitor.report.grid_rows import grid_brackets, interp_bracketed_rows
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.core.monitor.state import TrigTables
from frictionwatch.core.monitor.teeth.flywheel import FlywheelMotion, harmonic_series, harmonics_of
from frictionwatch.core.types import Cycle


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
    js, dxs, special, n_special, dxp = grid_brackets(grid, theta)
    interp_bracketed_rows(vals, js, dxs, special, n_special, dxp, out)


class StageReport(NamedTuple):
    """What the monitor's other stages put in a cycle's result: ``flags`` so far; ``speed_fit_poor`` after them where
    the fit's R^2 is below ``r_squared_floor`` (NaN, no ripple: not added), then ``later_flags``; ``fields``: their
    ``CycleResult`` fields by name (the checks' reports, the free end)."""

    flags: list[str]
    r_squared_floor: float
    later_flags: tuple[str, ...]
    fields: dict


def build_result(spec: EngineSpec, cycle: Cycle, fly: FlywheelMotion, exc: Excitation, rows: CycleRows,
                 layout: ParameterLayout, ident: Identification, mean: MeanBalance, pmax: np.ndarray,
                 pmax_angle: np.ndarray, tables: TrigTables, stages: StageReport) -> CycleResult:
    """The result of one cycle from its stages. The traces use the smoothed parameters [friction scales, tooth
    nuisances]; this cycle's drift (``ident.drift_col``) has its best fit taken out of the reported residual, as
    it is out of the noise statistics; tables: ``trig_tables(M, n_t)`` of the harmonic-balance time grid.
    ``stages``: what the other stages add (``StageReport``), set in the one construction (a ``dataclasses.replace``
    after it built the ~40-field result again)."""
    grid = np.ascontiguousarray(cycle.grid, dtype=np.float64)
    n_t = exc.tau.shape[0]
    p_f = layout.n_params
    params = np.ascontiguousarray(ident.smoothed.params, dtype=np.float64)
    coef = layout.coefficients(params[:p_f])
    drift = ident.drift_col
    load = mean.load
    if exc.omega_fly is not None and exc.alpha_fly is not None:
        omega_meas, alpha_meas = exc.omega_fly, exc.alpha_fly
    else:
        _, _, omega_meas, alpha_meas = fly.on_grid(n_t)
    # the tooth-pattern part of the model and the residual (without this cycle's best-fitting drift, as in the
    # noise statistics), the ripple power, and on the time grid the measured speed with the estimated tooth-spacing
    # pattern taken out and the model speed (speed_series above: one kernel, direct sums for the inverse series)
    m = rows.target.shape[0]
    use_drift = drift is not None
    resid = np.empty(m, dtype=np.complex128)
    extra = np.empty((3 if spec.n_nodes == 1 else 2, n_t))
    resid_sq, power = speed_series(
        _c128(rows.design), _c128(rows.target), params, p_f, _c128(drift if use_drift else rows.target), use_drift,
        ident.freq, _c128(fly.harmonics), np.ascontiguousarray(omega_meas, dtype=np.float64), tables.table, resid,
        extra)
    omega_meas = extra[0]
    r2 = 1.0 - resid_sq / power if power > 0 else float("nan")
    if spec.n_nodes == 1:  # direct rigid balance (paper 001 Eq. 26), low-passed to the identification band
        tl = load * (omega_meas / fly.omega_mean) ** spec.load.exponent if spec.load.kind != "grid" else load
        direct = rigid_friction_torque(exc.theta_fly, omega_meas, alpha_meas, exc.gas.sum(axis=0), tl, spec)
        extra[2] = harmonic_series(harmonics_of(direct, fly.n_harmonics), n_t, float(direct.mean()))
    # the traces onto the crank-angle grid in one pass (one bracket search per grid point); the per-cylinder
    # friction stays on the time grid until asked for (CycleResult.friction_torque_cyl)
    z = coef.shape[0]
    cyl_time = np.empty((z, n_t))
    on_grid = np.empty((1 + extra.shape[0], grid.shape[0]))
    theta_fly = np.ascontiguousarray(exc.theta_fly, dtype=np.float64)
    # exc.basis (z, L, n_t) is a view of the term-major block the balance filled: that block read in place (a C-order
    # copy would move the whole basis every cycle)
    report_traces(grid, theta_fly, coef, exc.basis.transpose(1, 0, 2), extra, cyl_time, on_grid)
    total = on_grid[0]
    speed_meas, speed_model = on_grid[1], on_grid[2]
    balance_trace = on_grid[3] if spec.n_nodes == 1 else None
    fit_flags = ("speed_fit_poor",) if r2 < stages.r_squared_floor else ()  # NaN (no ripple): no flag
    return CycleResult(
        **stages.fields, index=cycle.index, t_start=cycle.t_start, rpm_mean=fly.omega_mean * 60.0 / (2.0 * np.pi),
        omega_mean=fly.omega_mean, load_torque=float(load), load_power=float(cycle.load_power),
        imep=(exc.indicated_mean * mep_per_torque(spec.displacement_cyl) if mean.imep_centred is None else
              mean.imep_centred),
        pmax=pmax, pmax_angle=pmax_angle, indicated_torque=exc.indicated_mean,
        displacement_cyl=float(spec.displacement_cyl), friction_balance=float(mean.friction),
        coupling_loss=float(mean.coupling_loss), cycle=ident.cycle_estimate, smoothed=ident.smoothed_estimate,
        grid=grid.copy(), friction_torque=total,
        friction_torque_cyl_time=cyl_time, time_angles=theta_fly, speed_measured=speed_meas,
        speed_model=speed_model,
        residual_harmonics=resid, residual_rms=float(np.sqrt(0.5 * resid_sq)), r_squared=r2,
        friction_torque_balance=balance_trace, flags=(*stages.flags, *fit_flags, *stages.later_flags),
        acceleration=float(mean.acceleration), indicated_window=float(mean.indicated_window))


def _c128(a: np.ndarray) -> np.ndarray:
    if type(a) is np.ndarray and a.dtype == np.complex128 and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=np.complex128)
