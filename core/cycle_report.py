"""Assemble the ``CycleResult`` of one cycle: traces on the crank-angle grid, measured vs model speed, residuals."""

from __future__ import annotations

import numpy as np

from core.dynamics import rigid_friction_torque
from core.engine import EngineSpec
from core.excitation import Excitation
from core.excitation_kernels import interp_rows_periodic
from core.flywheel import FlywheelMotion, harmonic_series, harmonics_of
from core.identify import CycleRows, ParameterLayout
from core.results import CycleResult, FrictionEstimate
from core.types import Cycle

FOUR_PI = 4.0 * np.pi


def build_result(spec: EngineSpec, cycle: Cycle, fly: FlywheelMotion, exc: Excitation, rows: CycleRows,
                 theta: np.ndarray, layout: ParameterLayout, drift: np.ndarray | None, load: float, balance: float,
                 coupling_loss: float, pmax: np.ndarray, pmax_angle: np.ndarray, est_c: FrictionEstimate,
                 est_s: FrictionEstimate, flags: list[str]) -> CycleResult:
    """theta: smoothed [friction scales, tooth nuisances]; drift (M,) complex: this cycle's drift shape in speed
    harmonics (its best fit is taken out of the reported residual, as it is out of the noise statistics)."""
    grid = cycle.grid
    n_t = exc.tau.shape[0]
    p_f = layout.n_params
    coef = layout.coefficients(theta[:p_f])
    per_cyl_t = np.einsum("kl,klt->kt", coef, exc.basis)
    if exc.omega_fly is not None and exc.alpha_fly is not None:
        omega_meas, alpha_meas = exc.omega_fly, exc.alpha_fly
    else:
        _, _, omega_meas, alpha_meas = fly.on_grid(n_t)
    resid = rows.target - rows.design @ theta
    if drift is not None and np.vdot(drift, drift).real > 0:
        resid = resid - drift * (np.vdot(drift, resid).real / np.vdot(drift, drift).real)
    # show the measured speed with the estimated tooth-spacing pattern taken out; the model without it
    # (both series from one inverse FFT)
    pattern, resid_t = harmonic_series(np.stack([rows.design[:, p_f:] @ theta[p_f:], resid]), n_t)
    omega_meas = omega_meas - pattern
    model_t = omega_meas - resid_t
    power = float(np.sum(np.abs(fly.speed_harmonics) ** 2))
    r2 = 1.0 - float(np.sum(np.abs(resid) ** 2)) / power if power > 0 else float("nan")
    time_rows = [per_cyl_t, omega_meas[None], model_t[None]]
    if spec.n_nodes == 1:  # direct rigid balance (paper 001 Eq. 26), low-passed to the identification band
        tl = load * (omega_meas / fly.omega_mean) ** spec.load.exponent if spec.load.kind != "grid" else load
        direct = rigid_friction_torque(exc.theta_fly, omega_meas, alpha_meas, exc.gas.sum(axis=0), tl, spec)
        low = harmonic_series(harmonics_of(direct, fly.n_harmonics), n_t, float(direct.mean()))
        time_rows.append(low[None])
    # every trace onto the crank-angle grid in one pass (one bracket search per grid point)
    on_grid = to_grid(grid, exc.theta_fly, np.concatenate(time_rows))
    z = per_cyl_t.shape[0]
    per_cyl = on_grid[:z]
    speed_meas, speed_model = on_grid[z], on_grid[z + 1]
    balance_trace = on_grid[z + 2] if spec.n_nodes == 1 else None
    return CycleResult(
        index=cycle.index, t_start=cycle.t_start, rpm_mean=fly.omega_mean * 60.0 / (2.0 * np.pi),
        omega_mean=fly.omega_mean, load_torque=float(load), load_power=float(cycle.load_power),
        imep=exc.indicated_mean * FOUR_PI / spec.displacement_cyl, pmax=pmax, pmax_angle=pmax_angle,
        indicated_torque=exc.indicated_mean, friction_balance=float(balance), coupling_loss=float(coupling_loss),
        cycle=est_c, smoothed=est_s, grid=grid.copy(), friction_torque=per_cyl.sum(axis=0),
        friction_torque_cyl=per_cyl, speed_measured=speed_meas, speed_model=speed_model,
        residual_harmonics=resid, residual_rms=float(np.sqrt(0.5 * np.sum(np.abs(resid) ** 2))), r_squared=r2,
        friction_torque_balance=balance_trace, flags=tuple(flags))


def to_grid(grid: np.ndarray, theta: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Rows ``values`` (r, n_t) sampled at the increasing flywheel angles ``theta`` of the time grid, onto the
    crank-angle ``grid`` (periodic in 4 pi: theta spans one cycle from the first tooth edge)."""
    x = np.append(theta, theta[0] + FOUR_PI)
    u = theta[0] + np.mod(grid - theta[0], FOUR_PI)
    return interp_rows_periodic(u, x, values)
