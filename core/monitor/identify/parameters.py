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

Priors (physics.md §9, §10: 'a weak prior: commissioning baseline or siblings'):
- weak: each parameter scale params ~ N(1, parameter_sigma^2) about the baseline a0 (core.monitor.identify.parameters);
- tooth-spacing nuisances E_n ~ N(0, s^2 2/N_edges): white per-tooth errors of rms s (core.monitor.identify.parameters.tooth_patterns);
- siblings: each per-cylinder scale within sibling_spread of the mean of its siblings (same parts in every cylinder;
  the only prior that speaks for directions the speed cannot see, e.g. the contrast of cylinders 360 deg apart);
- Eq. 6 sharing of the measured mean loss (core.monitor.identify.parameters), per cylinder, added per cycle.

Eq. 6: Sharing of the mean loss among cylinders, non-firing cylinders included (paper 000 Eq. 6; physics.md §9).

Firing cylinder k:  T_fM^k = T'_fM * T_iM^k / T'_iM,  with T'_iM = sum over firing cylinders of T_iM^k and
                    T'_fM = T_fM - N_ml * T_fM,ml.
Motored cylinder:   T_fM^k = T_fM,ml, the motored friction of one cylinder at the same mean speed.

The proportional rule is an assumption (more indicated work, more ring and bearing load). The monitor uses it only
as a prior with a stated spread and reports how far the identified means move away from it.

The numba kernels of the Eq. 6 sharing (first below) and of its prior rows in normal form
(core.monitor.identify.parameters.PriorNormal.with_share). The numpy references are in tests/core/test_monitor_kernels.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.terms import TermLibrary, rezeka_henein
from frictionwatch.core.monitor.identify.posterior import Prior

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
        # the parameter count P, a plain attribute (read ~7 times a cycle, from the balance, the report and here: as a
        # property each read was a call into this file; design note 82)
        object.__setattr__(self, "n_params", p)
        # the library's term count L, likewise (the balance sizes its basis by it every cycle: a call into
        # core/model/terms.py each time as len(library))
        object.__setattr__(self, "n_terms", len(self.library))

    def coefficients(self, theta: np.ndarray) -> np.ndarray:
        return self.prior * np.asarray(theta)[self.group]

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
    return (layout._collapse_matrix.T @ per_coef.reshape(z * n_terms, m)).T  # (M, P): per coefficient, weighted by the prior, summed into its parameter


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
    return fmep_bar * 1e5 / spec.mep_per_torque_cyl  # spec.mep_to_torque(..., cylinders=1), its arithmetic


# Eq. 6's defaults (share_mean_loss; identify.step passes the same to its kernel): a motored cylinder's T_fM,ml
# known to 30 % (1 sigma), and a cylinder fires when its indicated work is above 15 % of the median of the positive ones
MOTORED_SPREAD = 0.3
FIRING_FRACTION = 0.15


def firing_mask(indicated_mean: np.ndarray, fraction: float = FIRING_FRACTION) -> np.ndarray:
    """True for cylinders that fire: indicated work above ``fraction`` of the median of the positive ones."""
    t = np.ascontiguousarray(indicated_mean, dtype=np.float64)
    return firing_kernel(t.reshape(-1), float(fraction)).reshape(t.shape)


def share_mean_loss(
    friction_total: float,
    indicated_mean: np.ndarray,
    motored_friction: float,
    spread: float = 0.15,
    motored_spread: float = MOTORED_SPREAD,
    fraction: float = FIRING_FRACTION,
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
