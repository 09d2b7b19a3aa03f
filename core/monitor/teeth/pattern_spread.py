"""What the in-band tooth pattern's remaining uncertainty puts into the speed residual (design note 118).

The monitor carries the wheel's in-band tooth-spacing error as accumulated nuisance parameters E_n (two real numbers
per integer order, core.monitor.identify.parameters.tooth_patterns); their columns in a cycle's speed equations are
the angle patterns passed through that cycle's flywheel fit (the nuisance block of ``CycleRows.design``, complex
rad/s per unit of E). The reported residual (measured - model) is taken at the estimate of E, so an estimate off by
dE moves each order's residual by -D_E dE: the same in every cycle while the estimate has not converged, a coherent
residual that averaging over cycles does not remove. Its spread at engine order m/2, with Cov(E) the posterior's
nuisance block, is

    s_m^2 = Var(Re r_m) + Var(Im r_m) = D_m Cov(E) D_m^H        (E real: Re D Cov Re D^T + Im D Cov Im D^T)

the same measure of a complex harmonic's spread as the discrepancy's order table uses (core.discrepancy.features.
order_table: sqrt of the Re and Im variances summed). A few (M, n) x (n, n) products a cycle, asked for only by the
discrepancy workflow's runs (MonitorConfig.nuisance_spread), so plain numpy.
"""

from __future__ import annotations

import numpy as np


def pattern_spread(design_nuisance: np.ndarray, cov_nuisance: np.ndarray) -> np.ndarray:
    """(M,) rad/s the 1-sigma spread of each residual speed harmonic (Re and Im variances summed, square-rooted) that
    the nuisances' posterior covariance ``cov_nuisance`` (n, n) puts there through their columns ``design_nuisance``
    (M, n) complex; zeros without nuisances. A covariance that is not positive semi-definite by rounding gives no
    negative variance (clipped at 0)."""
    d = np.asarray(design_nuisance)
    if d.shape[1] == 0:
        return np.zeros(d.shape[0])
    cov = np.asarray(cov_nuisance, dtype=np.float64)
    # Re and Im apart, two real products: a third of a three-operand complex einsum's time at genset-v20's 24 x 24
    # (32 against 86 us a call, alternated, load ~7), the same numbers to 6e-16 relative
    dr, di = d.real, d.imag
    var = ((dr @ cov) * dr).sum(axis=1) + ((di @ cov) * di).sum(axis=1)
    return np.sqrt(np.maximum(var, 0.0))


__all__ = ["pattern_spread"]
