"""The ring condition's kernel (core.monitor.checks.ring_condition): ``ring_condition_reference``'s numbers --
the two inverse-variance ``combine``s, the sibling window's standard error, the sibling excess and the choice of
reference -- in one dispatch, element by element in numpy's order of arithmetic (its ~15 small numpy calls were
~110 us of the alert engine's ~0.36 ms a genset-v20 cycle in serve: design note 86)."""

from __future__ import annotations

import numba
import numpy as np

SINCE, SIBLINGS = 0, 1  # ring_condition's references (the same numbers)


@numba.njit(cache=True)
def ring_condition_kernel(evidence, window_mean, window_var, reals, ints):
    """(out (9, z): figure, sigma, since, since_sigma, siblings, siblings_sigma, leak_siblings,
    leak_siblings_sigma, friction_now used; reference (z,) int64) from evidence = (leak_change, its sigma,
    friction_change, its sigma, friction_now, its sigma) (z,) each, the sibling window's mean and var (z,),
    reals = (leak_scale, friction_scale, window, leak_allowance, friction_allowance) and ints = (window count,
    warmup, siblings)."""
    lc, lc_s, fc, fc_s, fn, fn_s = evidence
    leak_scale, friction_scale, window, leak_allowance, friction_allowance = reals[0], reals[1], reals[2], reals[3], \
        reals[4]
    count, warmup, siblings = ints[0], ints[1], ints[2] != 0
    z = window_mean.shape[0]
    out = np.full((9, z), np.nan)
    reference = np.empty(z, dtype=np.int64)
    combine_pair(lc, lc_s, fc, fc_s, leak_scale, friction_scale, out[2], out[3])
    if siblings and count >= warmup and z >= 3:
        g = max(1.0 / window, 1.0 / max(count, 1))
        se = np.empty(z)
        for k in range(z):
            v = window_var[k]
            se[k] = np.sqrt((0.0 if v < 0.0 else v) * g / (2.0 - g))  # np.maximum(var, 0): NaN stays NaN
        sibling_kernel(window_mean, se, leak_allowance, out[6], out[7])
    # against the siblings the friction only adds to a leak that is there (ring_condition_reference)
    fr_now_s = np.empty(z)
    allowance2 = friction_allowance ** 2
    for k in range(z):
        if siblings and out[6, k] > 0.0:
            out[8, k] = fn[k]
        fr_now_s[k] = np.sqrt(fn_s[k] ** 2 + allowance2)
    combine_pair(out[6], out[7], out[8], fr_now_s, leak_scale, friction_scale, out[4], out[5])
    for k in range(z):
        since, sib = out[2, k], out[4, k]
        z_since = since / out[3, k] if np.isfinite(since) else -np.inf
        z_sib = sib / out[5, k] if np.isfinite(sib) else -np.inf
        use_sib = z_sib > z_since
        reference[k] = (SIBLINGS if use_sib else SINCE) if np.isfinite(since) or np.isfinite(sib) else -1
        out[0, k] = sib if use_sib else since
        out[1, k] = out[5, k] if use_sib else out[3, k]
    return out, reference


@numba.njit(cache=True)
def combine_pair(a, a_s, b, b_s, a_scale, b_scale, fig, sig):
    """``combine`` of two pieces of evidence (z,) each with sigmas, divided by their scales, into fig and sig (z,)
    (NaN where neither is left): each weight 1 / s^2 and the two summed in numpy's order (row 0 + row 1)."""
    for k in range(a.shape[0]):
        v0, s0 = a[k] / a_scale, a_s[k] / a_scale
        v1, s1 = b[k] / b_scale, b_s[k] / b_scale
        ok0 = np.isfinite(v0) and np.isfinite(s0) and s0 > 0
        ok1 = np.isfinite(v1) and np.isfinite(s1) and s1 > 0
        w0 = 1.0 / (s0 * s0) if ok0 else 0.0
        w1 = 1.0 / (s1 * s1) if ok1 else 0.0
        wsum = w0 + w1
        if wsum > 0:
            fig[k] = (w0 * (v0 if ok0 else 0.0) + w1 * (v1 if ok1 else 0.0)) / wsum
            sig[k] = 1.0 / np.sqrt(wsum)
        else:
            fig[k] = np.nan
            sig[k] = np.nan


@numba.njit(cache=True)
def sibling_kernel(x, se, allowance, dev, sig):  # pragma: no cover - compiled; tested against the reference
    """``sibling_excess_reference`` into dev and sig (z,) (NaN-filled by the caller), z >= 3.

    The finite x are sorted once; a cylinder's others, sorted, are that order without one of its value's places,
    and the median of their distances to the centre is read off the two runs that order gives (``_median_distance``):
    the same values the reference sorts, so the same medians to the last bit (but a zero's sign where +0 and -0
    tie), without the two sorts a cylinder (40 sorts of 19 values a genset-v20 cycle: ~90 % of the kernel's ~30 us,
    design note 145)."""
    z = x.shape[0]
    finite = np.empty(z)
    m = 0
    for j in range(z):
        if np.isfinite(x[j]):
            finite[m] = x[j]
            m += 1
    ranked = np.sort(finite[:m])
    o = np.empty(z)
    n = m - 1  # a finite cylinder's finite others
    for k in range(z):
        if not np.isfinite(x[k]) or n < 2:
            continue
        se2 = 0.0  # the others' squared errors summed in cylinder order, as the reference does
        i = 0
        for j in range(z):
            if j != k and np.isfinite(x[j]):
                se2 += se[j] ** 2
                o[i] = x[j]  # in cylinder order (the two others' mean below: a zero's sign as the reference's)
                i += 1
        if n == 2:  # three cylinders: the mean of the two others, their disagreement as spread
            centre = 0.5 * (o[0] + o[1])
            spread = abs(o[0] - o[1]) / np.sqrt(2.0)
            centre_var = 0.25 * se2 + 0.5 * spread ** 2
        else:  # the median of the others, their median absolute deviation as spread
            p = np.searchsorted(ranked, x[k])  # a place of x[k]'s value: without it, the others in order
            for i in range(n):
                o[i] = ranked[i] if i < p else ranked[i + 1]
            centre = _sorted_median(o[:n])
            spread = 1.4826 * _median_distance(o, n, centre)
            centre_var = (np.pi / 2.0) * (spread ** 2 + se2 / n) / n
        dev[k] = x[k] - centre
        sig[k] = np.sqrt(se[k] ** 2 + max(spread, allowance) ** 2 + centre_var)


@numba.njit(cache=True)
def _median_distance(o, n, c):  # pragma: no cover - compiled
    """``_sorted_median`` of abs(o[:n] - c) sorted, for o[:n] sorted: the distances left of c grow leftwards and those
    right of it rightwards (rounding is monotone), so their merge, walked from c up to the middle rank, is their
    sorted order."""
    left = np.searchsorted(o[:n], c) - 1
    right = left + 1
    lower = 0.0
    d = 0.0
    for rank in range(n // 2 + 1):
        if right < n and (left < 0 or abs(o[right] - c) <= abs(o[left] - c)):
            d = abs(o[right] - c)
            right += 1
        else:
            d = abs(o[left] - c)
            left -= 1
        if rank == (n - 1) // 2:
            lower = d
    return lower if n % 2 == 1 else 0.5 * (lower + d)


@numba.njit(cache=True)
def _sorted_median(s):  # pragma: no cover - compiled
    n = s.shape[0]
    return s[(n - 1) // 2] if n % 2 == 1 else 0.5 * (s[n // 2 - 1] + s[n // 2])
