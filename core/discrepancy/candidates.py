"""Name: the library of candidate augmentations, each an effect of core.model.effects with a few free parameters.

Each effect declares whether and how it may be a candidate (``Effect.candidate``, a ``CandidateSpec``: the
parameters the fit moves, the values at which it does nothing, a finite-difference step, bounds, the cylinders);
this module only expands those declarations over the cylinders of a model. A candidate is one effect (and cylinder,
for a per-cylinder one); ``effect_at(x)`` is the Effect instance the augmented model carries; toggles (a default
effect the baseline left out: the flexible shaft line, J(theta)) have no parameters, and where the baseline left out
several, all of them at once is one more toggle ('torsional_flexibility+variable_inertia'): a rigid crank of
constant inertia is not made right by either alone (k9k 3000 rpm, rigid baseline: held-out gap 11.8; the flexible
shaft alone 35.8, J(theta) alone 12.3).

A load ripple is engine-wide, one candidate per engine order its effect declares (``CandidateSpec.variants``: the
half orders 0.5 and 1.5; an integer order is the tooth-spacing learner's, core/model/effects/catalog.py says why).
An effect may declare further shapes (``CandidateSpec.also``): an extra friction is a constant torque in each
cylinder, and a cam-order torque fitted in a stand-in cylinder (``places_cylinder`` False: the speed cannot tell
which cylinder; the workflow says that and adds nothing).

A pressure sensor's thermal shock is one candidate for every cylinder's sensor at once (its size the log's own): one
sensor's shock is the monitor's thermal-shock watch's to flag against its siblings (core.discrepancy.sensor_faults).

Not in the library today, and why (the monitor cannot be told, or there is nothing to tell it):
- misfire, blow_by: they change the cylinder pressure, which the monitor measures: the model already sees them
  (a misfire, a leak past the rings and a sensor's pegging offset are named from the pressure itself:
  pressure_channel.pressure_findings; a worn ring's friction stays the speed's candidate, ring_wear, its leak the
  pressure's: a ring that wears and leaks is two findings on one cylinder, design note 97);
- tooth_spacing_error: the monitor learns the wheel's tooth pattern itself;
- an element's inertia other than the flywheel node's: no effect holds it (the flywheel's is flywheel_inertia, one
  ratio; where it and the chain's stiffness read one resonance the workflow says both: core.discrepancy.resonance).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from frictionwatch.core.model.chain import lowest_mode_hz
from frictionwatch.core.model.effects import EFFECTS, Effect, make_effect
from frictionwatch.core.model.effects.base import CandidateSpec, ViewSetup
from frictionwatch.core.model.effects.mismatch import MISMATCHES
from frictionwatch.core.model.engine_model import EngineModel

FRICTION_LAWS = tuple(c.name for c in MISMATCHES if getattr(c, "base", ""))  # the laws a candidate may bring


@dataclass(frozen=True)
class Candidate:
    """effect name; cylinder (None: engine-wide; 0 for tdc_offset: the whole wheel); params fitted, their
    no-effect values x0, finite-difference steps and bounds; fixed: other parameters of the effect."""

    effect: str
    cylinder: int | None
    params: tuple[str, ...]
    x0: tuple[float, ...]
    step: tuple[float, ...]
    lo: tuple[float, ...]
    hi: tuple[float, ...]
    fixed: Mapping[str, float] = field(default_factory=dict)
    separated_by: str = ""  # the measurement that tells it from another explanation (its effect's declaration)
    variant: str = ""  # an engine-wide candidate's fixed variant, e.g. "order 0.5" (its values are in ``fixed``)
    places_cylinder: bool = True  # False: fitted in a stand-in cylinder the speed cannot tell from the others
    seeds: tuple[tuple[float, ...], ...] = ()  # further starting points of its refinement (its effect's declaration)
    fixed_sigma: Mapping[str, float] = field(default_factory=dict)  # a fixed parameter's sigma (its declaration)
    # (p,) |d ln omega^2 / d x| of the shaft line's lowest mode per unit of each parameter at x0, the model's view
    # (``line_mode_share``): where a parameter moves that mode, the line's own error in it reads as a parameter error
    # (fit.parameter_floor); () on a one-node line or for a toggle
    mode_share: tuple[float, ...] = ()

    @property
    def label(self) -> str:
        if self.variant:
            return f"{self.effect}[{self.variant}]"
        return self.effect if self.cylinder is None else f"{self.effect}[cyl {self.cylinder}]"

    @property
    def shape(self) -> str:
        """What it explains apart from where: its effect and variant (a per-cylinder effect's cylinders are one
        shape, the held-out cycles choose among them; a stand-in shape, a variant, is one of its own)."""
        return f"{self.effect}[{self.variant}]" if self.variant else self.effect

    @property
    def toggle(self) -> bool:
        return not self.params

    @property
    def names(self) -> tuple[str, ...]:
        """The effects it adds: one, or a toggle's several ('a+b')."""
        return tuple(self.effect.split("+"))

    def clip(self, x: np.ndarray) -> np.ndarray:
        return np.clip(x, self.lo, self.hi)

    def effect_at(self, x: np.ndarray | None = None) -> Effect:
        values = dict(self.fixed)
        if self.cylinder is not None:
            values["cylinder"] = self.cylinder
        if x is not None:
            values.update({k: float(v) for k, v in zip(self.params, self.clip(np.asarray(x, float)))})
        return make_effect(self.effect, values)

    def model_at(self, model: EngineModel, x: np.ndarray | None) -> EngineModel:
        """``model`` with this candidate at ``x``; at x0 (no effect) the model itself."""
        if self.toggle:
            for name in self.names:
                model = model.with_effect(make_effect(name, {}))
            return model
        if not self.toggle and np.allclose(np.asarray(x, float), self.x0, rtol=0, atol=1e-15):
            return model
        return model.with_effect(self.effect_at(x))


