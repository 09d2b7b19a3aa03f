"""Numba kernels of the condition check (core.monitor.checks.condition), each beside the plain numpy it stands for
there: the levels and their windows, the combustion flags with the siblings' medians from one sort, and the cycle's
chi^2 over its effective degrees of freedom in numpy's own order of arithmetic; ``condition_kernel`` runs them, the
change detector's and the ring indicators' kernels and the blow-by and worn-ring tests as one dispatch a cycle."""

from __future__ import annotations

import numba
import numpy as np
from frictionwatch.core.monitor.checks.change import cusum_kernel
from frictionwatch.core.monitor.checks.ring_pressure import median_of_first, moved_kernel, ring_kernel

NOT_JUDGED, MOTORED, FIRED = 0, 1, 2  # combustion_kernel's status: no burn ratio, none burned, some burned


@numba.njit(cache=True)
def combustion_kernel(burn, work, reference, cycles, limits):
    """(status, misfire (z,) bool, reference (z,), cycles (z,) int64) of ``combustion_flags_reference``: status
    NOT_JUDGED / MOTORED (the arrays then unused) / FIRED; limits = (burn_log_ratio, partial_fraction, burn_window).
    Each burned cylinder's reference is the median of its burned siblings' work (NaN when one is NaN, as np.median),
    its own ``reference`` without a burned sibling."""
    z = burn.shape[0]
    burned = np.zeros(z, dtype=np.bool_)
    judged_any = False
    b = 0
    for k in range(z):
        if np.isfinite(burn[k]):
            judged_any = True
            if burn[k] > limits[0]:
                burned[k] = True
                b += 1
    misfire = np.zeros(z, dtype=np.bool_)
    new_reference = reference.copy()
    new_cycles = cycles.copy()
    if b == 0:
        return (MOTORED if judged_any else NOT_JUDGED), misfire, new_reference, new_cycles
    # the burned cylinders' work sorted once (NaN apart): each cylinder's siblings are that list without one
    # sample equal to its own, so their median is read off it (the same samples averaged as np.median's; one sort
    # per cylinder cost ~0.5 us each, 12 us a genset-v20 cycle)
    finite = np.empty(b)
    n_fin = np.int64(0)  # typed int64 from the start: a literal 0 compiles median_without and _position once more
    for j in range(z):
        if burned[j] and not np.isnan(work[j]):
            finite[n_fin] = work[j]
            n_fin += 1
    s = np.sort(finite[:n_fin])
    n_nan = b - n_fin
    for k in range(z):
        if not burned[k]:
            misfire[k] = np.isfinite(burn[k])  # judged, did not burn
            continue
        ref = reference[k]
        if b >= 2:
            own_nan = np.isnan(work[k])
            ref = np.nan if n_nan - int(own_nan) > 0 else median_without(s, n_fin, -1 if own_nan else
                                                                      _position(s, n_fin, work[k]))
        if np.isfinite(ref) and ref > 0 and work[k] < limits[1] * ref:
            misfire[k] = True  # burned partially
            continue
        new_cycles[k] += 1  # burned fully: the reference follows
        g = max(1.0 / limits[2], 1.0 / max(new_cycles[k], 1))
        new_reference[k] = reference[k] + g * (work[k] - reference[k]) if np.isfinite(reference[k]) else work[k]
    return FIRED, misfire, new_reference, new_cycles


@numba.njit(cache=True)
def _position(s, n, v):
    """An index of the value v in the sorted s[:n] (it is there)."""
    for i in range(n):
        if s[i] == v:
            return i
    return n - 1


@numba.njit(cache=True)
def median_without(s, n, r):
    """``median_of_first`` of the sorted s[:n] without its element r (r < 0: all n): the same one or two samples,
    the same arithmetic."""
    m = n - 1 if r >= 0 else n
    h = m // 2
    hi = s[h + 1] if 0 <= r <= h else s[h]
    if m % 2:
        return hi
    lo = s[h] if 0 <= r <= h - 1 else s[h - 1]
    return 0.5 * (lo + hi)


