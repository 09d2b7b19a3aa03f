"""The ``Effect`` interface and the plant set-up values its hooks transform.

An effect is an object: a class per piece of physics (name, one line of description, parameter table, on by default
or not) and an instance per use (its parameter values, validated on construction, optionally a sigma per fitted
parameter). The simulator builds four frozen set-up values from the engine spec and passes each through every active
effect's hook, in the order the effects are listed:

    apply_chain(ChainSetup)         -> ChainSetup       rigid or flexible shaft line, constant or variable inertia,
                                                        the line's stiffness and the flywheel's inertia off the record
    apply_cylinders(CylinderSetup)  -> CylinderSetup    friction coefficients, true firing angles, misfire
                                                        probability, blow-by mass loss, extra friction
    apply_load(LoadSetup)           -> LoadSetup        load-torque ripple
    apply_sensors(SensorSetup)      -> SensorSetup      wheel offset, tooth errors, noise, pressure gain/offset

The monitor's side of an effect is its own too (core.model.view builds the model the monitor runs from it):

    apply_view(ViewSetup)           -> ViewSetup        shaft line, inertia, phases, pressure corrections, scaled
                                                        coefficients
    size_view(ViewSetup, means)     -> ViewSetup        a friction shape sized at the reference operating point
                                                        (``sized_at_reference``: extra friction, friction laws)

A hook returns a new value (``dataclasses.replace`` with fresh arrays) and never changes the one it got, so an effect
cannot touch shared state and two instances (worn rings in cylinders 2 and 3) simply compose. An effect that is a
missing torque term also names the identification columns it adds (``monitor_terms``) or the existing terms it
scales (``scales_terms``), for the monitor's augmented model.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import ClassVar

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.terms import LossTerm, TermLibrary

ONCE, PER_CYLINDER = "once", "per_cylinder"


@dataclass(frozen=True)
class Param:
    """One effect parameter: default, unit, valid closed range, integer or float."""

    default: float
    unit: str
    lo: float
    hi: float
    integer: bool = False
    doc: str = ""


def cylinder_param(doc: str = "cylinder number, 1-based", allow_all: bool = False) -> Param:
    return Param(0 if allow_all else 1, "-", 0 if allow_all else 1, 24, integer=True, doc=doc)


# ---- the set-up values the hooks transform -------------------------------------------------------------------

@dataclass(frozen=True)
class ChainSetup:
    """Shaft-line model: the spec's node chain or one rigid node; J(theta) per throw or its constant mean."""

    flexible: bool = False
    variable_inertia: bool = False
    stiffness_scale: float = 1.0  # the plant's section stiffnesses and dampings x these (a chain the monitor is
    damping_scale: float = 1.0  # not told about: core.model.effects.mismatch)
    flywheel_inertia_scale: float = 1.0  # the flywheel node's inertia x this (a flywheel the record has wrong)


@dataclass(frozen=True)
class CylinderSetup:
    """Per-cylinder plant inputs (z rows). ``coefficients`` (z, n) truth a_kl of the loss terms ``term_names`` (n,);
    ``firing_angles`` (z,) TRUE firing
    angles [rad]; ``misfire`` (z,) probability of a motored cycle; ``mass_loss`` (z,) trapped-mass fraction lost to
    blow-by IVC->EVO (the simulator sizes the leak orifice from it); ``extra_friction`` (z, 4) = [mean, amplitude as
    fractions of the cylinder's mean friction, order, phase rad] of T = T_ref (mean + amp cos(order theta_k + phase)).
    ``transfers``: (base term, new term, fraction) moves that fraction of the base term's mean friction at the
    operating point into the new term's shape (the simulator sizes the new coefficient; a friction law of another
    shape with the same mean there, core.model.effects.mismatch)."""

    coefficients: np.ndarray
    term_names: tuple[str, ...]
    firing_angles: np.ndarray
    misfire: np.ndarray
    mass_loss: np.ndarray
    extra_friction: np.ndarray
    transfers: tuple[tuple[str, str, float], ...] = ()

    @classmethod
    def nominal(cls, spec: EngineSpec, coefficients: np.ndarray, term_names: tuple[str, ...]) -> CylinderSetup:
        z = spec.n_cyl
        coef = np.array(coefficients, dtype=np.float64)
        if coef.shape != (z, len(term_names)):
            raise ValueError(f"coefficients {coef.shape} do not match {z} cylinders x {len(term_names)} terms")
        return cls(coef, tuple(term_names), spec.firing_angles.astype(np.float64).copy(), np.zeros(z), np.zeros(z),
                   np.zeros((z, 4)))


