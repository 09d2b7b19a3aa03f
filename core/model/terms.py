"""The library of named mechanical-loss (friction) terms of a cylinder (paper 000 Eq. 4; physics.md §7).

The friction torque of cylinder k is T_f,k = sum_l a_kl F_l(samples_k), every F_l >= 0. A ``LossTerm`` is one F_l:
its name, its physics (a plain-numpy ``reference`` written from the equation and one numba ``kernel`` with the same
numbers), the group the monitor scales it with by default ("cylinder": one scale per cylinder, "engine": one scale
shared by all cylinders), the unit of its coefficient and a prior coefficient. A ``TermLibrary`` is an ordered tuple of
terms; libraries compose with ``+`` (after pysindy's feature libraries), so a model gains a term without any solver
being edited: the simulator (core.plant.plant) and the monitor's harmonic balance (core.monitor.balance.harmonic_balance)
both evaluate whatever library the model carries, and the number of terms is ``len(library)`` everywhere.

    lib = rezeka_henein(spec.friction.coefficients) + my_term
    samples = cylinder_samples(local_angle, omega, p_gauge, spec.friction_params())   # (N_FIELDS, n)
    basis = lib.evaluate(samples, spec.friction_params())                              # (len(lib), n)

Every term reads the same sample rows (``FIELDS``), so one set of kinematics serves the whole library:

    ANGLE    local crank angle of the cylinder [rad], wrapped into [0, 4 pi), 0 = its firing TDC
    SIN, COS sin and cos of ANGLE
    DX, DDX  x'(angle) [m/rad] and x''(angle) [m/rad^2]: piston displacement derivatives (physics.md §1)
    OMEGA    angular speed of the cylinder's throw [rad/s], floored at OMEGA_FLOOR
    P_GAUGE  cylinder gauge pressure max(p - p_cc, 0) [Pa]

and the engine's constants ``EngineSpec.friction_params()`` (``CONSTS`` names them). A kernel evaluates every
cylinder at once: ``kernel(samples (N_FIELDS, z, n), consts (N_CONSTS,), out (z, n))`` writes F_l of cylinder k at
sample i into out[k, i] (the monitor passes a cycle's time grid, n = 256..512; the plant one instant, n = 1).
``fill_sample`` is the one numba routine that forms a sample (kinematics from the angle's sin and cos), into the
row views ``sample_rows`` gives.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numba
import numpy as np
from frictionwatch.core.model.jit import BORROWING

FIELDS = ("angle", "sin", "cos", "dx", "ddx", "omega", "p_gauge")
ANGLE, SIN, COS, DX, DDX, OMEGA, P_GAUGE = range(len(FIELDS))
N_FIELDS = len(FIELDS)
CONSTS = ("crank_radius", "conrod", "pin_offset", "bore", "oil_viscosity", "ring_tension", "ring_thickness",
          "compression_rings", "oil_rings", "skirt_length", "skirt_film", "valves", "valve_spring", "bearing_radius")
(R, L, E, D, MU, PE, ETH, NC, NO, LFP, GA, NV, LS, RB) = range(len(CONSTS))
N_CONSTS = len(CONSTS)
GROUPS = ("cylinder", "engine")
FOUR_PI = 4.0 * np.pi
OMEGA_FLOOR = 1e-3  # rad/s: the terms with 1/sqrt(omega) stay finite on a stopped shaft
# every term kernel has this one signature, compiled eagerly: then a tuple of them is a tuple of first-class
# functions of one type, which the plant's cached RK4 kernel iterates (core.plant.plant) whatever the library holds
KERNEL_SIGNATURE = numba.types.void(numba.types.float64[:, :, ::1], numba.types.float64[::1],
                                    numba.types.float64[:, ::1])


def loss_kernel(func: Callable | None = None, *, divides_by_floored_speed: bool = False) -> Callable:
    """Decorator of a term kernel ``func(samples, consts, out)``: numba-compiled with ``KERNEL_SIGNATURE``, cached,
    borrowing its arrays (core.model.jit: the plant calls each kernel per RK4 stage, so the kernel must not allocate).

    ``divides_by_floored_speed``: the kernel's only divisors are sqrt(OMEGA), OMEGA floored at OMEGA_FLOOR, so no
    division is by zero; it is compiled with numba's numpy error model, which drops the zero test the default
    (python) model puts before every float division and so lets the loop vectorise: the same IEEE quotients and
    square roots, bit for bit (tests/core/test_terms.py), ~7x faster on genset-v20's (20, 192) samples (10.6 ->
    1.5 us a call; design note 46). A kernel that could divide by zero keeps the default (it raises there)."""
    def compiled(f: Callable) -> Callable:
        options = dict(BORROWING, error_model="numpy") if divides_by_floored_speed else BORROWING
        return numba.njit(KERNEL_SIGNATURE, **options)(f)

    return compiled if func is None else compiled(func)


@dataclass(frozen=True)
class LossTerm:
    """One friction basis term F_l (see the module docstring for ``kernel`` and ``reference``)."""

    name: str
    equation: str  # F_l in words and symbols, for reports
    group: str  # "cylinder" or "engine": the monitor's default scaling of this term
    unit: str  # SI unit of the coefficient a_l (a_l F_l is a torque in N m)
    prior: float  # coefficient used when an engine states none (0: the term is off until a prior is given)
    kernel: Callable[[np.ndarray, np.ndarray, np.ndarray], None]
    reference: Callable[[np.ndarray, np.ndarray], np.ndarray]

    def __post_init__(self) -> None:
        sigs = getattr(self.kernel, "signatures", None)
        if not sigs or KERNEL_SIGNATURE.args not in [tuple(sig) for sig in sigs]:
            raise ValueError(f"term {self.name!r}: the kernel must be compiled with KERNEL_SIGNATURE (@loss_kernel)")
        if self.group not in GROUPS:
            raise ValueError(f"term {self.name!r}: group must be one of {GROUPS}, got {self.group!r}")
        if not (np.isfinite(self.prior) and self.prior >= 0):
            raise ValueError(f"term {self.name!r}: prior must be finite and >= 0, got {self.prior!r}")


@dataclass(frozen=True)
class TermLibrary:
    """An ordered, composable set of loss terms with distinct names."""

    terms: tuple[LossTerm, ...]

    def __post_init__(self) -> None:
        names = [t.name for t in self.terms]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"a term library holds each term once; repeated: {', '.join(dup)}")

    def __add__(self, other: TermLibrary | LossTerm) -> TermLibrary:
        extra = (other,) if isinstance(other, LossTerm) else other.terms
        return TermLibrary(self.terms + extra)

    def __len__(self) -> int:
        return len(self.terms)

    def __iter__(self) -> Iterator[LossTerm]:
        return iter(self.terms)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.terms)

    @property
    def kernels(self) -> tuple:
        """The terms' numba kernels in order (the plant iterates them with numba.literal_unroll)."""
        return tuple(t.kernel for t in self.terms)

    @property
    def priors(self) -> np.ndarray:
        """(len,) the terms' prior coefficients."""
        return np.array([t.prior for t in self.terms], dtype=np.float64)

    @property
    def per_cylinder(self) -> np.ndarray:
        """(len,) bool: the terms of group "cylinder" (scaled per cylinder by default; the rest engine-wide)."""
        return np.array([t.group == "cylinder" for t in self.terms], dtype=np.bool_)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no loss term {name!r}; the library has {', '.join(self.names)}") from None

    def evaluate_into(self, samples: np.ndarray, consts: np.ndarray, out: np.ndarray) -> None:
        """out[l] = F_l (z, n) for samples (N_FIELDS, z, n), consts (N_CONSTS,), out (len, z, n), all C-contiguous
        float64: each term's kernel, no checks (the monitor's per-pass call; ``evaluate`` is the checked form)."""
        for i, term in enumerate(self.terms):
            term.kernel(samples, consts, out[i])

    def evaluate(self, samples: np.ndarray, consts: np.ndarray) -> np.ndarray:
        """Basis F (len, n) of one cylinder from samples (N_FIELDS, n), or (z, len, n) from (N_FIELDS, z, n)."""
        s, c = _checked(samples, consts)
        out = np.empty((len(self.terms), s.shape[1], s.shape[2]))
        self.evaluate_into(s, c, out)
        return out[:, 0] if np.ndim(samples) == 2 else out.transpose(1, 0, 2)

    def evaluate_reference(self, samples: np.ndarray, consts: np.ndarray) -> np.ndarray:
        """The same basis from each term's plain-numpy reference."""
        s, c = _checked(samples, consts)
        out = np.stack([t.reference(s, c) for t in self.terms], axis=1) if self.terms else np.empty(
            (s.shape[1], 0, s.shape[2]))
        return out[0] if np.ndim(samples) == 2 else out

    def equations(self, coefficients: np.ndarray, label: str = "T_f") -> str:
        """``T_f = 12.8·ring_viscous + ...``: the fitted friction law in words (pysindy's ``equations``)."""
        coef = np.asarray(coefficients, dtype=np.float64)
        if coef.shape != (len(self.terms),):
            raise ValueError(f"expected {len(self.terms)} coefficients, got shape {coef.shape}")
        return f"{label} = " + " + ".join(f"{a:.4g}·{t.name}" for a, t in zip(coef, self.terms))