@numba.njit(cache=True)
def levels_kernel(pressure, cols, frac, pmax, indicated):
    """(4, z): ln compression rise, ln max(pmax, 1 Pa), ln max(indicated, 1e-9 N m) and the burn ratio of each
    cylinder (``compression_rise``, ``burn_ratio``: p linear between grid columns; NaN where one is not positive)."""
    z, n = pressure.shape
    out = np.empty((4, z))
    p = np.empty(4)
    for k in range(z):
        for a in range(4):
            i = cols[k, a]
            p[a] = pressure[k, i] * (1.0 - frac[k, a]) + pressure[k, (i + 1) % n] * frac[k, a]
        out[0, k] = np.log(p[1] / p[0]) if p[0] > 0 and p[1] > 0 else np.nan
        out[1, k] = np.log(pmax[k] if not pmax[k] < 1.0 else 1.0)  # np.maximum: NaN stays NaN
        out[2, k] = np.log(indicated[k] if not indicated[k] < 1e-9 else 1e-9)
        out[3, k] = np.log(p[3] / p[2]) if p[2] > 0 and p[3] > 0 else np.nan
    return out


@numba.njit(cache=True)
def window_kernel(levels, window, g, first):
    """The window (2, 3, z) after this cycle: ``_ewma`` of the ``sibling_deviation`` of each of the first three
    rows of levels (4, z)."""
    z = levels.shape[1]
    out = np.empty_like(window)
    dev = np.zeros(z)
    buf = np.empty(z)
    for r in range(3):
        x = levels[r]
        if z == 2:
            dev[0] = x[0] - x[1]
            dev[1] = x[1] - x[0]
        elif z > 2:
            nan = False
            for k in range(z):
                nan = nan or np.isnan(x[k])
                buf[k] = x[k]
            med = np.nan if nan else median_of_first(buf, z)  # np.median: NaN in, NaN out
            for k in range(z):
                dev[k] = x[k] - med
        for k in range(z):
            ok = np.isfinite(dev[k])
            if first:
                out[0, r, k] = dev[k] if ok else 0.0
                out[1, r, k] = 0.0
            else:
                d = dev[k] - window[0, r, k] if ok else 0.0
                out[0, r, k] = window[0, r, k] + g * d
                out[1, r, k] = (1.0 - g) * (window[1, r, k] + g * d * d)
    return out


@numba.njit(cache=True)
def cycle_chi2_kernel(yty, rows, params, rhs, info, cov_stat, chi2_red):
    """``cycle_chi2_reduced_reference``'s arithmetic in its order: chi^2 cancels ~5 digits, so its dot products are
    the same BLAS calls numpy makes (ddot, dgemv), and tr(info unscaled) is summed as np.sum sums (``numpy_sum``)."""
    chi2 = yty - np.dot(2.0 * params, rhs) + np.dot(np.dot(params, info), params)
    c = chi2_red if chi2_red > 1.0 else 1.0  # Python's max(1.0, x): NaN keeps 1.0
    p = info.shape[0]
    prod = np.empty(p * p)  # info * unscaled.T, C order
    for i in range(p):
        for j in range(p):
            prod[i * p + j] = info[i, j] * (cov_stat[j, i] / c)
    dof = rows - numpy_sum(prod, np.int64(0), np.int64(p * p))  # (plain ints: one specialisation, see numpy_sum)
    return chi2 / dof if dof > 0 else 1.0


