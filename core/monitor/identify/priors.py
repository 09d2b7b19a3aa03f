"""Prior rows of the identification (physics.md §9, §10: 'a weak prior: commissioning baseline or siblings').

- weak: each parameter scale params ~ N(1, parameter_sigma^2) about the baseline a0 (core.monitor.identify.layout);
- tooth-spacing nuisances E_n ~ N(0, s^2 2/N_edges): white per-tooth errors of rms s (core.monitor.identify.layout.tooth_patterns);
- siblings: each per-cylinder scale within sibling_spread of the mean of its siblings (same parts in every cylinder;
  the only prior that speaks for directions the speed cannot see, e.g. the contrast of cylinders 360 deg apart);
- Eq. 6 sharing of the measured mean loss (core.monitor.identify.sharing), per cylinder, added per cycle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.identify.accumulate import Prior
from frictionwatch.core.monitor.identify.layout import ParameterLayout
from frictionwatch.core.monitor.identify.sharing import SharedLoss, share_rows_kernel


@dataclass(frozen=True)
class FixedPriors:
    """The fixed prior rows plus the per-cylinder rows (z, P) the Eq. 6 shares are attached to."""

    base: Prior
    cylinder_rows: np.ndarray

    def with_share(self, share: SharedLoss) -> Prior:
        if not np.all(np.isfinite(share.friction_mean)):
            return self.base
        return Prior.stack(self.base, Prior(self.cylinder_rows, share.friction_mean, np.maximum(share.sigma, 1e-6)))


def tooth_coefficient_sigma(tooth_error_deg: float, edges: int) -> float:
    """rms [rad] of each real Fourier part of white per-tooth angle errors of rms ``tooth_error_deg`` over ``edges``
    edges a revolution: s sqrt(2 / N) (the in-band tooth nuisances' prior; the drive train's leak noise)."""
    return float(np.radians(tooth_error_deg) * np.sqrt(2.0 / edges))


def build_priors(spec: EngineSpec, layout: ParameterLayout, n_nuisance: int, cylinder_rows: np.ndarray,
                 parameter_sigma: float, tooth_error_deg: float, sibling_spread: float) -> FixedPriors:
    """Priors over [friction scales (P_f), tooth nuisances (n_nuisance)]; cylinder_rows (z, P_f + n_nuisance)."""
    p_f = layout.n_params
    p = p_f + n_nuisance
    sig = np.full(p, parameter_sigma)
    target = np.concatenate([np.ones(p_f), np.zeros(n_nuisance)])
    if n_nuisance:
        sig[p_f:] = tooth_coefficient_sigma(tooth_error_deg, spec.sensors.wheel_teeth - spec.sensors.wheel_missing)
    base = Prior(np.eye(p), target, sig)
    z = spec.n_cyl
    per_cyl = np.flatnonzero(layout.per_cylinder)
    if sibling_spread > 0 and z > 1:
        block = per_cyl.reshape(z, -1)  # one block of equal terms per cylinder
        rows = []
        for j in range(block.shape[1]):
            for k in range(z):
                r = np.zeros(p)
                r[block[:, j]] = -1.0 / z
                r[block[k, j]] += 1.0
                rows.append(r)
        sib = np.array(rows)
        base = Prior.stack(base, Prior(sib, np.zeros(sib.shape[0]), np.full(sib.shape[0], sibling_spread)))
    return FixedPriors(base, cylinder_rows)


@dataclass(frozen=True)
class PriorNormal:
    """The fixed priors in normal form, info (P, P) and rhs (P,) (``FixedPriors.base.normal()``), kept in the
    monitor's state (they do not change from cycle to cycle); ``key`` = the configuration they were built for
    (parameter_sigma, tooth_error_deg, sibling_spread)."""

    key: tuple[float, float, float]
    info: np.ndarray
    rhs: np.ndarray

    def with_share(self, cylinder_rows: np.ndarray, share: SharedLoss) -> tuple[np.ndarray, np.ndarray]:
        """Normal equations of the fixed priors plus the Eq. 6 share rows (``FixedPriors.with_share(share).normal()``);
        cylinder_rows (z, p_f) act on the leading p_f parameters. A share that is not finite adds nothing."""
        if not np.isfinite(share.friction_mean).all():
            return self.info, self.rhs
        rows = np.ascontiguousarray(cylinder_rows, dtype=np.float64)
        if rows.shape[1] > self.info.shape[0] or share.friction_mean.shape != (rows.shape[0],):
            raise ValueError(f"cylinder rows {rows.shape} do not fit the priors ({self.info.shape[0]} parameters) "
                             f"or the shares {share.friction_mean.shape}")
        return share_rows_kernel(self.info, self.rhs, rows, share.friction_mean, share.sigma)


def prior_normal(spec: EngineSpec, layout: ParameterLayout, n_nuisance: int, parameter_sigma: float,
                 tooth_error_deg: float, sibling_spread: float) -> PriorNormal:
    """The fixed priors of ``build_priors`` in normal form."""
    base = build_priors(spec, layout, n_nuisance, np.zeros((spec.n_cyl, layout.n_params + n_nuisance)),
                        parameter_sigma, tooth_error_deg, sibling_spread).base
    info, rhs = base.normal()
    return PriorNormal((parameter_sigma, tooth_error_deg, sibling_spread), info, rhs)
