"""The alert engine's per-cycle pressure statistics as one kernel (design note 94): the indicators' EWMA against a
load band, its change and this cycle's against the siblings' median change, the leak signature's z (this cycle's
and the EWMA's) and the long-run-variance factor of the two figures.

Statistics only, the alerts' decisions stay in service/alerts.py. The definitions, in numpy, are the service's
(service/alert_interface.py ``change_against_siblings``, ``leak_statistics``, ``LongRunVariance.add`` / ``factor``;
service/alerts.py ``AlertEngine.statistics_reference`` strings them together): those ~25 numpy calls on (2..4, z)
arrays were ~50 us a genset-v20 cycle, this kernel ~5 us. Each value is formed by the same IEEE operations in the
same order, so the two agree to the last bit (tests/service/test_pressure_statistics.py holds the kernel to the
reference over a looped replay with faults and load bands, with tolerance 0).

Arrays, all float64, z cylinders:
    x (4, z)        this cycle's indicators (rows as service.alert_baseline.INDICATORS), all finite
    mean (4, z)     the load band's mean
    ewma (4, z)     the EWMA of x - mean, updated in place with factor g
    weights (4, z)  the band's leak weights: w1, w2 (the exponents' weights), s_sd, sd_ratio (alert_interface.LeakWeights)
    lrv (4, 2, z)   the long-run-variance state (alert_interface.LongRunVariance): centre, last, c0, c1 of the two
                    figures (leak z, ratio z), updated in place; n its cycles so far
    params (5,)     centre cycles, horizon, warm-up cycles, var (the EWMA's variance times the siblings' factor), the
                    band mean's variance
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def _less_median(a, out):
    """out = a - each row's median over the cylinders (a sort's middle, or half the sum of the two middle ones; NaN
    where a row holds a NaN, as np.median), rows of (r, z); a copy where z < 3 (no siblings' median)."""
    r, z = a.shape
    for i in range(r):
        if z < 3:
            out[i] = a[i]
            continue
        s = np.sort(a[i])
        if np.isnan(s[z - 1]):  # a NaN sorts last
            m = np.nan
        elif z % 2:
            m = s[z // 2]
        else:
            m = 0.5 * (s[z // 2 - 1] + s[z // 2])
        for k in range(z):
            out[i, k] = a[i, k] - m


@numba.njit(cache=True)
def pressure_statistics_kernel(x, mean, ewma, g, weights, lrv, n, params):
    """``(change (4, z), z_leak, effect, z_ratio (z,), factors (2,), n)`` of one cycle (module doc)."""
    z = x.shape[1]
    centre_cycles, horizon, warmup, var, band_var = params[0], params[1], params[2], params[3], params[4]
    both = np.empty((8, z))  # the EWMA's rows then this cycle's, as np.array((ewma, u)) stacks them
    for i in range(4):
        for k in range(z):
            u = x[i, k] - mean[i, k]
            ewma[i, k] += g * (u - ewma[i, k])
            both[i, k] = ewma[i, k]
            both[4 + i, k] = u
    rel = np.empty((8, z))
    _less_median(both, rel)
    w1, w2, s_sd, sd_ratio = weights[0], weights[1], weights[2], weights[3]
    # this cycle's own standardised figures (leak_statistics with var 1: se 1.0) into the long-run estimate
    one = np.empty((2, z))
    finite = True
    for k in range(z):
        one[0, k] = (w1[k] * rel[5, k] + w2[k] * rel[6, k]) / (s_sd[k] * 1.0)
        one[1, k] = rel[4, k] / (sd_ratio[k] * 1.0)
        finite = finite and math.isfinite(one[0, k]) and math.isfinite(one[1, k])
    centre, last, c0, c1 = lrv[0], lrv[1], lrv[2], lrv[3]
    if finite:
        n += 1
        a_centre = max(1.0 / centre_cycles, 1.0 / n)
        a = max(1.0 / horizon, 1.0 / n)
        a1 = max(1.0 / horizon, 1.0 / (n - 1)) if n > 1 else 0.0
        for s in range(2):
            for k in range(z):
                centre[s, k] += a_centre * (one[s, k] - centre[s, k])
                d = one[s, k] - centre[s, k]
                c0[s, k] += a * (d * d - c0[s, k])
                if n > 1:
                    c1[s, k] += a1 * (d * last[s, k] - c1[s, k])
                last[s, k] = d
    factors = np.ones(2)
    if not (n < warmup or z < 3):
        f = np.empty(z)
        for s in range(2):
            for k in range(z):
                phi = c1[s, k] / c0[s, k] if c0[s, k] > 0.0 else 0.0
                r = min(max(phi, 0.0), 0.999) * (1.0 - g)
                f[k] = (1.0 + r) / (1.0 - r)
            f = np.sort(f)
            median = f[z // 2] if z % 2 else 0.5 * (f[z // 2 - 1] + f[z // 2])
            factors[s] = min(max(median, 1.0), (2.0 - g) / g)
    se = math.sqrt((var + band_var) * factors[0])
    se_ratio = math.sqrt((var + band_var) * factors[1])
    z_leak = np.empty(z)
    effect = np.empty(z)
    z_ratio = np.empty(z)
    for k in range(z):
        z_leak[k] = (w1[k] * rel[1, k] + w2[k] * rel[2, k]) / (s_sd[k] * se)
        effect[k] = 0.5 * (rel[2, k] - rel[1, k])
        z_ratio[k] = rel[0, k] / (sd_ratio[k] * se_ratio)
    return rel[:4].copy(), z_leak, effect, z_ratio, factors, n


def pressure_statistics(x: np.ndarray, mean: np.ndarray, ewma: np.ndarray, g: float, weights: np.ndarray,
                        lrv: np.ndarray, n: int, params: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """``pressure_statistics_kernel`` (module doc); ``ewma`` and ``lrv`` are updated in place."""
    change, z_leak, effect, z_ratio, factors, n_after = pressure_statistics_kernel(
        np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(mean, dtype=np.float64), ewma, float(g),
        weights, lrv, int(n), params)
    return change, z_leak, effect, z_ratio, factors, int(n_after)
