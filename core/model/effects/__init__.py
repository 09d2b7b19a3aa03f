"""Named, parametrised effects of the plant simulator as objects (docs/effects.md gives the physics of each).

    RingWear(cylinder=3, gain=1.4)                       an instance: validated parameters, defaults filled in
    parse_effect("ring_wear:cylinder=3,gain=1.4")        the same from the CLI's text
    resolve_effects([RingWear(cylinder=2), RingWear(cylinder=3)], without={"sensor_noise"}, n_cyl=4)
        -> every active instance: the default-on effects minus ``without`` plus the given ones

Several instances of a per-cylinder effect are allowed on distinct cylinders (worn rings in 2 and 3); a second
instance of a once-only effect (load_ripple, tooth_spacing_error, ...) or of the same effect on the same cylinder is
refused. Bad input raises ``ValueError`` with one line that names the problem.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from types import MappingProxyType

from frictionwatch.core.model.effects.base import (
    ONCE,
    PER_CYLINDER,
    ChainSetup,
    CylinderSetup,
    Effect,
    LoadSetup,
    Param,
    SensorSetup,
)
from frictionwatch.core.model.effects.catalog import (
    ALL,
    BlowBy,
    ExtraFriction,
    LoadRipple,
    Misfire,
    PressureGain,
    PressureOffset,
    RingWear,
    SensorNoise,
    TdcOffset,
    ThermalShock,
    ToothSpacingError,
    TorsionalFlexibility,
    VariableInertia,
)
from frictionwatch.core.model.effects.loss_terms import auxiliaries_quadratic, extra_friction_term
from frictionwatch.core.model.effects.mismatch import MISMATCHES

EFFECTS: Mapping[str, type[Effect]] = MappingProxyType({cls.name: cls for cls in ALL + MISMATCHES})


def effect_class(name: str) -> type[Effect]:
    if name not in EFFECTS:
        raise ValueError(f"unknown effect '{name}'; known: {', '.join(EFFECTS)}")
    return EFFECTS[name]


def make_effect(name: str, params: Mapping[str, object] | None = None,
                sigma: Mapping[str, float] | None = None) -> Effect:
    """An instance of effect ``name`` with ``params`` (defaults for the rest), validated."""
    return effect_class(name)(sigma=sigma, **dict(params or {}))


def _cli_value(text: str) -> object:
    try:
        return float(text)
    except ValueError:
        return text  # the effect refuses it: "expected a number"


def parse_effect(text: str) -> Effect:
    """``"NAME[:key=value,...]"`` -> the effect instance. Raises ValueError naming the problem."""
    name, _, rest = text.strip().partition(":")
    name = name.strip()
    given: dict[str, object] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq or not key.strip() or not val.strip():
            raise ValueError(f"effect '{name}': '{item}' is not key=value")
        given[key.strip()] = _cli_value(val.strip())
    return make_effect(name, given)


def check_instances(effects: Iterable[Effect], n_cyl: int) -> tuple[Effect, ...]:
    """The instances as a tuple, each checked against the engine; a repeated slot is refused in one line."""
    seen: dict[tuple, Effect] = {}
    out = []
    for e in effects:
        if not isinstance(e, Effect):
            raise ValueError(f"expected an Effect instance, got {e!r}")
        e.check_engine(n_cyl)
        if e.slot in seen:
            where = f" for cylinder {e['cylinder']}" if e.repeat == PER_CYLINDER else ""
            once = "" if e.repeat == PER_CYLINDER else "; it applies once per engine"
            raise ValueError(f"effect '{e.name}' is given twice{where}{once}")
        seen[e.slot] = e
        out.append(e)
    return tuple(out)


def resolve_effects(effects: Mapping[str, Mapping] | Iterable[Effect] | None, without: Iterable[str] = (),
                    n_cyl: int = 24) -> tuple[Effect, ...]:
    """Active instances: the default-on effects (each left out if in ``without`` or given explicitly) plus
    ``effects`` ({name: params} or Effect instances). Raises ValueError for an unknown name, a bad parameter, an
    effect both requested and excluded, a repeated instance or a cylinder number above ``n_cyl``."""
    without = set(without)
    for name in without:
        if name not in EFFECTS:
            raise ValueError(f"unknown effect '{name}' in without; known: {', '.join(EFFECTS)}")
    if effects is None:
        given: list[Effect] = []
    elif isinstance(effects, Mapping):
        given = [make_effect(name, params) for name, params in effects.items()]
    else:
        given = list(effects)
    names = {e.name for e in given if isinstance(e, Effect)}
    for name in names & without:
        raise ValueError(f"effect '{name}' is both requested and excluded")
    defaults = [cls() for name, cls in EFFECTS.items() if cls.default_on and name not in without | names]
    return check_instances(defaults + given, n_cyl)


__all__ = ["EFFECTS", "MISMATCHES", "ONCE", "PER_CYLINDER", "BlowBy", "ChainSetup", "CylinderSetup", "Effect", "ExtraFriction",
           "LoadRipple", "LoadSetup", "Misfire", "Param", "PressureGain", "PressureOffset", "RingWear",
           "SensorNoise", "SensorSetup", "TdcOffset", "ThermalShock", "ToothSpacingError", "TorsionalFlexibility", "VariableInertia",
           "auxiliaries_quadratic", "check_instances", "effect_class", "extra_friction_term", "make_effect",
           "parse_effect", "resolve_effects"]