def _checked(samples: np.ndarray, consts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = np.asarray(samples, dtype=np.float64)
    if s.ndim == 2:
        s = s[:, None, :]
    s = np.ascontiguousarray(s)
    c = np.ascontiguousarray(consts, dtype=np.float64)
    if s.ndim != 3 or s.shape[0] != N_FIELDS:
        raise ValueError(f"samples must be ({N_FIELDS}, n) or ({N_FIELDS}, z, n) rows {FIELDS}, got {s.shape}")
    if c.shape != (N_CONSTS,):
        raise ValueError(f"consts must be EngineSpec.friction_params() ({N_CONSTS} values), got shape {c.shape}")
    return s, c


@numba.njit(cache=True, inline="always")
def fill_sample(rows, i, angle, sin_a, cos_a, omega, p_gauge, r, inv_rod, e):
    """Sample i into ``rows``, the N_FIELDS row views (n,) of one cylinder (``sample_rows``): the wrapped angle, its
    sin and cos (given: the monitor rotates them from the flywheel's), x' and x'' of the slider crank (physics.md
    §1; core.model.kinematics with the divisions by L and cos(beta) as products), the floored speed and the clipped
    gauge pressure. Returns (x', x'') for the gas and reciprocating torques."""
    sb = (r * sin_a - e) * inv_rod
    cb = np.sqrt(1.0 - sb * sb)
    icb = 1.0 / cb
    tb = sb * icb
    dx = r * sin_a + r * cos_a * tb
    ddx = r * cos_a - r * sin_a * tb + r * r * cos_a * cos_a * inv_rod * (icb * icb * icb)
    rows[ANGLE][i] = angle - FOUR_PI * np.floor(angle * (1.0 / FOUR_PI))
    rows[SIN][i] = sin_a
    rows[COS][i] = cos_a
    rows[DX][i] = dx
    rows[DDX][i] = ddx
    rows[OMEGA][i] = max(omega, OMEGA_FLOOR)
    rows[P_GAUGE][i] = max(p_gauge, 0.0)
    return dx, ddx


@numba.njit(cache=True, inline="always")
def sample_rows(samples, k):
    """The N_FIELDS row views (n,) of cylinder k in samples (N_FIELDS, z, n), for ``fill_sample``."""
    return (samples[ANGLE, k], samples[SIN, k], samples[COS, k], samples[DX, k], samples[DDX, k], samples[OMEGA, k],
            samples[P_GAUGE, k])


@numba.njit(cache=True)
def _cylinder_samples(angle, omega, p_gauge, r, inv_rod, e, out):
    rows = sample_rows(out, 0)
    for i in range(angle.shape[0]):
        fill_sample(rows, i, angle[i], np.sin(angle[i]), np.cos(angle[i]), omega[i], p_gauge[i], r, inv_rod, e)


def cylinder_samples(local_angle: np.ndarray, omega: np.ndarray | float, p_gauge: np.ndarray | float,
                     consts: np.ndarray) -> np.ndarray:
    """Sample rows (N_FIELDS, n) of one cylinder (``fill_sample``, the routine the monitor and the plant use).

    local_angle : (n,) crank angle of the cylinder [rad], 0 = its firing TDC; omega : throw speed [rad/s];
    p_gauge : cylinder minus crankcase pressure [Pa] (negative values are clipped to 0); consts : friction_params().
    """
    ang = np.ascontiguousarray(local_angle, dtype=np.float64).ravel()
    n = ang.shape[0]
    w = np.ascontiguousarray(np.broadcast_to(np.asarray(omega, dtype=np.float64), (n,)))
    p = np.ascontiguousarray(np.broadcast_to(np.asarray(p_gauge, dtype=np.float64), (n,)))
    if not (np.all(np.isfinite(ang)) and np.all(np.isfinite(w)) and np.all(np.isfinite(p))):
        raise ValueError("local_angle, omega and p_gauge must be finite; mark bad samples before calling")
    c = np.asarray(consts, dtype=np.float64)
    out = np.empty((N_FIELDS, 1, n))
    _cylinder_samples(ang, w, p, float(c[R]), 1.0 / float(c[L]), float(c[E]), out)
    return out[:, 0]


def cylinder_samples_reference(local_angle: np.ndarray, omega: np.ndarray | float, p_gauge: np.ndarray | float,
                               consts: np.ndarray) -> np.ndarray:
    """``cylinder_samples`` in plain numpy from core.model.kinematics (the reference of ``fill_sample``)."""
    from frictionwatch.core.model.kinematics import kinematics

    ang = np.asarray(local_angle, dtype=np.float64).ravel()
    n = ang.shape[0]
    _, dx, ddx = kinematics(ang, np.asarray(consts, dtype=np.float64)[:3])
    out = np.empty((N_FIELDS, n))
    out[ANGLE] = np.mod(ang, FOUR_PI)
    out[SIN] = np.sin(ang)
    out[COS] = np.cos(ang)
    out[DX] = dx
    out[DDX] = ddx
    out[OMEGA] = np.maximum(np.broadcast_to(np.asarray(omega, dtype=np.float64), (n,)), OMEGA_FLOOR)
    out[P_GAUGE] = np.maximum(np.broadcast_to(np.asarray(p_gauge, dtype=np.float64), (n,)), 0.0)
    return out


# ---- the six Rezeka-Henein terms (paper 000 Eq. 4; physics.md §7): numpy reference, then kernel ----------------

def ring_viscous_reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """F1 = sqrt(mu |c| (P_e + p) e) pi D (n_o + 0.4 n_c) |x'|, c = omega x' the piston speed."""
    lever = np.abs(s[DX])
    return np.sqrt(c[MU] * s[OMEGA] * lever * (c[PE] + s[P_GAUGE]) * c[ETH]) * np.pi * c[D] * (c[NO] + 0.4 * c[NC]) * lever


@loss_kernel
def ring_viscous_kernel(s, c, out):
    k = np.pi * c[D] * (c[NO] + 0.4 * c[NC])
    for j in range(out.shape[0]):
        for i in range(out.shape[1]):
            lever = abs(s[DX, j, i])
            out[j, i] = np.sqrt(c[MU] * s[OMEGA, j, i] * lever * (c[PE] + s[P_GAUGE, j, i]) * c[ETH]) * k * lever


def ring_mixed_reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """F2 = pi D n_c (P_e + p)(1 - |sin angle|) |x'| within +-90 deg of firing TDC, else 0."""
    window = (s[ANGLE] <= 0.5 * np.pi) | (s[ANGLE] >= FOUR_PI - 0.5 * np.pi)
    return np.where(window, np.pi * c[D] * c[NC] * (c[PE] + s[P_GAUGE]) * (1.0 - np.abs(s[SIN])) * np.abs(s[DX]), 0.0)


@loss_kernel
def ring_mixed_kernel(s, c, out):
    k = np.pi * c[D] * c[NC]
    for j in range(out.shape[0]):
        for i in range(out.shape[1]):
            a = s[ANGLE, j, i]
            if a <= 0.5 * np.pi or a >= FOUR_PI - 0.5 * np.pi:
                out[j, i] = k * (c[PE] + s[P_GAUGE, j, i]) * (1.0 - abs(s[SIN, j, i])) * abs(s[DX, j, i])
            else:
                out[j, i] = 0.0


def skirt_viscous_reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """F3 = mu |c| / g_a pi D L_FP |x'|."""
    lever = np.abs(s[DX])
    return c[MU] * s[OMEGA] * lever / c[GA] * np.pi * c[D] * c[LFP] * lever


@loss_kernel
def skirt_viscous_kernel(s, c, out):
    k = c[MU] / c[GA] * np.pi * c[D] * c[LFP]
    for j in range(out.shape[0]):
        for i in range(out.shape[1]):
            lever = abs(s[DX, j, i])
            out[j, i] = k * s[OMEGA, j, i] * lever * lever


def valve_train_reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """F4 = N_v L_s |x'| / sqrt(omega) (the paper's form: on the piston lever, not the cam angle)."""
    return c[NV] * c[LS] * np.abs(s[DX]) / np.sqrt(s[OMEGA])


@loss_kernel(divides_by_floored_speed=True)
def valve_train_kernel(s, c, out):
    k = c[NV] * c[LS]
    for j in range(out.shape[0]):
        for i in range(out.shape[1]):
            out[j, i] = k * abs(s[DX, j, i]) / np.sqrt(s[OMEGA, j, i])


def auxiliaries_reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """F5 = mu omega (auxiliaries and unloaded bearings)."""
    return c[MU] * s[OMEGA]


@loss_kernel
def auxiliaries_kernel(s, c, out):
    for j in range(out.shape[0]):
        for i in range(out.shape[1]):
            out[j, i] = c[MU] * s[OMEGA, j, i]


def loaded_bearings_reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """F6 = (pi/4) D^2 r_b p |cos angle| / sqrt(omega)."""
    return 0.25 * np.pi * c[D] ** 2 * c[RB] * s[P_GAUGE] * np.abs(s[COS]) / np.sqrt(s[OMEGA])


@loss_kernel(divides_by_floored_speed=True)
def loaded_bearings_kernel(s, c, out):
    k = 0.25 * np.pi * c[D] * c[D] * c[RB]
    for j in range(out.shape[0]):
        for i in range(out.shape[1]):
            out[j, i] = k * s[P_GAUGE, j, i] * abs(s[COS, j, i]) / np.sqrt(s[OMEGA, j, i])


def rezeka_henein(coefficients: np.ndarray | None = None) -> TermLibrary:
    """The six Rezeka-Henein terms, in the paper's order. ``coefficients`` (one per term): their priors (default 0: the engine
    spec carries its own, ``EngineSpec.friction.coefficients``). Ring and skirt terms are scaled per cylinder by
    default (the group ring wear changes), valve train, auxiliaries and bearings engine-wide (core.monitor.identify.parameters)."""
    spec = [
        ("ring_viscous", "sqrt(mu |c| (P_e + p) e) pi D (n_o + 0.4 n_c) |x'|", "cylinder", "-",
         ring_viscous_kernel, ring_viscous_reference),
        ("ring_mixed", "pi D n_c (P_e + p)(1 - |sin angle|) |x'|, +-90 deg of firing TDC", "cylinder", "m",
         ring_mixed_kernel, ring_mixed_reference),
        ("skirt_viscous", "mu |c| / g_a pi D L_FP |x'|", "cylinder", "-", skirt_viscous_kernel, skirt_viscous_reference),
        ("valve_train", "N_v L_s |x'| / sqrt(omega)", "engine", "m s^-0.5", valve_train_kernel,
         valve_train_reference),
        ("auxiliaries", "mu omega", "engine", "m^3", auxiliaries_kernel, auxiliaries_reference),
        ("loaded_bearings", "(pi/4) D^2 r_b p |cos angle| / sqrt(omega)", "engine", "s^-0.5",
         loaded_bearings_kernel, loaded_bearings_reference),
    ]
    a0 = np.zeros(len(spec)) if coefficients is None else np.asarray(coefficients, dtype=np.float64)
    if a0.shape != (len(spec),):
        raise ValueError(f"rezeka_henein takes {len(spec)} coefficients, got shape {a0.shape}")
    return TermLibrary(tuple(LossTerm(name, eq, group, unit, float(a), kern, ref)
                             for (name, eq, group, unit, kern, ref), a in zip(spec, a0)))
