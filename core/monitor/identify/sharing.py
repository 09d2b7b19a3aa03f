"""Sharing of the mean loss among cylinders, non-firing cylinders included (paper 000 Eq. 6; physics.md §9).

Firing cylinder k:  T_fM^k = T'_fM * T_iM^k / T'_iM,  with T'_iM = sum over firing cylinders of T_iM^k and
                    T'_fM = T_fM - N_ml * T_fM,ml.
Motored cylinder:   T_fM^k = T_fM,ml, the motored friction of one cylinder at the same mean speed.

The proportional rule is an assumption (more indicated work, more ring and bearing load). The monitor uses it only
as a prior with a stated spread and reports how far the identified means move away from it.

The numba kernels of the Eq. 6 sharing (first below) and of its prior rows in normal form
(core.monitor.identify.priors.PriorNormal.with_share). The numpy references are in tests/core/test_monitor_kernels.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from frictionwatch.core.model.engine import EngineSpec


@numba.njit(cache=True)
def firing_kernel(t, fraction):
    """(z,) bool: t above ``fraction`` of the median of its positive entries (none positive: nothing fires)."""
    z = t.shape[0]
    fire = np.zeros(z, dtype=np.bool_)
    positive = np.sort(t[t > 0])
    n = positive.shape[0]
    if n == 0:
        return fire
    median = positive[n // 2] if n % 2 else 0.5 * (positive[n // 2 - 1] + positive[n // 2])
    for k in range(z):
        fire[k] = t[k] > fraction * median
    return fire


@numba.njit(cache=True)
def share_kernel(total, t_i, motored_friction, spread, motored_spread, fraction):
    """Eq. 6 shares (z,) of ``total`` by t_i, their 1-sigma (z,) and the motored mask (z,) (``share_mean_loss``)."""
    z = t_i.shape[0]
    fire = firing_kernel(t_i, fraction)
    out = np.full(z, motored_friction)
    sig = np.full(z, motored_spread * abs(motored_friction))
    n_fire = 0
    t_fire = 0.0
    for k in range(z):
        if fire[k]:
            n_fire += 1
            t_fire += t_i[k]
    if n_fire:  # nothing firing: every cylinder gets the motored loss
        t_f_fire = total - (z - n_fire) * motored_friction
        for k in range(z):
            if fire[k]:
                out[k] = t_f_fire * t_i[k] / t_fire
                sig[k] = spread * abs(out[k])
    return out, sig, ~fire


@numba.njit(cache=True)
def share_rows_kernel(info, rhs, rows, share, sigma):
    """info + W^T W and rhs + W^T (share / s), W = rows / s, s = max(sigma, 1e-6), as new arrays; rows (z, p_f) act
    on the leading p_f of the P parameters (info (P, P), rhs (P,))."""
    z, p_f = rows.shape
    out_info = info.copy()
    out_rhs = rhs.copy()
    w = np.empty((z, p_f))
    wt = np.empty(z)
    for k in range(z):
        s = max(sigma[k], 1e-6)
        for i in range(p_f):
            w[k, i] = rows[k, i] / s
        wt[k] = share[k] / s
    for i in range(p_f):
        for j in range(i, p_f):
            acc = 0.0
            for k in range(z):
                acc += w[k, i] * w[k, j]
            out_info[i, j] += acc
            if j != i:
                out_info[j, i] += acc
        acc = 0.0
        for k in range(z):
            acc += w[k, i] * wt[k]
        out_rhs[i] += acc
    return out_info, out_rhs


# Chen-Flynn defaults (engines.md §4; 1-D engine-code defaults, provenance not checked against SAE 650733)
CHEN_FLYNN_BAR = (0.4, 0.005, 0.09, 0.0009)


@dataclass(frozen=True)
class SharedLoss:
    """Prior per-cylinder mean friction torque (z,) [N m], its 1-sigma (z,) and which cylinders were motored."""

    friction_mean: np.ndarray
    sigma: np.ndarray
    motored: np.ndarray


def motored_friction_per_cylinder(spec: EngineSpec, rpm: float, pmax_motored_pa: float,
                                  chen_flynn_bar: tuple[float, float, float, float] = CHEN_FLYNN_BAR) -> float:
    """T_fM,ml [N m] of one motored cylinder from FMEP_m = A + B pmax + C c + D c^2 (engines.md §4.2), with the
    *motored* peak pressure and mean piston speed c = 2 S n."""
    a, b, c, d = chen_flynn_bar
    cbar = 2.0 * spec.stroke * rpm / 60.0
    fmep_bar = a + b * pmax_motored_pa / 1e5 + c * cbar + d * cbar * cbar
    return spec.mep_to_torque(fmep_bar * 1e5, cylinders=1)


def firing_mask(indicated_mean: np.ndarray, fraction: float = 0.15) -> np.ndarray:
    """True for cylinders that fire: indicated work above ``fraction`` of the median of the positive ones."""
    t = np.ascontiguousarray(indicated_mean, dtype=np.float64)
    return firing_kernel(t.reshape(-1), float(fraction)).reshape(t.shape)


def share_mean_loss(
    friction_total: float,
    indicated_mean: np.ndarray,
    motored_friction: float,
    spread: float = 0.15,
    motored_spread: float = 0.3,
    fraction: float = 0.15,
) -> SharedLoss:
    """Eq. 6 shares of ``friction_total`` T_fM [N m] by the per-cylinder indicated torques T_iM^k (z,) [N m].

    spread : relative 1-sigma given to a firing cylinder's share (cylinder-to-cylinder scatter the rule ignores)
    motored_spread : relative 1-sigma of a motored cylinder's T_fM,ml
    """
    t_i = np.ascontiguousarray(indicated_mean, dtype=np.float64)
    if t_i.ndim != 1:
        raise ValueError(f"indicated_mean must be one value per cylinder (z,), got shape {t_i.shape}")
    out, sig, motored = share_kernel(float(friction_total), t_i, float(motored_friction), float(spread),
                                     float(motored_spread), float(fraction))
    return SharedLoss(friction_mean=out, sigma=sig, motored=motored)