@dataclass(frozen=True)
class LoadSetup:
    """Extra load torque A sin(order theta_L + phase) at the load node; A = ``amplitude_nm`` if > 0, else
    ``fraction`` x the mean brake torque estimate (the simulator resolves it at the operating point).
    ``coast_down_s``: time [s] at which the ignition goes off and the load is disconnected (inf: never)."""

    amplitude_nm: float = 0.0
    fraction: float = 0.0
    order: float = 0.0
    phase_rad: float = 0.0
    coast_down_s: float = float("inf")


@dataclass(frozen=True)
class SensorSetup:
    """Acquisition errors. ``wheel_offset_rad``: the wheel frame is theta_W = theta_F + offset; tooth errors (rms
    and order-1 runout, deg); edge jitter [ns], pressure noise (x ``sensors.pressure_noise_pa``), load noise
    (fraction of rated torque); per cylinder a pressure reading ``pressure_gain`` (z,) x p + ``pressure_offset_pa``,
    less a thermal-shock error of peak ``thermal_shock_pa`` (z,) at full load (None: none; its time constant
    ``thermal_shock_tau_s`` (z,) and its size at no load as a fraction of full load's ``thermal_shock_idle`` (z,):
    core.model.thermal_shock)."""

    pressure_gain: np.ndarray
    pressure_offset_pa: np.ndarray
    wheel_offset_rad: float = 0.0
    tooth_sigma_deg: float = 0.0
    runout_deg: float = 0.0
    runout_phase_deg: float = 0.0
    edge_jitter_ns: float = 0.0
    pressure_noise_scale: float = 0.0
    load_noise_frac: float = 0.0
    thermal_shock_pa: np.ndarray | None = None
    thermal_shock_tau_s: np.ndarray | None = None
    thermal_shock_idle: np.ndarray | None = None

    @classmethod
    def ideal(cls, n_cyl: int) -> SensorSetup:
        return cls(np.ones(n_cyl), np.zeros(n_cyl))


@dataclass(frozen=True)
class ShockView:
    """The pressure sensors' thermal-shock error as the monitor undoes it (core.model.thermal_shock): per cylinder
    its peak at full load ``size_pa`` (z,) Pa (0: none), time constant ``tau_s`` (z,) and size at no load as a
    fraction of full load's ``idle`` (z,)."""

    size_pa: np.ndarray
    tau_s: np.ndarray
    idle: np.ndarray


@dataclass(frozen=True)
class ViewSetup:
    """The model as the monitor runs it, while the effects build it (core.model.view.monitor_view): the spec, the
    loss terms and their coefficients (z, L); the shaft line flexible or one rigid node and the inertia variable or
    constant (as the plant's ChainSetup: off unless an effect says so); per cylinder the kinematic phase offset
    ``tdc`` (z,) rad and the pressure reading's ``gain`` (z,) and ``offset`` (z,) Pa that the monitor undoes; a known
    load-torque ripple at the load node ``load_ripple`` = (amplitude [N m], fraction of the measured mean load torque
    (used where the amplitude is 0), engine order, phase [rad]) as the plant's LoadSetup, all 0: none; the pressure
    sensors' thermal-shock error the monitor adds back to what it reads (``shock``, None: none)."""

    spec: EngineSpec
    terms: TermLibrary
    coefficients: np.ndarray
    tdc: np.ndarray
    gain: np.ndarray
    offset: np.ndarray
    flexible: bool = False
    variable_inertia: bool = False
    load_ripple: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    shock: ShockView | None = None

    @classmethod
    def nominal(cls, spec: EngineSpec, terms: TermLibrary, coefficients: np.ndarray) -> ViewSetup:
        z = spec.n_cyl
        return cls(spec, terms, np.array(coefficients, dtype=np.float64), np.zeros(z), np.ones(z), np.zeros(z))


