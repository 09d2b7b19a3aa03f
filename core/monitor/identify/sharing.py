"""Sharing of the mean loss among cylinders, non-firing cylinders included (paper 000 Eq. 6; physics.md §9).

Firing cylinder k:  T_fM^k = T'_fM * T_iM^k / T'_iM,  with T'_iM = sum over firing cylinders of T_iM^k and
                    T'_fM = T_fM - N_ml * T_fM,ml.
Motored cylinder:   T_fM^k = T_fM,ml, the motored friction of one cylinder at the same mean speed.

The proportional rule is an assumption (more indicated work, more ring and bearing load). The monitor uses it only
as a prior with a stated spread and reports how far the identified means move away from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.identify.sharing_kernels import firing_kernel, share_kernel

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
