"""Numba kernel of the flywheel fit (core.flywheel): the Fourier design matrix over the tooth-edge times.

cos(m w1 tau) and sin(m w1 tau) for m = 1..M come from the angle-addition recurrence, re-seeded with a direct
cos/sin every ``RESEED`` harmonics so the rounding cannot build up (< 1e-14 relative to the direct evaluation; the
plain reference is ``np.cos(np.outer(tau, w))``, tests/core/test_flywheel_kernels.py).
"""

from __future__ import annotations

import numba
import numpy as np

RESEED = 8


@numba.njit(cache=True)
def _fit_design(tau, period, w1, n_drift, n_harm, design):
    """design (n_edges, n_drift + 2 n_harm): [1, (u (u - 1)), cos(m w1 tau)..., sin(m w1 tau)...], u = tau/T."""
    n = tau.shape[0]
    c0 = n_drift
    s0 = n_drift + n_harm
    for i in range(n):
        t = tau[i]
        design[i, 0] = 1.0
        if n_drift == 2:
            u = t / period
            design[i, 1] = u * (u - 1.0)
        c = 1.0
        s = 0.0
        c1 = 1.0
        s1 = 0.0
        for m in range(n_harm):
            if m % RESEED == 0:
                a = t * (w1 * (m + 1))
                c = np.cos(a)
                s = np.sin(a)
                if m == 0:
                    c1 = c
                    s1 = s
            else:
                c, s = c * c1 - s * s1, s * c1 + c * s1
            design[i, c0 + m] = c
            design[i, s0 + m] = s