def candidate_library(model: EngineModel) -> list[Candidate]:
    """Every candidate that can still be added to ``model`` (a slot it already holds is left out), in the effect
    registry's order, each as its effect declares it (``Effect.candidate``)."""
    have = {e.slot for e in model.effects}
    names = {e.name for e in model.effects}
    out = []
    for name, cls in EFFECTS.items():
        for spec in (() if cls.candidate is None else (cls.candidate, *cls.candidate.also)):
            out += _expanded(name, spec, model, names)
    toggles = [c for c in out if c.toggle]
    if len(toggles) > 1:  # every default effect the model left out, at once
        out.append(Candidate("+".join(c.effect for c in toggles), None, (), (), (), (), (),
                             separated_by="; ".join(c.separated_by for c in toggles if c.separated_by)))
    kept = [c for c in out if _slot(c) not in have]
    if not model.spec.stiffness.size:
        return kept
    view = model_view(model)
    return [replace(c, mode_share=line_mode_share(view, c)) if c.cylinder is None and not c.toggle else c
            for c in kept]


def model_view(model: EngineModel) -> ViewSetup:
    """The model's record as its effects make it for the monitor (each effect's ``apply_view``, in order)."""
    setup = ViewSetup.nominal(model.spec, model.terms, model.coefficients)
    for e in model.effects:
        setup = e.apply_view(setup)
    return setup


def line_mode_share(view: ViewSetup, cand: Candidate, h: float = 1e-3) -> tuple[float, ...]:
    """(p,) |d ln omega^2 / d x_i| of the line's lowest undamped mode (core.model.chain.lowest_mode_hz) at the
    candidate's no-effect point, one-sided steps of ``h`` into its bounds, on ``view`` (``model_view``): 1 for the
    chain's stiffness scale (omega^2 ~ k, every section scaled), ~0.46-0.5 for the flywheel's inertia scale on k9k and
    maruti (the flywheel's share of the mode's inertia), 0 for what does not move the line (a friction, a damping).
    Only engine-wide candidates are asked: a cylinder's effect moves no node of the line."""
    x0 = np.asarray(cand.x0, dtype=np.float64)
    f0 = lowest_mode_hz(cand.effect_at(x0).apply_view(view).spec)
    out = []
    for i in range(x0.size):
        d = h if x0[i] + h <= cand.hi[i] else -h
        x = x0.copy()
        x[i] += d
        f = lowest_mode_hz(cand.effect_at(x).apply_view(view).spec)
        out.append(float(abs(2.0 * np.log(f / f0) / d)))
    return tuple(out)


def _expanded(name: str, spec: CandidateSpec, model: EngineModel, names: set[str]) -> list[Candidate]:
    """One effect's declaration (``CandidateSpec``) over the cylinders (and variants) of ``model``."""
    z = model.spec.n_cyl
    if not spec.params:  # a toggle: only where the model left its default effect out
        return [] if name in names else [Candidate(name, None, (), (), (), (), (), separated_by=spec.separated_by)]
    if spec.requires and (spec.requires not in names or (spec.requires == "torsional_flexibility"
                                                         and not model.spec.stiffness.size)):
        return []
    # on a one-cylinder engine the whole wheel and its one cylinder are one offset to the monitor: offer it once
    each_and_wheel = range(1, z + 1) if z == 1 else range(0, z + 1)
    cylinders = {"each": range(1, z + 1), "each_and_wheel": each_and_wheel}.get(spec.where, (None,))
    return [Candidate(name, k, spec.params, spec.x0, spec.step, spec.lo, spec.hi, {**spec.fixed, **v},
                      spec.separated_by, ", ".join(f"{a} {b:g}" for a, b in v.items()), spec.places_cylinder,
                      spec.seeds, fixed_sigma=spec.fixed_sigma)
            for k in cylinders for v in (spec.variants or ({},))]


def _slot(c: Candidate) -> tuple:
    """The slot a candidate would take (a stand-in's: the cylinder it is fitted in)."""
    cyl = c.cylinder if c.cylinder is not None else c.fixed.get("cylinder")
    return (c.effect, int(cyl)) if cyl is not None else (c.effect,)


__all__ = ["FRICTION_LAWS", "Candidate", "candidate_library", "line_mode_share", "model_view"]
