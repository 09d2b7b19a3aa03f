"""Friction identification as a bounded, equality-constrained linear least squares (physics.md §8, §10, §12).

With the pressure measured and the omega-dependent factors frozen at the current estimate of each throw's motion,
the flywheel speed harmonics are affine in the coefficients a_kl (physics.md §12.2):

    W_meas,m = W0_m - sum_{k,l} a_kl H_m,node(k) Fhat_kl,m  (+ noise),   m = 1..M,

with H_m the speed transfer of the torsional chain (core.model.dynamics; a rigid engine is its one-node case) and W0 the
response to the known torques. The cycle's mean balance adds one row: sum_kl a_kl <F_kl> = T_fM.

Parametrisation (physics.md §12.5). Six free terms per cylinder are not identifiable on a multi-cylinder engine (F3 and
F4 have 0.99-correlated speed signatures, F5 has none). A ``ParameterLayout`` groups coefficients: a_kl = a0_kl *
theta_g(k,l), theta >= 0, where a0 is the prior (commissioning baseline or the preset's values) and each group shares
one scale. The default for multi-cylinder engines ('piston_group') scales the piston-assembly terms F1 ring viscous,
F2 ring mixed and F3 skirt per cylinder - the group ring wear changes - and shares F4, F5, F6 engine-wide. Why not
F1+F2+F6 as physics.md §12.5 suggests: with F3 engine-wide, a worn cylinder's skirt/ring increase has to be fitted
with the F6 (bearing) shape, which projects onto it with the wrong sign (measured: a worn cylinder read 5-10 % low).
A single-cylinder engine identifies all six a_l (paper 000 Eq. 5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.linalg.lapack
import scipy.optimize
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.terms import TermLibrary, rezeka_henein
from frictionwatch.core.monitor.identify.posterior_kernels import OK, as_vector, bounded_solve_kernel, lower_vector

_getrf = scipy.linalg.lapack.dgetrf
_getrs = scipy.linalg.lapack.dgetrs
_trtrs = scipy.linalg.lapack.dtrtrs
SCHEMES = ("all", "pressure_group", "piston_group", "scale")


@dataclass(frozen=True)
class ParameterLayout:
    """Map from parameters theta (P,) to coefficients a (z, L) of the L terms of ``library``:
    a_kl = prior[k, l] * theta[group[k, l]].

    names (P,) describe each parameter, e.g. 'cyl3:F1+F2+F3' or 'all:F4' (F_l+1 = library term l); per_cylinder (P,)
    bool; library the loss terms (core.model.terms) the simulator, the balance and the layout share.
    """

    scheme: str
    group: np.ndarray
    prior: np.ndarray
    names: tuple[str, ...]
    per_cylinder: np.ndarray
    library: TermLibrary

    def __post_init__(self) -> None:
        # precomputed scatter maps (not fields: equality and replace() see only the layout itself)
        z = self.group.shape[0]
        p = len(self.names)
        g = self.group.ravel()
        used = g >= 0
        flat = (np.arange(z)[:, None] * p + self.group).ravel()
        object.__setattr__(self, "_cyl_index", np.where(used, flat, z * p))  # unused terms go to a spill bin
        weights = np.zeros((g.size, p))
        weights[np.flatnonzero(used), g[used]] = np.asarray(self.prior, dtype=np.float64).ravel()[used]
        object.__setattr__(self, "_collapse_matrix", weights)  # (z*L, P): a0_kl where (k, l) is in group p

    @property
    def n_params(self) -> int:
        return len(self.names)

    def coefficients(self, theta: np.ndarray) -> np.ndarray:
        return self.prior * np.asarray(theta)[self.group]

    def collapse(self, per_coefficient: np.ndarray) -> np.ndarray:
        """Sum a per-coefficient quantity (..., z, L), weighted by the prior, into parameters (..., P)."""
        x = np.asarray(per_coefficient) * self.prior
        out = np.zeros(x.shape[:-2] + (self.n_params,), dtype=x.dtype)
        flat = x.reshape(x.shape[:-2] + (-1,))
        for p in range(self.n_params):
            out[..., p] = flat[..., self.group.ravel() == p].sum(axis=-1)
        return out

    def cylinder_rows(self, basis_mean: np.ndarray) -> np.ndarray:
        """(z, P): d(mean friction of cylinder k)/d theta_p, given work means <F_kl> (z, L)."""
        z = self.group.shape[0]
        p = self.n_params
        contrib = self.prior * basis_mean
        # the same additions, in the same order, as one scatter per cylinder
        rows = np.bincount(self._cyl_index, weights=contrib.ravel(), minlength=z * p + 1)
        return rows[: z * p].reshape(z, p)


def parameter_layout(spec: EngineSpec, scheme: str | None = None, prior: np.ndarray | None = None,
                     library: TermLibrary | None = None) -> ParameterLayout:
    """Group the z x L coefficients of ``library`` on ``spec`` (default library: the six Rezeka-Henein terms with the
    preset's ``friction.coefficients`` as priors; default scheme: 'all' for one cylinder, else 'piston_group').

    Schemes: 'all' every coefficient its own parameter; 'piston_group' the terms of group "cylinder" one scale per
    cylinder, each "engine" term one scale for all cylinders; 'pressure_group' the same with the per-cylinder set
    ring_viscous, ring_mixed, loaded_bearings (physics.md §12.5); 'scale' one scale per cylinder for all its terms.
    prior : (L,) or (z, L) baseline coefficients a0 (default: the library's priors). A zero prior coefficient keeps
    that term out of the model.
    """
    lib = rezeka_henein(spec.friction.coefficients) if library is None else library
    z = spec.n_cyl
    n_terms = len(lib)
    if scheme is None:
        scheme = "all" if z == 1 else "piston_group"
    if scheme not in SCHEMES:
        raise ValueError(f"unknown parameter scheme {scheme!r}; choose one of {', '.join(SCHEMES)}")
    a0 = np.asarray(lib.priors if prior is None else prior, dtype=np.float64)
    try:
        a0 = np.broadcast_to(a0, (z, n_terms)).copy()
    except ValueError:
        raise ValueError(f"prior must be ({n_terms},) or ({z}, {n_terms}) for the library's terms, got {a0.shape}"
                         ) from None
    if np.any(a0 < 0) or not np.all(np.isfinite(a0)):
        raise ValueError("prior coefficients must be finite and >= 0")
    if scheme == "pressure_group":
        per_cyl_terms = tuple(lib.index(name) for name in ("ring_viscous", "ring_mixed", "loaded_bearings"))
    elif scheme == "piston_group":
        per_cyl_terms = tuple(int(i) for i in np.flatnonzero(lib.per_cylinder))
    else:
        per_cyl_terms = tuple(range(n_terms))
    group = np.full((z, n_terms), -1, dtype=np.int64)
    names: list[str] = []
    per_cylinder: list[bool] = []
    if scheme == "all":
        for k in range(z):
            for term in range(n_terms):
                group[k, term] = len(names)
                names.append(f"cyl{k + 1}:F{term + 1}")
                per_cylinder.append(True)
    else:
        label = "+".join(f"F{t + 1}" for t in per_cyl_terms)
        if per_cyl_terms:
            for k in range(z):
                group[k, list(per_cyl_terms)] = len(names)
                names.append(f"cyl{k + 1}:{label}")
                per_cylinder.append(True)
        for term in range(n_terms):
            if term not in per_cyl_terms:
                group[:, term] = len(names)
                names.append(f"all:F{term + 1}")
                per_cylinder.append(False)
    return ParameterLayout(scheme=scheme, group=group, prior=a0, names=tuple(names),
                           per_cylinder=np.array(per_cylinder), library=lib)


@dataclass(frozen=True)
class CycleRows:
    """One cycle's identification equations in parameter space (raw units, before weighting).

    design (M, P) complex [rad/s]: d W_model,m / d theta_p; target (M,) complex [rad/s]: W_meas - W0
    mean_row (P,) [N m]: d T_fM / d theta; mean_target [N m]: T_fM from the balance
    cylinder_rows (z, P) [N m]: d T_fM,k / d theta
    """

    design: np.ndarray
    target: np.ndarray
    mean_row: np.ndarray
    mean_target: float
    cylinder_rows: np.ndarray


def friction_design(layout: ParameterLayout, transfer: np.ndarray, basis_harm: np.ndarray,
                    cylinder_node: np.ndarray) -> np.ndarray:
    """(M, P) complex: flywheel speed harmonics per unit theta_p, -sum_{kl in p} a0_kl H_m,node(k) Fhat_kl,m.

    transfer (M, N) flywheel speed per node torque; basis_harm (z, L, M)."""
    h = transfer[:, cylinder_node]  # (M, z)
    per_coef = -h.T[:, None, :] * basis_harm  # (z, L, M)
    z, n_terms, m = per_coef.shape
    return (layout._collapse_matrix.T @ per_coef.reshape(z * n_terms, m)).T  # (M, P), = layout.collapse


def tooth_patterns(tooth_angle: np.ndarray, n_orders: int) -> np.ndarray:
    """(edges, 2 n_orders) angle patterns cos(n theta), sin(n theta) at the edges, n = 1..n_orders per revolution.

    Tooth-spacing errors are fixed in angle and repeat every revolution, so inside the model band they look like a
    steady engine response at integer orders (physics.md §14.3): at one operating point they can only be carried as
    nuisances E_n (two real numbers per order) with a prior of their expected size. Passed through the flywheel fit
    (``fit_flywheel(patterns=...)``) they become exact columns of the speed equations."""
    th = np.asarray(tooth_angle, dtype=np.float64)
    n = np.arange(1, n_orders + 1)
    arg = np.outer(th - th[0], n)
    out = np.empty((th.shape[0], 2 * n_orders))
    out[:, 0::2] = np.cos(arg)
    out[:, 1::2] = np.sin(arg)
    return out


def whiten(rows: CycleRows, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Real weighted rows (2M, P) and targets (2M,) with per-harmonic noise sigma (M,) [rad/s per component]."""
    a = np.concatenate([rows.design.real, rows.design.imag]) / np.concatenate([sigma, sigma])[:, None]
    y = np.concatenate([rows.target.real, rows.target.imag]) / np.concatenate([sigma, sigma])
    return a, y


def bounded_solve(info: np.ndarray, rhs: np.ndarray, lower: float | np.ndarray = 0.0) -> np.ndarray:
    """argmin_{theta >= lower} theta^T info theta - 2 rhs^T theta for a symmetric positive-definite ``info``.

    ``lower`` may be -inf for free parameters (nuisances): they are eliminated exactly (Schur complement) before the
    bounded part is solved and recovered after. Never forms a least-squares problem from raw rows: it factors the
    (already accumulated) information matrix, column-scaled to unit diagonal (physics.md §8). The problem is convex:
    when its unconstrained minimiser meets the bounds it is the answer (core.monitor.identify.posterior_kernels); otherwise, or when
    the factors are nearly singular, NNLS on the triangular factor decides (``bounded_solve_nnls``)."""
    info = np.asarray(info, dtype=np.float64)
    n = info.shape[0]
    if info.shape == (n, n):
        lo = lower_vector(lower, n)
        status, theta = bounded_solve_kernel(np.ascontiguousarray(info), as_vector(rhs, n, "rhs"), lo)
        if status == OK:
            return theta
    return bounded_solve_nnls(info, rhs, lower)


def bounded_solve_nnls(info: np.ndarray, rhs: np.ndarray, lower: float | np.ndarray = 0.0) -> np.ndarray:
    """``bounded_solve`` by NNLS on the Cholesky factor of the reduced, unit-diagonal information matrix: the
    general path (a bound active, nearly singular factors) and the reference of the fast one."""
    n = info.shape[0]
    lo = np.broadcast_to(np.asarray(lower, dtype=np.float64), (n,))
    free = ~np.isfinite(lo)
    n_free = int(free.sum())
    d = np.sqrt(np.clip(np.diag(info), 1e-300, None))
    s = info / np.outer(d, d)
    r = rhs / d
    if 0 < n_free < n and free[n - n_free:].all():  # nuisances last (the monitor's layout): plain slices
        nb = n - n_free
        bnd = slice(0, nb)
        fre = slice(nb, n)
    else:
        bnd = np.flatnonzero(~free)
        fre = np.flatnonzero(free)
    s_bb = s[bnd][:, bnd] if isinstance(bnd, np.ndarray) else s[bnd, bnd]
    out = np.empty(n)
    if n_free:
        s_ff = (s[fre][:, fre] if isinstance(fre, np.ndarray) else s[fre, fre]) + 1e-12 * np.eye(n_free)
        s_bf = s[bnd][:, fre] if isinstance(bnd, np.ndarray) else s[bnd, fre]
        lu, piv, _ = _getrf(s_ff)  # one factorisation for the three solves
        x_ff = _getrs(lu, piv, np.column_stack([s_bf.T, r[fre]]))[0]
        s_red = s_bb - s_bf @ x_ff[:, :-1]
        r_red = r[bnd] - s_bf @ x_ff[:, -1]
    else:
        s_red, r_red = s, r
    if n_free < n:
        lo_x = lo[bnd] * d[bnd]
        chol = np.linalg.cholesky(s_red + 1e-12 * np.eye(s_red.shape[0]))  # s = L L^T
        y = _trtrs(chol, r_red, lower=1)[0]
        # min ||L^T x - y||^2 with x >= lo_x: substitute x = x' + lo_x
        x, _ = scipy.optimize.nnls(chol.T, y - chol.T @ lo_x, maxiter=50 * s_red.shape[0])
        out[bnd] = x + lo_x
    if n_free:
        out[fre] = _getrs(lu, piv, r[fre] - s_bf.T @ out[bnd])[0]
    return out / d


def p_omega_fit(basis: np.ndarray, friction: np.ndarray, mean_row: np.ndarray | None = None,
                mean_target: float | None = None, mean_weight: float = 1e6) -> np.ndarray:
    """Paper 000 Eq. 5 with a >= 0: fit a (6,) to a measured friction trace T_F (p,) = F (p, 6) a.

    Column-scaled, bounded (NNLS); the mean condition sum_l a_l <F_l> = T_fM (paper 000 Eq. 7) enters as a heavily
    weighted row (``mean_weight`` times the rms of the equations), i.e. an equality to working precision."""
    f = np.asarray(basis, dtype=np.float64)
    t = np.asarray(friction, dtype=np.float64)
    if f.ndim != 2 or f.shape[0] != t.shape[0]:
        raise ValueError(f"basis must be (p, n_terms) matching friction (p,), got {f.shape} and {t.shape}")
    scale = np.sqrt(np.mean(f * f, axis=0))
    keep = scale > 0
    a_mat = f[:, keep] / scale[keep]
    b = t
    if mean_row is not None and mean_target is not None:
        wgt = mean_weight / np.sqrt(a_mat.shape[0])
        a_mat = np.vstack([a_mat, wgt * np.asarray(mean_row)[keep] / scale[keep]])
        b = np.append(b, wgt * mean_target)
    x, _ = scipy.optimize.nnls(a_mat, b, maxiter=100 * a_mat.shape[1])
    out = np.zeros(f.shape[1])
    out[keep] = x / scale[keep]
    return out
