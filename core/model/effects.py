"""Named, parametrised effects of the plant simulator (docs/effects.md gives the physics of each).

An effect is a switchable piece of physics or a fault. Three (four with ``sensor_noise``) are on by default because every
real engine has them; the rest are faults and model gaps that the discrepancy workflow must find.

    parse_effect("ring_wear:cylinder=3,gain=1.4")  ->  ("ring_wear", {"cylinder": 3, "gain": 1.4, "mass_loss": 0.05})
    resolve_effects({"misfire": {"cylinder": 2}}, without={"tooth_spacing_error"}, n_cyl=4)
        -> every active effect with all its parameters filled in (defaults included)

Bad input raises ``ValueError`` with one line that names the problem.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Param:
    """One effect parameter: default, unit, valid closed range, integer or float."""

    default: float
    unit: str
    lo: float
    hi: float
    integer: bool = False
    doc: str = ""


@dataclass(frozen=True)
class Effect:
    name: str
    description: str  # one line of physics
    default_on: bool
    params: dict[str, Param] = field(default_factory=dict)


def _cyl(doc: str = "cylinder number, 1-based", allow_all: bool = False) -> Param:
    return Param(0 if allow_all else 1, "-", 0 if allow_all else 1, 24, integer=True, doc=doc)


EFFECTS: dict[str, Effect] = {e.name: e for e in [
    Effect("torsional_flexibility", "multi-DOF shaft line (damper, throws, flywheel, coupling, load); off = one rigid "
           "lumped shaft", True),
    Effect("variable_inertia", "each throw's J(theta) = J_rot + sum m_rec x'^2 and its 1/2 J' omega^2 term; off = "
           "constant mean inertia, no mass torque", True),
    Effect("tooth_spacing_error", "per-tooth angle errors of the crank wheel (sum zero) plus optional order-1 runout",
           True, {
               "sigma_deg": Param(0.03, "deg", 0.0, 0.5, doc="rms of the random per-tooth angle error"),
               "runout_deg": Param(0.0, "deg", 0.0, 2.0, doc="amplitude of the once-per-rev (eccentricity) error"),
               "runout_phase_deg": Param(0.0, "deg", -360.0, 360.0, doc="phase of the runout error"),
           }),
    Effect("sensor_noise", "edge-time jitter, pressure noise and load-reading noise at realistic levels; off = ideal "
           "sensors (timer and ADC quantisation remain)", True, {
               "edge_jitter_ns": Param(50.0, "ns", 0.0, 1e5, doc="rms jitter of each tooth / cam edge time"),
               "pressure_noise_scale": Param(1.0, "-", 0.0, 100.0, doc="multiplies sensors.pressure_noise_pa"),
               "load_noise_frac": Param(0.002, "-", 0.0, 0.2, doc="rms load-reading noise, fraction of rated torque"),
           }),
    Effect("tdc_offset", "the cylinder's true firing TDC lies deg later than the wheel says (cylinder=0: the whole "
           "wheel is mounted off, all cylinders)", False, {
               "deg": Param(0.5, "deg", -10.0, 10.0, doc="offset, + = TDC later than stated"),
               "cylinder": _cyl("cylinder, 0 = all (wheel offset)", allow_all=True),
           }),
    Effect("pressure_offset", "pressure sensor of one cylinder reads gain * p + offset (pegging / gain error)", False, {
        "cylinder": _cyl(),
        "pa": Param(2e4, "Pa", -1e6, 1e6, doc="additive offset"),
        "gain": Param(1.0, "-", 0.5, 1.5, doc="multiplicative gain"),
    }),
    Effect("load_ripple", "extra load torque ripple A sin(order theta_L + phase) at the load node", False, {
        "amplitude_nm": Param(0.0, "N m", 0.0, 1e6, doc="amplitude; 0 = fraction x mean load torque"),
        "fraction": Param(0.02, "-", 0.0, 1.0, doc="amplitude as a fraction of the mean load torque"),
        "order": Param(1.0, "-", 0.5, 50.0, doc="engine order (events per crank revolution)"),
        "phase_deg": Param(0.0, "deg", -360.0, 360.0),
    }),
    Effect("ring_wear", "worn rings in one cylinder: F1-F3 coefficients x gain and a blow-by leak", False, {
        "cylinder": _cyl(),
        "gain": Param(1.4, "-", 1.0, 5.0, doc="multiplies a_k1, a_k2, a_k3"),
        "mass_loss": Param(0.12, "-", 0.0, 0.4, doc="trapped-mass fraction lost IVC->EVO (sizes the leak area)"),
    }),
    Effect("blow_by", "blow-by leak only in one cylinder (lower compression and peak pressure)", False, {
        "cylinder": _cyl(),
        "mass_loss": Param(0.12, "-", 0.0, 0.4, doc="trapped-mass fraction lost IVC->EVO (sizes the leak area)"),
    }),
    Effect("extra_friction", "a friction term the 6-term model lacks: T = T_ref (mean_frac + amp_frac cos(order "
           "theta_k + phase)) in one cylinder", False, {
               "cylinder": _cyl(),
               "mean_frac": Param(0.1, "-", -1.0, 5.0, doc="constant part, fraction of the cylinder's mean friction"),
               "amp_frac": Param(0.0, "-", 0.0, 5.0, doc="order-n amplitude, fraction of the mean friction"),
               "order": Param(2.0, "-", 0.5, 50.0, doc="engine order of the varying part"),
               "phase_deg": Param(0.0, "deg", -360.0, 360.0),
           }),
    Effect("misfire", "cylinder gets no fuel in a cycle with the given probability (motored cycle)", False, {
        "cylinder": _cyl(),
        "probability": Param(1.0, "-", 0.0, 1.0),
    }),
]}


def _value(effect: Effect, key: str, raw: object) -> float | int:
    if key not in effect.params:
        known = ", ".join(effect.params) or "none"
        raise ValueError(f"effect '{effect.name}' has no parameter '{key}'; known: {known}")
    prm = effect.params[key]
    try:
        v = float(raw)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"effect '{effect.name}': {key}={raw!r} is not a number") from None
    if isinstance(raw, bool) or not math.isfinite(v) or not prm.lo <= v <= prm.hi:
        raise ValueError(f"effect '{effect.name}': {key}={raw!r} is out of range {prm.lo:g}..{prm.hi:g} {prm.unit}")
    if prm.integer:
        if v != int(v):
            raise ValueError(f"effect '{effect.name}': {key}={raw!r} must be an integer")
        return int(v)
    return v


def effect_params(name: str, params: dict | None = None) -> dict[str, float | int]:
    """All parameters of effect ``name`` (defaults overridden by ``params``), validated."""
    if name not in EFFECTS:
        raise ValueError(f"unknown effect '{name}'; known: {', '.join(EFFECTS)}")
    eff = EFFECTS[name]
    out = {k: (int(p.default) if p.integer else p.default) for k, p in eff.params.items()}
    for key, raw in (params or {}).items():
        out[key] = _value(eff, key, raw)
    return out


def parse_effect(text: str) -> tuple[str, dict[str, float | int]]:
    """``"NAME[:key=value,...]"`` -> (name, params with defaults filled in). Raises ValueError naming the problem."""
    name, _, rest = text.strip().partition(":")
    name = name.strip()
    given: dict[str, str] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq or not key.strip() or not val.strip():
            raise ValueError(f"effect '{name}': '{item}' is not key=value")
        given[key.strip()] = val.strip()
    return name, effect_params(name, given)


def resolve_effects(effects: dict[str, dict] | None, without: set[str] | tuple = (), n_cyl: int = 24
                    ) -> dict[str, dict[str, float | int]]:
    """Active effects with full parameters: the defaults-on ones minus ``without`` plus ``effects``.

    Raises ValueError for an unknown name, a bad parameter, an effect both requested and excluded, or a cylinder
    number above ``n_cyl``.
    """
    without = set(without)
    for name in without:
        if name not in EFFECTS:
            raise ValueError(f"unknown effect '{name}' in without; known: {', '.join(EFFECTS)}")
    active = {n: effect_params(n) for n, e in EFFECTS.items() if e.default_on and n not in without}
    for name, params in (effects or {}).items():
        if name in without:
            raise ValueError(f"effect '{name}' is both requested and excluded")
        active[name] = effect_params(name, params)
        cyl = active[name].get("cylinder")
        if cyl is not None and cyl > n_cyl:
            raise ValueError(f"effect '{name}': cylinder={cyl} but the engine has {n_cyl} cylinders")
    return active
