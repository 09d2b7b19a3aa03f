"""Numba kernels of the Eq. 6 sharing (core.monitor.identify.sharing) and of its prior rows in normal form
(core.monitor.identify.priors.PriorNormal.with_share). The numpy references are in tests/core/test_monitor_kernels.py."""

from __future__ import annotations

import numba
import numpy as np


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