@numba.njit(cache=True)
def numpy_sum(a, lo, n):
    """sum of a[lo:lo + n] as numpy's add.reduce forms it for a contiguous float64 array (pairwise: blocks of up to
    128 summed by ``_block_sum``, halves above added left + right), so the kernel's rounding is numpy's (tested bit
    for bit). The halving walks an explicit stack: a recursive kernel loaded from numba's cache crashed. Callers pass
    ``lo`` and ``n`` as np.int64: a constant 0 (or a count typed as its first value 0 while numba infers the
    caller) compiled it once per literal, two specialisations of ~0.56 s each (design note 93)."""
    kind = np.empty(64, np.int64)  # 0: sum the range, 1: add the two values on top (depth <= log2(n / 128) + 1)
    t_lo = np.empty(64, np.int64)
    t_n = np.empty(64, np.int64)
    vals = np.empty(64)
    n_task = 1
    n_val = 0
    kind[0], t_lo[0], t_n[0] = 0, lo, n
    while n_task > 0:
        n_task -= 1
        if kind[n_task] == 1:
            n_val -= 1
            vals[n_val - 1] = vals[n_val - 1] + vals[n_val]
            continue
        start, size = t_lo[n_task], t_n[n_task]
        if size <= 128:
            vals[n_val] = _block_sum(a, start, size)
            n_val += 1
            continue
        half = size // 2
        half -= half % 8
        kind[n_task], t_lo[n_task], t_n[n_task] = 1, 0, 0  # after both halves: add them
        kind[n_task + 1], t_lo[n_task + 1], t_n[n_task + 1] = 0, start + half, size - half
        kind[n_task + 2], t_lo[n_task + 2], t_n[n_task + 2] = 0, start, half  # popped first: the left half
        n_task += 3
    return vals[0]


