"""Name: the library of candidate augmentations, each an effect of core.model.effects with a few free parameters.

A candidate is one effect (and cylinder, for a per-cylinder one) with the parameters the fit moves, the values at
which it does nothing (``x0``: the model as it is), a finite-difference step and bounds. ``effect_at(x)`` is the
Effect instance the augmented model carries; toggles (a default effect the baseline left out: the flexible shaft
line, J(theta)) have no parameters.

Not in the library, and why (the monitor cannot be told, or there is nothing to tell it):
- load_ripple: the monitor has no known load-torque input to put it in (it would need a hook in core/monitor);
- misfire, blow_by: they change the cylinder pressure, which the monitor measures: the model already sees them;
- tooth_spacing_error: the monitor learns the wheel's tooth pattern itself;
- an element's inertia: no effect holds it (the spec's node inertia would be edited, not augmented).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from frictionwatch.core.model.effects import Effect, make_effect
from frictionwatch.core.model.engine_model import EngineModel

FRICTION_LAWS = ("stribeck_ring", "side_thrust_skirt", "cam_valve_train", "auxiliaries_speed_squared", "bearings_load")
TOGGLES = ("torsional_flexibility", "variable_inertia")


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

    @property
    def label(self) -> str:
        return self.effect if self.cylinder is None else f"{self.effect}[cyl {self.cylinder}]"

    @property
    def toggle(self) -> bool:
        return not self.params

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
        if not self.toggle and np.allclose(np.asarray(x, float), self.x0, rtol=0, atol=1e-15):
            return model
        return model.with_effect(self.effect_at(x))


def _per_cylinder(name: str, z: int, param: str, x0: float, step: float, lo: float, hi: float,
                  fixed: Mapping[str, float] | None = None, cylinders=None) -> list[Candidate]:
    cyls = range(1, z + 1) if cylinders is None else cylinders
    return [Candidate(name, k, (param,), (x0,), (step,), (lo,), (hi,), dict(fixed or {})) for k in cyls]


def candidate_library(model: EngineModel) -> list[Candidate]:
    """Every candidate that can still be added to ``model`` (a slot it already holds is left out)."""
    z = model.spec.n_cyl
    have = {e.slot for e in model.effects}
    names = {e.name for e in model.effects}
    out = [Candidate(t, None, (), (), (), (), ()) for t in TOGGLES if t not in names]
    out += _per_cylinder("tdc_offset", z, "deg", 0.0, 0.5, -10.0, 10.0, cylinders=range(0, z + 1))
    out += _per_cylinder("pressure_gain", z, "gain", 1.0, 0.02, 0.5, 1.5)
    out += _per_cylinder("pressure_offset", z, "pa", 0.0, 2e4, -1e6, 1e6)
    out += _per_cylinder("ring_wear", z, "gain", 1.0, 0.2, 1.0, 5.0, fixed={"mass_loss": 0.0})
    out += _per_cylinder("extra_friction", z, "mean_frac", 0.0, 0.1, 0.0, 5.0, fixed={"amp_frac": 0.0})
    out += [Candidate(n, None, ("fraction",), (0.0,), (0.25,), (0.0,), (1.0,)) for n in FRICTION_LAWS]
    if "torsional_flexibility" in names and model.spec.stiffness.size:
        out.append(Candidate("chain_mismatch", None, ("stiffness_scale", "damping_scale"), (1.0, 1.0), (0.1, 0.5),
                             (0.5, 0.2), (2.0, 5.0)))
    return [c for c in out if _slot(c) not in have]


def _slot(c: Candidate) -> tuple:
    return (c.effect, c.cylinder) if c.cylinder is not None else (c.effect,)


__all__ = ["FRICTION_LAWS", "TOGGLES", "Candidate", "candidate_library"]
