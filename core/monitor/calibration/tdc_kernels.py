"""The Gauss-Newton fit of ``core.monitor.calibration.tdc`` as one kernel: its numpy reference is
``tdc._gauss_newton_reference`` with ``tdc._model_terms`` (tested equal in tests/core/test_tdc_kernels.py).

Why a kernel: ``tdc_from_pressure`` runs 9 Gauss-Newton fits of ~2.5 iterations on ~115 window samples (k9k); in
numpy they were 1.7 of its 2.6 ms per cylinder (180 us a fit: ~40 small array operations per residual
and an SVD ``lstsq`` per step, numpy's per-call overhead), in one kernel 82 us a fit. The per-sample arithmetic is
the same (``kinematics_kernel``, ``cp_air_kernel``, the order of operations of ``_model_terms``), the step is
LAPACK's least squares as numpy's (same rcond), so the fits agree to ~1e-14 rad.

The step's least squares is LAPACK's dgelsd called directly (``least_squares_kernel``), the routine and the library
numba's ``np.linalg.lstsq`` calls, with its arguments: the same bits, without lstsq's general wrapper (its 1-D/2-D
right-hand sides, residuals, singular values, and its errors' formatted messages), which was ~2/3 of this kernel's
cold compile (design note 130).
"""

from __future__ import annotations

import math

import llvmlite.binding as llvm
import numba
import numpy as np
from frictionwatch.core.model.kinematics import kinematics_kernel
from frictionwatch.core.model.thermo import (
    N_MOTORED,
    R_AIR,
    WALL_AREA_HEAD_PISTON,
    WOSCHNI_C1,
    WOSCHNI_C2,
    WOSCHNI_SCALE,
    cp_air_kernel,
)
from numba import types
from numba.extending import get_cython_function_address

# layout of the constants array (``tdc._constants``)
(C_R, C_L, C_E, C_AREA, C_CLEAR, C_DISP, C_BORE, C_IVC, C_TIVC, C_TWALL, C_OMEGA, C_PIVC, C_SOC, C_HEAT,
 N_CONST) = range(15)
EPS = 2.220446049250313e-16  # float64 machine epsilon

# LAPACK dgelsd(m, n, nrhs, a, lda, b, ldb, s, rcond, rank, work, lwork, iwork, info), all by pointer, bound by
# symbol name from scipy.linalg.cython_lapack, where numba's np.linalg.lstsq finds it (as spd.py binds dpotri: a
# cached kernel resolves the name when it is loaded)
llvm.add_symbol("frictionwatch_dgelsd", get_cython_function_address("scipy.linalg.cython_lapack", "dgelsd"))
_dgelsd = types.ExternalFunction("frictionwatch_dgelsd", types.void(*([types.voidptr] * 14)))
# the int32 arguments' places in one array
(D_M, D_N, D_NRHS, D_LDA, D_LDB, D_RANK, D_LWORK, D_INFO, D_LIWORK, N_DIMS) = range(10)


@numba.njit(cache=True)
def least_squares_kernel(a, b, rcond):
    """x (n,) = ``np.linalg.lstsq(a, b, rcond)[0]`` of numba for a (m, n) and b (m,), its bits: LAPACK dgelsd on
    the same copies (a in Fortran order, b in a column of max(m, n)), the workspace of dgelsd's own query, as numba's
    helper sizes it. Raises np.linalg.LinAlgError where numba's would (a non-finite entry, an SVD that did not
    converge), with a plain message."""
    m, n = a.shape
    for i in range(m):
        for j in range(n):
            if not np.isfinite(a[i, j]):
                raise np.linalg.LinAlgError("Array must not contain infs or NaNs.")
    for i in range(m):
        if not np.isfinite(b[i]):
            raise np.linalg.LinAlgError("Array must not contain infs or NaNs.")
    if m == 0 or n == 0 or b.shape[0] != m:
        raise np.linalg.LinAlgError("an empty or mismatched system")
    big = max(m, n)
    acpy = np.empty((n, m))  # C-order (n, m) is Fortran-order (m, n)
    for i in range(m):
        for j in range(n):
            acpy[j, i] = a[i, j]
    x = np.empty(big)
    for i in range(m):  # a loop: a slice's assignment compiles numba's shape-mismatch message (its string formatting)
        x[i] = b[i]
    s = np.empty(min(m, n))
    cond = np.array([rcond])
    dims = np.zeros(N_DIMS, dtype=np.int32)
    dims[D_M], dims[D_N], dims[D_NRHS], dims[D_LDA], dims[D_LDB], dims[D_LWORK] = m, n, 1, m, big, -1
    query = np.empty(1)
    _dgelsd(dims[D_M:].ctypes, dims[D_N:].ctypes, dims[D_NRHS:].ctypes, acpy.ctypes, dims[D_LDA:].ctypes, x.ctypes,
            dims[D_LDB:].ctypes, s.ctypes, cond.ctypes, dims[D_RANK:].ctypes, query.ctypes, dims[D_LWORK:].ctypes,
            dims[D_LIWORK:].ctypes, dims[D_INFO:].ctypes)
    if dims[D_INFO] != 0:
        raise np.linalg.LinAlgError("dgelsd's workspace query failed")
    work = np.empty(int(query[0]))  # numba's helper truncates the query's double likewise
    iwork = np.empty(max(dims[D_LIWORK], 1), dtype=np.int32)
    dims[D_LWORK] = work.shape[0]
    _dgelsd(dims[D_M:].ctypes, dims[D_N:].ctypes, dims[D_NRHS:].ctypes, acpy.ctypes, dims[D_LDA:].ctypes, x.ctypes,
            dims[D_LDB:].ctypes, s.ctypes, cond.ctypes, dims[D_RANK:].ctypes, work.ctypes, dims[D_LWORK:].ctypes,
            iwork.ctypes, dims[D_INFO:].ctypes)
    if dims[D_INFO] != 0:
        raise np.linalg.LinAlgError("SVD did not converge in Linear Least Squares")
    return x[:n].copy()


