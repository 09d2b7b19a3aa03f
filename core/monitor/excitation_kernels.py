"""Constants of the per-cycle excitation (core.monitor.excitation) and periodic row interpolation.

``excitation_consts`` bundles what the excitation kernel needs from the spec (the slider-crank kinematics, gas
torque, reciprocating remainder and six friction basis terms of core.model.torques / core.model.friction: paper 000 Eq. 4,
physics.md §2-§3, §7, §12.3); the kernel that evaluates them is core.monitor.harmonic_balance_kernels._cycle_rows, run
inside core.monitor.balance_pass_kernel. ``interp_rows_periodic`` (numba ``_interp_rows``) is np.interp for many rows at
once on one closed period (core.monitor.cycle_report). The earlier fused kernel ``_excitation_rows`` is a test reference now
(tests/core/excitation_reference.py, tested against core.model.torques / core.model.friction in test_excitation_kernels.py).

Layout of ``consts`` (``excitation_consts``):
  0-2 kinematics [R, L, e]; 3-16 friction params (EngineSpec.friction_params()); 17 piston area [m^2];
  18 crankcase pressure [Pa]; 19 reciprocating mass [kg]; 20 mean reciprocating inertia of one cylinder [kg m^2];
  21 variable inertia (1.0) or not (0.0); 22 mean speed Omega [rad/s] (work means); 23.. firing angles [rad]
"""

from __future__ import annotations

import numba
import numpy as np

FOUR_PI = 4.0 * np.pi
N_CONSTS = 23
OMEGA_SLOT = 22


def excitation_consts(kin: np.ndarray, fric: np.ndarray, area: float, p_cc: float, m_rec: float,
                      recip_inertia_mean: float, variable_inertia: bool, omega_mean: float,
                      phases: np.ndarray) -> np.ndarray:
    """Bundle the constants of the excitation kernel (``_cycle_rows``; layout in the module docstring)."""
    ph = np.asarray(phases, dtype=np.float64).ravel()
    out = np.empty(N_CONSTS + ph.shape[0])
    out[0:3] = kin
    out[3:17] = fric
    out[17:N_CONSTS] = (area, p_cc, m_rec, recip_inertia_mean, 1.0 if variable_inertia else 0.0, omega_mean)
    out[N_CONSTS:] = ph
    return out


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