@numba.njit(cache=True)
def _block_sum(a, lo, n):
    """numpy's pairwise_sum of n <= 128 contiguous values: plain below 8, else eight partial sums."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r = a[lo:lo + 8].copy()
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += a[lo + i + j]
        i += 8
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


# ---- the whole check as one kernel ------------------------------------------------------------------------------
# The kernels above are called one by one from ``assess_condition``'s reference (``assess_condition_reference``);
# ``condition_kernel`` runs them, the change detector's step, the blow-by/worn-ring tests and the ring indicators in
# one dispatch over the state's arrays (their Python between the kernels was ~20 small numpy calls a cycle).

INT_FIELDS = ("use", "first", "flag_window", "has_terms", "det_count", "det_quiet", "ring", "moved")
REAL_FIELDS = ("g", "z_flag", "ring_sigmas", "misfit_cap", "yty", "rows", "chi2_reduced", "rel_floor",
               "theta_start")


@numba.njit(cache=True)
def condition_kernel(levels_in, state, estimate, fit, ring_in, limits, ints, reals):
    """One cycle of ``assess_condition_reference`` after its Python: (window (2, 3, z), combustion status,
    misfire (z,) bool, burn reference (z,), burn cycles (z,), capped chi^2, wear (z,) int64 (1 blow-by, 2 blow-by
    and a worn ring), change status, the detector's mean (z,), var (z,) and sums (2, z), alarm (z,) bool, ring
    (7, z) as ``ring_kernel``'s).

    Tuples of arrays, by what they are:
      levels_in = (pressure (z, n), cols (z, 4), frac (z, 4): the condition tables, pmax (z,), indicated (z,));
      state = (window (2, 3, z), burn_reference (z,), burn_cycles (z,) int64, the change detector's mean (z,),
               var (z,), sums (2, z));
      estimate = (torque (z,), sigma (z,), resolved (z,) bool): the smoothed estimate's;
      fit = (cycle_params (P,), smoothed_params (P,), cylinder_rows (z, p_f): the change detector's innovations;
             rhs (P,), info (P, P) of the cycle's terms and its cov_statistical (P, P): ``cycle_chi2_kernel``'s,
             unread without terms);
      ring_in = (grid (n,), cols (z, m), frac (z, m), local (m,), -ln V (m,), sizes (n_comp, edge): the ring
                 tables; phases (z,) the firing angles, static (z,) and relative (z, M) the throw motion);
      limits = (burn (3,) as ``combustion_kernel``'s, the window's floors (3,), cusum (5,) as ``cusum_kernel``'s);
    ints and reals: the flags and scalars named by INT_FIELDS and REAL_FIELDS, in that order. One signature for
    every engine: the optional parts (terms, ring, motion) are switched by ints, never by the arguments' types."""
    pressure, cols, frac, pmax, work = levels_in
    window, burn_reference, burn_cycles, det_mean, det_var, det_sums = state
    torque, sigma, resolved = estimate
    cycle_params, smoothed_params, cylinder_rows, rhs, info, cov_stat = fit
    ring_grid, ring_cols, ring_frac, ring_local, ring_x, ring_sizes, phases, static, relative = ring_in
    burn_limits, floors, cusum_limits = limits
    use, first, flag_window, has_terms = ints[0] != 0, ints[1] != 0, ints[2] != 0, ints[3] != 0
    g, z_flag, ring_sigmas, misfit_cap = reals[0], reals[1], reals[2], reals[3]
    z = pressure.shape[0]
    levels = levels_kernel(pressure, cols, frac, pmax, work)
    new_window = window_kernel(levels, window, g, first) if use else window.copy()
    status, misfire, new_reference, new_cycles = combustion_kernel(levels[3], work, burn_reference, burn_cycles,
                                                                   burn_limits)
    if has_terms:
        chi2 = cycle_chi2_kernel(reals[4], reals[5], cycle_params, rhs, info, cov_stat, reals[6])
    else:
        chi2 = reals[6]
    chi2 = misfit_cap if misfit_cap < chi2 else chi2  # Python's min(chi2, cap): NaN stays NaN
    wear = np.zeros(z, dtype=np.int64)
    if flag_window and z > 1:
        se = np.sqrt(g / (2.0 - g))  # standard error of an EWMA mean per unit of scatter
        for k in range(z):
            low = True
            for r in range(3):
                low = low and new_window[0, r, k] < -(floors[r] + z_flag * se * np.sqrt(new_window[1, r, k]))
            if low:
                wear[k] = 2 if friction_up_kernel(torque, sigma, resolved, k, ring_sigmas) else 1
    # the change detector on the innovation of each cylinder's friction: this cycle's minus the smoothed
    p_f = cylinder_rows.shape[1]
    smooth = np.dot(cylinder_rows, np.ascontiguousarray(smoothed_params[:p_f]))
    u = np.dot(cylinder_rows, np.ascontiguousarray(cycle_params[:p_f])) - smooth
    floor = reals[7] * np.abs(smooth)
    mean, var, sums, alarm = np.empty(z), np.empty(z), np.empty((2, z)), np.zeros(z, dtype=np.bool_)
    change = cusum_kernel(u, det_mean, det_var, det_sums, ints[4], ints[5], cusum_limits, floor, mean, var, sums,
                           alarm)
    ring = np.empty((7, z))
    if ints[6] != 0:
        r_cols, r_frac = ring_cols, ring_frac
        if ints[7] != 0:  # each window sample where the cylinder's throw, not the flywheel, is at its angle
            r_cols, r_frac = np.empty_like(ring_cols), np.empty_like(ring_frac)
            moved_kernel(ring_grid, ring_local, phases, static, relative, reals[8], r_cols, r_frac)
        ring = ring_kernel(pressure, r_cols, r_frac, ring_x, ring_sizes[0], ring_sizes[1])
    return new_window, status, misfire, new_reference, new_cycles, chi2, wear, change, mean, var, sums, alarm, ring


@numba.njit(cache=True)
def friction_up_kernel(torque, sigma, resolved, k, sigmas):
    """``condition._friction_up``: cylinder k's torque resolved and above its resolved siblings' mean by ``sigmas``
    combined sigmas, the means summed as np.mean sums (``numpy_sum``)."""
    z = torque.shape[0]
    if not resolved[k]:
        return False
    t_o, s2_o = np.empty(z), np.empty(z)
    n = 0
    for j in range(z):
        if j != k and resolved[j]:
            t_o[n] = torque[j]
            s2_o[n] = sigma[j] * sigma[j]
            n += 1
    if n == 0:
        return False
    lo, count = np.int64(0), np.int64(n)  # (plain ints: one specialisation, see numpy_sum)
    excess = torque[k] - numpy_sum(t_o, lo, count) / n
    return excess > sigmas * np.sqrt(sigma[k] * sigma[k] + numpy_sum(s2_o, lo, count) / n / n)
