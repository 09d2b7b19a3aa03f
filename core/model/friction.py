"""The six Rezeka-Henein friction basis terms F_l(theta) of one cylinder (paper 000 Eq. 4; physics.md §7).

T_f,k(theta) = sum_l a_kl F_kl(theta), every F >= 0. Inputs are the cylinder's own local angle theta_k (0 = its firing
TDC), the speed at its throw omega_k and its gauge pressure p_k = max(p - p_cc, 0).

  l  term                          F_l
  1  ring viscous                  sqrt(mu |c| (P_e + p) e) * pi D (n_o + 0.4 n_c) * |x'|
  2  ring mixed lubrication        pi D n_c (P_e + p)(1 - |sin theta|) |x'|   for theta within +-90 deg of firing TDC
  3  piston-skirt viscous          mu |c| / g_a * pi D L_FP * |x'|
  4  valve train                   N_v L_s |x'| / sqrt(omega)
  5  auxiliaries + unloaded brgs   mu omega
  6  loaded bearings               (pi/4) D^2 r_b p |cos theta| / sqrt(omega)
with c = omega x' the piston speed.
"""

from __future__ import annotations

import numba
import numpy as np

from frictionwatch.core.model.kinematics import _kinematics

N_TERMS = 6
TERM_NAMES = ("ring_viscous", "ring_mixed", "skirt_viscous", "valve_train", "auxiliaries", "loaded_bearings")
# params layout (EngineSpec.friction_params())
_R, _L, _E, _D, _MU, _PE, _ETH, _NC, _NO, _LFP, _GA, _NV, _LS, _RB = range(14)
FOUR_PI = 4.0 * np.pi


@numba.njit(cache=True)
def _friction_basis(theta, omega, p_gauge, params, out):
    n = theta.shape[0]
    x = np.empty(n)
    dx = np.empty(n)
    ddx = np.empty(n)
    _kinematics(theta, params[0:3], x, dx, ddx)
    d = params[_D]
    mu = params[_MU]
    pe = params[_PE]
    ring_geom = np.pi * d * (params[_NO] + 0.4 * params[_NC])
    for i in range(n):
        w = omega[i] if omega[i] > 1e-3 else 1e-3
        p = p_gauge[i] if p_gauge[i] > 0.0 else 0.0
        lever = abs(dx[i])
        c = w * lever
        out[0, i] = np.sqrt(mu * c * (pe + p) * params[_ETH]) * ring_geom * lever
        th = theta[i] % FOUR_PI
        if th <= 0.5 * np.pi or th >= FOUR_PI - 0.5 * np.pi:
            out[1, i] = np.pi * d * params[_NC] * (pe + p) * (1.0 - abs(np.sin(th))) * lever
        else:
            out[1, i] = 0.0
        out[2, i] = mu * c / params[_GA] * np.pi * d * params[_LFP] * lever
        rw = 1.0 / np.sqrt(w)
        out[3, i] = params[_NV] * params[_LS] * lever * rw
        out[4, i] = mu * w
        out[5, i] = 0.25 * np.pi * d * d * params[_RB] * p * abs(np.cos(th)) * rw


def friction_basis(theta: np.ndarray, omega: np.ndarray, p_gauge: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Basis matrix F (6, n) of one cylinder.

    Parameters
    ----------
    theta : (n,) local crank angle of the cylinder [rad], 0 = its firing TDC
    omega : (n,) or scalar angular speed of its throw [rad/s]
    p_gauge : (n,) cylinder pressure minus crankcase pressure [Pa]; negative values are clipped to 0
    params : ``EngineSpec.friction_params()``
    """
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    n = th.shape[0]
    w = np.ascontiguousarray(np.broadcast_to(np.asarray(omega, dtype=np.float64), (n,)))
    p = np.ascontiguousarray(np.broadcast_to(np.asarray(p_gauge, dtype=np.float64), (n,)))
    prm = np.ascontiguousarray(params, dtype=np.float64)
    if prm.shape != (14,):
        raise ValueError(f"params must be EngineSpec.friction_params() (14 values), got shape {prm.shape}")
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(p))):
        raise ValueError("omega and p_gauge must be finite; mark bad samples before calling")
    out = np.empty((N_TERMS, n))
    _friction_basis(th, w, p, prm, out)
    return out