@numba.njit(cache=True)
def residual_kernel(p, dp, ang, delta, peg, c, out):
    """out (m,) = net apparent ROHR + Woschni wall heat [J/rad] of the mean pressure p (m,), dp/dtheta (m,) at the
    angles ang - delta (m,), pressure + peg (``tdc._model_terms`` summed, sample by sample); c: the constants."""
    pegs = np.empty(1)
    pegs[0] = peg
    residuals_kernel(p, dp, ang, delta, pegs, c, out.reshape((1, out.shape[0])))


@numba.njit(cache=True)
def residuals_kernel(p, dp, ang, delta, pegs, c, out):
    """out (k, m): ``residual_kernel`` at one delta and k peggings pegs (k,), each row the same numbers as alone.
    What depends on delta only (the kinematics, the volumes, the motored polytrope's volume ratio, the wall area) is
    evaluated once for all k: the Gauss-Newton step's residual and its pegging column share it (~1/3 of a fit's
    kinematics and a pow per sample after the start of combustion)."""
    m = ang.shape[0]
    kin = c[C_R:C_E + 1]
    shifted = np.empty(m)
    for i in range(m):
        shifted[i] = ang[i] - delta
    x, dx, ddx = np.empty(m), np.empty(m), np.empty(m)
    kinematics_kernel(shifted, kin, x, dx, ddx)
    ivc = np.empty(1)
    ivc[0] = c[C_IVC] - delta
    xi, dxi, ddxi = np.empty(1), np.empty(1), np.empty(1)
    kinematics_kernel(ivc, kin, xi, dxi, ddxi)
    area = c[C_AREA]
    v_ivc = c[C_CLEAR] + area * xi[0]
    omega = c[C_OMEGA]
    cbar = c[C_DISP] / area * omega / math.pi
    h0 = WOSCHNI_SCALE * 3.26 * c[C_BORE] ** -0.2
    n_peg = pegs.shape[0]
    p_ivc, mass, burn = np.empty(n_peg), np.empty(n_peg), np.empty(n_peg)
    for j in range(n_peg):
        p_ivc[j] = max(c[C_PIVC] + pegs[j], 1e3)
        mass[j] = p_ivc[j] * v_ivc / (R_AIR * c[C_TIVC])
        burn[j] = WOSCHNI_C2 * c[C_DISP] * c[C_TIVC] / (p_ivc[j] * v_ivc)
    for i in range(m):
        vol = c[C_CLEAR] + area * x[i]
        dvol = area * dx[i]
        burning = shifted[i] > c[C_SOC]
        polytrope = (v_ivc / vol) ** N_MOTORED if burning else 0.0
        area_w = WALL_AREA_HEAD_PISTON * area + math.pi * c[C_BORE] * vol / area
        for j in range(n_peg):
            pc = max(p[i] + pegs[j], 1e3)
            temp = pc * vol / (mass[j] * R_AIR)
            cp = cp_air_kernel(temp)
            gamma = cp / (cp - R_AIR)
            q = (gamma * pc * dvol + vol * dp[i]) / (gamma - 1.0)
            w = WOSCHNI_C1 * cbar + (burn[j] * max(pc - p_ivc[j] * polytrope, 0.0) if burning else 0.0)
            h = h0 * (pc * 1e-3) ** 0.8 * temp ** -0.55 * w ** 0.8
            out[j, i] = q + c[C_HEAT] * h * area_w * (temp - c[C_TWALL]) / omega


@numba.njit(cache=True)
def gauss_newton_kernel(p, dp, ang, c, start, steps):
    """(delta, peg) of ``tdc._gauss_newton`` from the mean of the rows of p, dp (k, m) at the window angles ang (m,)
    from start = [delta, peg, constant_loss (0/1)]; steps = [iterations, FD delta, FD peg, max step, stop]."""
    k, m = p.shape
    pm, dpm = np.zeros(m), np.zeros(m)
    for j in range(k):
        for i in range(m):
            pm[i] += p[j, i]
            dpm[i] += dp[j, i]
    for i in range(m):
        pm[i] /= k
        dpm[i] /= k
    delta, peg = start[0], start[1]
    n_col = 3 if start[2] != 0.0 else 2
    both, moved = np.empty((2, m)), np.empty((1, m))  # (r, rp) at delta, rd at delta + FD
    r, rp, rd = both[0], both[1], moved[0]
    pegs, peg_alone = np.empty(2), np.empty(1)
    jac = np.ones((m, n_col))
    for _ in range(int(steps[0])):
        pegs[0], pegs[1], peg_alone[0] = peg, peg + steps[2], peg
        residuals_kernel(pm, dpm, ang, delta, pegs, c, both)
        residuals_kernel(pm, dpm, ang, delta + steps[1], peg_alone, c, moved)
        for i in range(m):
            jac[i, 0] = (rd[i] - r[i]) / steps[1]
            jac[i, 1] = (rp[i] - r[i]) / steps[2]
        sol = least_squares_kernel(jac, -r, EPS * max(m, n_col))  # numpy's rcond=None
        delta += min(max(sol[0], -steps[3]), steps[3])
        peg += sol[1]
        if abs(sol[0]) < steps[4]:
            break
    return delta, peg