@dataclass(frozen=True)
class CandidateSpec:
    """How the discrepancy workflow may add an effect to a model (core.discrepancy.candidates): the parameters
    it fits, their no-effect values ``x0``, finite-difference steps and bounds, the other parameters ``fixed``; where:
    ``each`` cylinder, ``each_and_wheel`` (cylinder 0 too: the whole wheel), or ``engine``-wide (once, or once per
    fixed ``variants`` entry, e.g. a load ripple at each of a few engine orders); ``also``: further shapes of the
    effect, each declared so (an extra friction's constant and its cam-order shape); ``places_cylinder`` False: a
    shape the speed reads alike from every cylinder, fitted in the one its ``fixed`` names and never added, only
    said (the workflow's outcome is then ambiguous over the cylinders); ``requires``: an
    effect the model must hold (and a shaft line with sections, for ``torsional_flexibility``); ``separated_by``: the
    measurement that tells this effect from another that explains a log as well (said when the workflow finds two);
    ``fixed_sigma``: the uncertainty of a ``fixed`` parameter the fit does not move, carried into the fitted
    parameters' sigma. No parameters: a toggle (a default effect the model left out)."""

    params: tuple[str, ...] = ()
    x0: tuple[float, ...] = ()
    step: tuple[float, ...] = ()
    lo: tuple[float, ...] = ()
    hi: tuple[float, ...] = ()
    fixed: Mapping[str, float] = field(default_factory=dict)
    where: str = "engine"
    requires: str = ""
    separated_by: str = ""
    variants: tuple[Mapping[str, float], ...] = ()  # engine-wide: one candidate per variant (its values fixed too)
    also: tuple[CandidateSpec, ...] = ()  # further shapes of the same effect, each a candidate of its own
    places_cylinder: bool = True  # False: the speed cannot tell in which cylinder it is (fitted in a stand-in one)
    seeds: tuple[tuple[float, ...], ...] = ()  # further starting points of its refinement (a strongly nonlinear fit)
    # a fixed parameter's own uncertainty (name -> its sigma, in its unit): the fit's shift with that parameter off by
    # it joins the sigma of the fitted ones (core.discrepancy.fit.polish); e.g. a sensor's time constant not read
    fixed_sigma: Mapping[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class HarmonicForm:
    """One harmonic part of an effect, A cos/sin(order theta + phase), given either as amplitude and phase [deg]
    (``amplitude``, ``phase``) or, where either is non-zero, as A cos(phase) and A sin(phase) (``cos``, ``sin``): the
    form the discrepancy workflow fits, since the speed it makes is linear in them and a phase means nothing at zero
    amplitude. The names are the effect's parameters."""

    amplitude: str
    phase: str
    cos: str
    sin: str

    def check(self, effect: str, v: Mapping[str, float]) -> None:
        """One form only: a one-line ValueError where both are given."""
        if (v[self.cos] or v[self.sin]) and (v[self.amplitude] or v[self.phase]):
            raise ValueError(f"effect '{effect}': give {self.amplitude} and {self.phase}, or {self.cos} and "
                             f"{self.sin}, not both")

    def polar(self, v: Mapping[str, float]) -> tuple[float, float]:
        """(A, phase [rad]) from whichever form is given."""
        if v[self.cos] or v[self.sin]:
            return float(np.hypot(v[self.cos], v[self.sin])), float(np.arctan2(v[self.sin], v[self.cos]))
        return float(v[self.amplitude]), float(np.radians(v[self.phase]))

    def amplitude_sigma(self, v: Mapping[str, float], sigma: Mapping[str, float]) -> float:
        """The amplitude's sigma from the given form's (the parts' propagated to first order)."""
        a, b = v[self.cos], v[self.sin]
        amp = float(np.hypot(a, b))
        if amp == 0.0:
            return sigma.get(self.amplitude, 0.0)
        return float(np.hypot(a * sigma.get(self.cos, 0.0), b * sigma.get(self.sin, 0.0))) / amp


# the (z, L) cycle means of each term's basis in every cylinder at the reference operating point, for a spec and a
# term library (core.model.view.basis_means at the view's reference)
BasisMeans = Callable[[EngineSpec, TermLibrary], np.ndarray]


def with_row(a: np.ndarray, k: int, value) -> np.ndarray:
    """A copy of ``a`` with row (or element) k set to ``value``: hooks never write into the array they were given."""
    out = np.array(a, dtype=np.float64)
    out[k] = value
    return out


# ---- the effect interface ----------------------------------------------------------------------------------------

class Effect:
    """Base of every effect; subclasses set the class attributes and override the hooks they need.

    ``Effect(**values, sigma=None)``: parameter values (defaults fill the rest), each validated against ``parameters``
    (one-line ValueError naming the parameter and its range); ``sigma`` maps fitted parameters to their standard
    deviation (an effect identified by the discrepancy workflow). Instances are immutable and compare by value.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""  # one line of physics
    default_on: ClassVar[bool] = False
    parameters: ClassVar[Mapping[str, Param]] = MappingProxyType({})
    repeat: ClassVar[str] = ONCE  # PER_CYLINDER: one instance per cylinder allowed (worn rings in 2 and 3)
    scales_terms: ClassVar[tuple[str, ...]] = ()  # loss terms whose per-cylinder coefficients this effect scales
    sized_at_reference: ClassVar[bool] = False  # size_view needs the reference operating point
    candidate: ClassVar[CandidateSpec | None] = None  # how the discrepancy workflow may add it (None: it may not)
    # a harmonic given either as amplitude and phase or as its two parts: checked at construction (HarmonicForm)
    form: ClassVar[HarmonicForm | None] = None
    every_cylinder_said: ClassVar[str] = "every cylinder"  # cylinder 0 in an operator's words (a TDC: the whole wheel)

    __slots__ = ("values", "sigma")

    def __init__(self, sigma: Mapping[str, float] | None = None, **values: object):
        given = {k: self._checked(k, v) for k, v in values.items()}
        full = {k: (int(p.default) if p.integer else float(p.default)) for k, p in self.parameters.items()}
        full.update(given)
        sig = {}
        for key, raw in (sigma or {}).items():
            if key not in self.parameters:
                raise ValueError(f"effect '{self.name}': sigma given for unknown parameter '{key}'")
            v = _number(self.name, f"sigma.{key}", raw)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"effect '{self.name}': sigma.{key}={raw!r} must be finite and >= 0")
            sig[key] = v
        object.__setattr__(self, "values", MappingProxyType(full))
        object.__setattr__(self, "sigma", MappingProxyType(sig))
        if self.form is not None:
            self.form.check(self.name, self.values)

    def _checked(self, key: str, raw: object) -> float | int:
        if key not in self.parameters:
            known = ", ".join(self.parameters) or "none"
            raise ValueError(f"effect '{self.name}' has no parameter '{key}'; known: {known}")
        prm = self.parameters[key]
        v = _number(self.name, key, raw)
        if not (math.isfinite(v) and prm.lo <= v <= prm.hi):
            raise ValueError(f"effect '{self.name}': {key}={raw!r} is out of range {prm.lo:g}..{prm.hi:g} {prm.unit}")
        if prm.integer:
            if v != int(v):
                raise ValueError(f"effect '{self.name}': {key}={raw!r} must be an integer")
            return int(v)
        return v

    def __setattr__(self, key: str, value: object) -> None:
        raise AttributeError(f"effect '{self.name}' is immutable; build a new one")

    def __getitem__(self, key: str) -> float | int:
        return self.values[key]

    def __eq__(self, other: object) -> bool:
        return (type(other) is type(self) and dict(self.values) == dict(other.values)
                and dict(self.sigma) == dict(other.sigma))

    def __hash__(self) -> int:
        return hash((self.name, tuple(self.values.items())))

    def __repr__(self) -> str:
        inner = ", ".join(f"{k}={v!r}" for k, v in self.values.items())
        return f"{self.name}({inner})" + (f" sigma={dict(self.sigma)}" if self.sigma else "")

    @property
    def slot(self) -> tuple:
        """What two instances may not share: the effect (ONCE) or the effect and its cylinder (PER_CYLINDER)."""
        return (self.name, self.values["cylinder"]) if self.repeat == PER_CYLINDER else (self.name,)

    def to_dict(self) -> dict:
        """{"name", "params"[, "sigma"]}: the truth JSON's and the model file's record of this instance."""
        out = {"name": self.name, "params": dict(self.values)}
        if self.sigma:
            out["sigma"] = dict(self.sigma)
        return out

    def check_engine(self, n_cyl: int) -> None:
        cyl = self.values.get("cylinder")
        if cyl is not None and cyl > n_cyl:
            raise ValueError(f"effect '{self.name}': cylinder={cyl} but the engine has {n_cyl} cylinders")

    # ---- hooks: the default leaves the plant as it is -------------------------------------------------------------
    def apply_chain(self, setup: ChainSetup) -> ChainSetup:
        return setup

    def apply_cylinders(self, setup: CylinderSetup) -> CylinderSetup:
        return setup

    def apply_load(self, setup: LoadSetup) -> LoadSetup:
        return setup

    def apply_sensors(self, setup: SensorSetup) -> SensorSetup:
        return setup

    def apply_view(self, setup: ViewSetup) -> ViewSetup:
        """The monitor's side: by default the coefficients of ``scales_terms`` in the effect's cylinder x its gain
        (an effect without them leaves the view as it is)."""
        if not self.scales_terms:
            return setup
        cols = [i for i, n in enumerate(setup.terms.names) if n in self.scales_terms]
        coef = np.array(setup.coefficients, dtype=np.float64)
        coef[self.values["cylinder"] - 1, cols] *= self.values["gain"]
        return replace(setup, coefficients=coef)

    def size_view(self, setup: ViewSetup, means: BasisMeans) -> ViewSetup:
        """The monitor's side of a friction shape, sized at the reference operating point (``means``); run after
        every effect's ``apply_view`` (a shape is sized on the coefficients the scalings left)."""
        return setup

    def monitor_terms(self, spec: EngineSpec) -> tuple[LossTerm, ...]:
        """Loss terms (identification columns) this effect adds when the monitor's model is augmented with it."""
        return ()

    def unphysical(self, sigma: Mapping[str, float], load_torque: float) -> str:
        """'' when these values (with their ``sigma``) can be the physics the effect stands for at an operating
        point whose mean load torque is ``load_torque`` [N m] (NaN: not measured); else why not, in words (the
        discrepancy workflow drops such a fit: it is some other torque than this effect's)."""
        return ""

    def plant_terms(self, spec: EngineSpec) -> tuple[LossTerm, ...]:
        """Loss terms the plant evaluates for this effect and the monitor is never told about (a model mismatch);
        their coefficients start at 0 and the effect's ``apply_cylinders`` sets or sizes them."""
        return ()

    @property
    def onset_cycle(self) -> int:
        """First output cycle the effect acts in (its ``from_cycle`` parameter; 0: from the start)."""
        return int(self.values.get("from_cycle", 0))

    @property
    def ramp_cycles(self) -> int:
        """Output cycles over which the effect grows linearly from its onset to full size (``ramp_cycles``; 0: a
        step at the onset)."""
        return int(self.values.get("ramp_cycles", 0))

    def ramp_fraction(self, cycle: int) -> float:
        """How much of the effect acts in output ``cycle``: 0 before the onset, then (cycle - onset + 1) / ramp up
        to 1 (the onset cycle carries the first step of the ramp)."""
        if cycle < self.onset_cycle:
            return 0.0
        ramp = self.ramp_cycles
        return 1.0 if ramp <= 1 else min(1.0, (cycle - self.onset_cycle + 1) / ramp)

    def scaled(self, fraction: float) -> Effect:
        """This effect at ``fraction`` (0..1] of its size (an effect with a ramp overrides it; the default: itself)."""
        return self


def _number(effect: str, key: str, raw: object) -> float:
    """A parameter value as float; strings and booleans are refused (the CLI parser converts its text first)."""
    if isinstance(raw, bool) or not isinstance(raw, (int, float, np.integer, np.floating)):
        raise ValueError(f"effect '{effect}': {key}={raw!r}: expected a number")
    return float(raw)


__all__ = ["ONCE", "PER_CYLINDER", "BasisMeans", "CandidateSpec", "ChainSetup", "CylinderSetup", "Effect",
           "HarmonicForm", "LoadSetup", "Param",
           "SensorSetup", "ShockView", "ViewSetup", "cylinder_param", "with_row"]
