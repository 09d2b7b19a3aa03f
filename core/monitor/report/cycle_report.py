"""Assemble the ``CycleResult`` of one cycle: traces on the crank-angle grid, measured vs model speed, residuals.

Periodic row interpolation: ``interp_rows_periodic`` (numba ``_interp_rows``) is np.interp for many rows at once
on one closed period (its numpy reference, np.interp row by row: tests/core/test_interp_rows_periodic.py).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
from frictionwatch.core.model.dynamics import rigid_friction_torque
from frictionwatch.core.model.engine import EngineSpec, mep_per_torque
from frictionwatch.core.monitor.balance.excitation import Excitation
from frictionwatch.core.monitor.balance.mean_balance import MeanBalance
from frictionwatch.core.monitor.identify.identification import Identification
from frictionwatch.core.monitor.identify.parameters import CycleRows, ParameterLayout
from frictionwatch.core.monitor.report.report_kernels import TrigTables, report_traces, speed_series
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.core.monitor.teeth.flywheel import FlywheelMotion, harmonic_series, harmonics_of
from frictionwatch.core.types import Cycle


@numba.njit(cache=True)
def _interp_rows(xq, xp, fp, out):
    """np.interp of every row of fp (r, n) at xq (m,), with xp (n + 1,) increasing and fp's value at xp[n] equal to
    its first column (one period closed). The bracket is searched once per query and used for all rows; the
    arithmetic is np.interp's: slope (fp[j+1] - fp[j]) / (xp[j+1] - xp[j]) times (x - xp[j]) plus fp[j]."""
    n = xp.shape[0] - 1
    rows = fp.shape[0]
    for i in range(xq.shape[0]):
        x = xq[i]
        if x >= xp[n]:
            for k in range(rows):
                out[k, i] = fp[k, 0]
            continue
        if x <= xp[0]:
            for k in range(rows):
                out[k, i] = fp[k, 0]
            continue
        lo = 0
        hi = n
        while hi - lo > 1:  # xp[lo] <= x < xp[hi]
            mid = (lo + hi) >> 1
            if xp[mid] <= x:
                lo = mid
            else:
                hi = mid
        j = lo
        if x == xp[j]:
            for k in range(rows):
                out[k, i] = fp[k, j]
            continue
        dxp = xp[j + 1] - xp[j]
        for k in range(rows):
            y0 = fp[k, j]
            y1 = fp[k, j + 1] if j + 1 < n else fp[k, 0]
            out[k, i] = (y1 - y0) / dxp * (x - xp[j]) + y0


def interp_rows_periodic(xq: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """Rows fp (r, n), sampled at xp (n + 1,) increasing with fp[:, 0] repeated at xp[n], at queries xq (m,).

    Same numbers as ``np.interp(xq, xp, np.append(row, row[0]))`` for each row."""
    q = np.ascontiguousarray(xq, dtype=np.float64)
    x = np.ascontiguousarray(xp, dtype=np.float64)
    f = np.ascontiguousarray(np.atleast_2d(fp), dtype=np.float64)
    if x.ndim != 1 or f.shape[1] + 1 != x.shape[0] or f.shape[1] < 1:
        raise ValueError(f"xp must have one point more than the rows of fp, got {x.shape} and {f.shape}")
    if np.any(np.diff(x) <= 0):
        raise ValueError("xp must be strictly increasing")
    out = np.empty((f.shape[0], q.shape[0]))
    _interp_rows(q, x, f, out)
    return out


FOUR_PI = 4.0 * np.pi


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
    # pattern taken out and the model speed (core.monitor.report.report_kernels: one kernel, direct sums for the inverse series)
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


def to_grid(grid: np.ndarray, theta: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Rows ``values`` (r, n_t) sampled at the increasing flywheel angles ``theta`` of the time grid, onto the
    crank-angle ``grid`` (periodic in 4 pi: theta spans one cycle from the first tooth edge)."""
    x = np.append(theta, theta[0] + FOUR_PI)
    u = theta[0] + np.mod(grid - theta[0], FOUR_PI)
    return interp_rows_periodic(u, x, values)
