"""The measurements behind the sensor-health stage (core.monitor.checks.sensor_health), one cycle each: the sibling
comparison of the compression stroke (pressure gain and pegging) and the speed-harmonic sensitivity to each
cylinder's TDC with its normal equations once the friction, tooth-error and gain columns are eliminated."""

from __future__ import annotations

import math

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.kinematics import kinematics
from frictionwatch.core.monitor.balance.harmonic_balance import OperatingPoint
from frictionwatch.core.monitor.teeth.flywheel import harmonics_of

FOUR_PI = 4.0 * np.pi
STEP_DEG = 1.0  # compression-window sampling
SHIFT_STEP = math.radians(0.1)  # central difference of the torques in Delta


def compression_angles(spec: EngineSpec, window_deg: tuple[float, float]) -> np.ndarray:
    """(L,) rad from firing TDC: the samples of the sibling comparison's compression window (its end kept 8 deg
    before the start of combustion)."""
    end = min(window_deg[1], spec.combustion.start_deg - 8.0)
    return np.radians(np.arange(window_deg[0], end + 1e-9, STEP_DEG))


def sibling_compare(spec: EngineSpec, grid: np.ndarray, pressure: np.ndarray, window_deg: tuple[float, float],
                    lead: np.ndarray) -> np.ndarray:
    """This cycle's (2, z) [gain - 1, offset Pa] of each cylinder against the median of its siblings over the
    compression window (NaN below three cylinders: two cannot say which one is off); lead (z,) rad: how far each
    piston is ahead of the flywheel angle the pressure is sampled at (the model's static twist minus the TDC
    correction in use), so that the traces are compared at the same piston position; or (z, L), at each of the
    window's samples (``compression_angles``: the twist's harmonics too)."""
    z, n = pressure.shape
    if z < 3:
        return np.full((2, z), np.nan)
    w = compression_angles(spec, window_deg)
    x, _, _ = kinematics(w, spec.kinematics_params())
    log_v = np.log((spec.clearance_volume + spec.piston_area * x) / spec.clearance_volume)
    log_v -= log_v.mean()
    tr0 = _window(grid, pressure, spec.firing_angles, w, -lead)
    gain, offset, expo = np.ones(z), np.zeros(z), np.zeros(z)
    for _ in range(2):  # Gauss-Newton: the second pass on the traces corrected by the first
        tr = (tr0 - offset[:, None]) / (gain[:, None] * np.exp(expo[:, None] * log_v))
        ref = np.median(tr, axis=0)
        cols = np.stack([ref, np.ones_like(w), ref * log_v], axis=1)
        a, o, b = np.linalg.lstsq(cols, (tr - ref).T, rcond=None)[0]  # tr = (1 + a) ref V^-b + o, linearised
        offset, gain, expo = offset + gain * o, gain * (1.0 + a), expo + b
    return np.stack([gain / np.median(gain) - 1.0, offset - np.median(offset)])


def _window(grid: np.ndarray, pressure: np.ndarray, phases: np.ndarray, w: np.ndarray,
            shift: np.ndarray) -> np.ndarray:
    """(z, L) pressure of each cylinder at its local angles w (+ its own ``shift``, (z,) or (z, L)), linear on the
    uniform grid."""
    z, n = pressure.shape
    h = FOUR_PI / n
    shift = np.reshape(shift, (z, -1))
    u = np.mod(w[None, :] + phases[:, None] + shift - grid[0], FOUR_PI) / h
    i0 = np.floor(u).astype(np.int64)
    f = u - i0
    rows = np.arange(z)[:, None]
    return pressure[rows, i0 % n] * (1.0 - f) + pressure[rows, (i0 + 1) % n] * f


def tdc_information(sens: np.ndarray, residual: np.ndarray, sigma: np.ndarray, design: np.ndarray,
                    prior_info: np.ndarray, gain_cols: np.ndarray, gain_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """This cycle's normal equations (z, z), (z,) of each cylinder's kinematic shift [rad] beyond the one in use,
    from the speed residual (M,) along its column of ``sens`` (M, z), with the friction and tooth columns ``design``
    (M, P) under their prior ``prior_info`` (whitened units) and each cylinder's pressure-gain column ``gain_cols``
    (M, z) under a prior of ``gain_sigma`` eliminated (Schur complement): a friction estimate that absorbed some of a
    TDC error must not hide it, nor a friction misfit or a gain error read as TDC."""
    inv = np.concatenate([1.0 / sigma, 1.0 / sigma])
    p = design.shape[1]
    z = gain_cols.shape[1]
    design = np.concatenate([design, gain_cols], axis=1)
    prior_info = np.pad(prior_info[:p, :p], ((0, z), (0, z))) + np.diag(np.r_[np.zeros(p), np.full(z, gain_sigma**-2)])
    d = np.concatenate([design.real, design.imag]) * inv[:, None]
    s = np.concatenate([sens.real, sens.imag]) * inv[:, None]
    rr = np.concatenate([residual.real, residual.imag]) * inv
    k = d.T @ d + prior_info
    sol = np.linalg.solve(k, np.concatenate([d.T @ s, (d.T @ rr)[:, None]], axis=1))  # K^-1 [D'S, D'r]
    ds = d.T @ s
    return s.T @ s - ds.T @ sol[:, :-1], s.T @ rr - ds.T @ sol[:, -1]


def speed_sensitivity(op: OperatingPoint, grid: np.ndarray, pressure: np.ndarray, theta_fly: np.ndarray,
                      omega: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Speed harmonics (M, z) complex per rad of a kinematic shift of each cylinder, its work-mean indicated torque
    per rad (z,) [N m/rad], and the speed harmonics (M, z) per unit relative pressure gain (its gas torque), from the
    (corrected) pressure on the harmonic balance's time samples."""
    cyl = op.cylinders
    z = cyl.phase.shape[0]
    n = pressure.shape[1]
    u = np.mod(theta_fly - grid[0], FOUR_PI) / (FOUR_PI / n)
    i0 = np.floor(u).astype(np.int64)
    f = u - i0
    p = pressure[:, i0 % n] * (1.0 - f) + pressure[:, (i0 + 1) % n] * f - cyl.p_crankcase  # (z, n_t)
    params = np.array([cyl.crank_radius, 1.0 / cyl.inv_rod, cyl.pin_offset])
    gas, mass = [], []
    for h in (SHIFT_STEP, -SHIFT_STEP):
        _, dx, ddx = kinematics((theta_fly[None, :] - cyl.phase[:, None] - h).ravel(), params)
        dx, ddx = dx.reshape(z, -1), ddx.reshape(z, -1)
        gas.append(cyl.area * p * dx)
        mass.append(-cyl.m_rec * dx * (ddx * omega**2 + dx * alpha) if cyl.variable_inertia else 0.0 * dx)
    d_gas = (gas[0] - gas[1]) / (2.0 * SHIFT_STEP)  # (z, n_t)
    harm = harmonics_of(d_gas + (mass[0] - mass[1]) / (2.0 * SHIFT_STEP), op.transfer.shape[0])  # (z, M)
    sens = op.transfer[:, cyl.node] * harm.T  # through the chain from each cylinder's own throw
    gain = op.transfer[:, cyl.node] * harmonics_of(0.5 * (gas[0] + gas[1]), op.transfer.shape[0]).T
    return sens, np.mean(d_gas * omega, axis=1) / np.mean(omega), gain  # work mean: the mass torque has none
