"""One engine model shared by the simulator, the monitor and the discrepancy workflow.

An ``EngineModel`` is an engine spec, a loss-term library with its coefficients a_kl (one row per cylinder), and the
effects (with their parameters, optionally a sigma each when fitted) that act on the plant. It reads and writes one
TOML file: the engine spec's own text (the preset format, verbatim) followed by

    [model.terms]
    names = ["ring_viscous", "ring_mixed", "skirt_viscous", "valve_train", "auxiliaries", "loaded_bearings",
             "auxiliaries_quadratic"]

    [model.coefficients]                       # a_kl, cylinder 1 first
    ring_viscous = [0.84, 0.84, 0.84, 0.84]
    ...
    auxiliaries_quadratic = [0.0, 0.0, 0.0, 0.0]

    [[model.effects]]
    name = "ring_wear"
    cylinder = 2
    gain = 1.4
    mass_loss = 0.12
    sigma = { gain = 0.05 }                    # optional: standard deviation of fitted parameters

    [model.calibration]                        # optional: how well the sensors are known (core.model.calibration);
    status = "commissioned"                    # absent: uncalibrated, a typical installation's sigmas
    tdc_wheel_sigma_deg = 0.05

A term is known by name: the six Rezeka-Henein terms, ``auxiliaries_quadratic`` and the terms of the model's effects
(``Effect.monitor_terms``). Unknown keys are refused naming the key and the nearest known one.
"""

from __future__ import annotations

import dataclasses
import re
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np
from frictionwatch.core.model.calibration import Calibration, calibration_from_dict, calibration_toml
from frictionwatch.core.model.effects import (
    EFFECTS,
    Effect,
    auxiliaries_quadratic,
    check_instances,
    make_effect,
    resolve_effects,
)
from frictionwatch.core.model.engine import (
    EngineSpec,
    SpecError,
    load_engine,
    nearest_known,
    read_engine_text,
    spec_from_dict,
)
from frictionwatch.core.model.terms import LossTerm, TermLibrary, rezeka_henein

SPEC_TABLES = ("name", "description", "geometry", "cylinders", "shaft", "friction", "combustion", "load", "sensors",
               "operating")
MODEL_MARKER = "# ---- engine model (core/model/engine_model.py)"


def known_terms(spec: EngineSpec, effects: Iterable[Effect] = ()) -> dict[str, LossTerm]:
    """Every loss term a model of ``spec`` with ``effects`` may name: Rezeka-Henein, auxiliaries_quadratic, and the
    effects' own terms (priors: the spec's coefficients for the six, 0 for the others)."""
    terms = list(rezeka_henein(spec.friction.coefficients)) + [auxiliaries_quadratic()]
    for e in effects:
        terms.extend(e.monitor_terms(spec))
    return {t.name: t for t in terms}


@dataclasses.dataclass(frozen=True, eq=False)
class EngineModel:
    """spec; terms (the loss-term library); coefficients (z, len(terms)) a_kl; effects (active instances);
    calibration: how well the sensors are known (core.model.calibration; the default: uncalibrated)."""

    spec: EngineSpec
    terms: TermLibrary
    coefficients: np.ndarray
    effects: tuple[Effect, ...] = ()
    calibration: Calibration = Calibration()

    def __post_init__(self) -> None:
        z, n = self.spec.n_cyl, len(self.terms)
        coef = np.array(self.coefficients, dtype=np.float64)
        if coef.shape != (z, n) or not np.all(np.isfinite(coef)) or np.any(coef < 0):
            raise ValueError(f"coefficients must be a ({z}, {n}) array (cylinders x terms) of finite values >= 0, "
                             f"got shape {coef.shape}")
        coef.setflags(write=False)
        object.__setattr__(self, "coefficients", coef)
        object.__setattr__(self, "effects", check_instances(self.effects, z))
        if not isinstance(self.calibration, Calibration):
            raise TypeError(f"calibration must be a Calibration, got {type(self.calibration).__name__}")

    # ---- construction ---------------------------------------------------------------------------------------------
    @classmethod
    def from_spec(cls, spec: EngineSpec, effects: Mapping[str, Mapping] | Iterable[Effect] | None = None,
                  without: Iterable[str] = (), coefficients: np.ndarray | None = None) -> EngineModel:
        """The spec's Rezeka-Henein model: its coefficients for every cylinder (or ``coefficients`` (z, 6)), the
        default-on effects minus ``without`` plus ``effects`` (core.model.effects.resolve_effects)."""
        z = spec.n_cyl
        coef = np.tile(spec.friction.coefficients, (z, 1)) if coefficients is None else coefficients
        return cls(spec, rezeka_henein(spec.friction.coefficients), coef, resolve_effects(effects, without, z))

    def with_term(self, term: LossTerm, coefficients: np.ndarray | float | None = None) -> EngineModel:
        """This model with ``term`` appended; its coefficients (scalar or (z,)) default to the term's prior."""
        z = self.spec.n_cyl
        col = np.broadcast_to(np.asarray(term.prior if coefficients is None else coefficients, float), (z,))
        return dataclasses.replace(self, terms=self.terms + term,
                                   coefficients=np.column_stack([self.coefficients, col]))

    def with_effect(self, effect: Effect) -> EngineModel:
        """This model with one more effect instance (a repeated one is refused); the terms are unchanged."""
        return dataclasses.replace(self, effects=self.effects + (effect,))

    def monitor_terms(self) -> tuple[LossTerm, ...]:
        """The identification columns the model's effects add (each once, those already in the library left out)."""
        have, out = set(self.terms.names), []
        for e in self.effects:
            for t in e.monitor_terms(self.spec):
                if t.name not in have:
                    have.add(t.name)
                    out.append(t)
        return tuple(out)

    def augmented(self) -> EngineModel:
        """This model with the effects' monitor terms added at their priors: what the monitor identifies."""
        model = self
        for t in self.monitor_terms():
            model = model.with_term(t)
        return model

    # ---- comparison -----------------------------------------------------------------------------------------------
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, EngineModel):
            return NotImplemented
        return (_same(self.spec, other.spec) and _terms_key(self.terms) == _terms_key(other.terms)
                and np.array_equal(self.coefficients, other.coefficients) and self.effects == other.effects
                and self.calibration == other.calibration)

    __hash__ = None  # type: ignore[assignment]

    # ---- TOML -----------------------------------------------------------------------------------------------------
    def to_toml(self) -> str:
        """The spec's TOML text (verbatim) plus the [model] tables; ``from_toml`` reads it back equal."""
        text = self.spec.source_text.rstrip()
        if not text:
            raise ValueError(f"engine {self.spec.name!r} has no TOML text (built from a dict); load it from a file")
        lines = [text, "", MODEL_MARKER + ": loss terms, coefficients a_kl per cylinder, effects ----",
                 "[model.terms]", f"names = [{', '.join(_str(n) for n in self.terms.names)}]", "",
                 "[model.coefficients]  # one value per cylinder, cylinder 1 first"]
        for i, name in enumerate(self.terms.names):
            lines.append(f"{name} = [{', '.join(repr(float(v)) for v in self.coefficients[:, i])}]")
        for e in self.effects:
            lines += ["", "[[model.effects]]", f"name = {_str(e.name)}"]
            lines += [f"{k} = {v!r}" for k, v in e.values.items()]
            if e.sigma:
                lines.append("sigma = { " + ", ".join(f"{k} = {v!r}" for k, v in e.sigma.items()) + " }")
        cal = calibration_toml(self.calibration)
        if cal:
            lines += ["", cal.rstrip()]
        return "\n".join(lines) + "\n"

    @classmethod
    def from_toml(cls, text: str, origin: str = "<model>") -> EngineModel:
        """Read a model file (``to_toml``'s layout). Raises ValueError naming a bad or unknown key."""
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise SpecError(f"{origin}: not valid TOML: {exc}") from exc
        _known_keys(data, SPEC_TABLES + ("model",), "", origin)
        model = data.pop("model", {})
        spec = spec_from_dict(data, source_text=_spec_text(text), origin=origin)
        _known_keys(model, ("terms", "coefficients", "effects", "calibration"), "model.", origin)
        try:
            calibration = calibration_from_dict(model.get("calibration", {}))
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{origin}: {exc}") from None
        for key in ("tdc_cylinder_reading_deg", "tdc_cylinder_sigmas_deg", "gain_sigmas"):
            per_cylinder = getattr(calibration, key)
            if per_cylinder and len(per_cylinder) != spec.n_cyl:
                raise ValueError(f"{origin}: model.calibration.{key} has {len(per_cylinder)} numbers for "
                                 f"{spec.n_cyl} cylinders")
        if "effects" in model:  # exactly the listed instances; none listed: the default-on effects
            effects = tuple(_effect(entry, i, origin) for i, entry in enumerate(_list(model, "effects", origin)))
        else:
            effects = resolve_effects(None, (), spec.n_cyl)
        table = model.get("terms", {})
        _known_keys(table, ("names",), "model.terms.", origin)
        names = table.get("names", list(rezeka_henein().names))
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise ValueError(f"{origin}: model.terms.names must be a list of term names")
        known = known_terms(spec, effects)
        for n in names:
            if n not in known:
                raise ValueError(f"{origin}: unknown loss term {n!r} in model.terms.names; nearest known: "
                                 f"{_nearest(n, known)!r}")
        terms = TermLibrary(tuple(known[n] for n in names))
        coef_table = model.get("coefficients", {})
        _known_keys(coef_table, tuple(names), "model.coefficients.", origin)
        z = spec.n_cyl
        cols = []
        for t in terms:
            raw = coef_table.get(t.name, [t.prior] * z)
            if not isinstance(raw, list) or len(raw) != z:
                raise ValueError(f"{origin}: model.coefficients.{t.name} must list {z} values (one per cylinder)")
            for v in raw:
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise ValueError(f"{origin}: model.coefficients.{t.name} = {v!r}: expected a number")
            cols.append(np.asarray(raw, dtype=np.float64))
        return cls(spec, terms, np.column_stack(cols), effects, calibration)


def load_model(name_or_path: str | Path) -> EngineModel:
    """A preset name or TOML file: a model file (with ``[model]`` tables, as ``EngineModel.to_toml`` writes) as it
    says, a plain engine file or preset as its spec's default model."""
    p = Path(name_or_path)
    if p.suffix and p.exists():
        text = read_engine_text(p)
        try:
            is_model = "model" in tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise SpecError(f"{p.name}: not valid TOML: {exc}") from exc
        if is_model:
            return EngineModel.from_toml(text, origin=p.name)
    return EngineModel.from_spec(load_engine(name_or_path))


def as_model(engine: EngineModel | EngineSpec) -> EngineModel:
    """``engine`` itself if it is a model, else the spec's default model (``EngineModel.from_spec``)."""
    if isinstance(engine, EngineModel):
        return engine
    if isinstance(engine, EngineSpec):
        return EngineModel.from_spec(engine)
    raise TypeError(f"expected an EngineModel or an EngineSpec, got {type(engine).__name__}")


# ---- helpers --------------------------------------------------------------------------------------------------

def _nearest(key: str, known: Iterable[str]) -> str:
    return nearest_known(key, known)  # one rule for engine and model files (core.model.engine)


def _known_keys(table: object, known: tuple[str, ...], prefix: str, origin: str) -> None:
    if not isinstance(table, dict):
        raise ValueError(f"{origin}: {prefix.rstrip('.')} must be a table")
    for key in table:
        if key not in known:
            raise ValueError(f"{origin}: unknown key '{prefix}{key}'; nearest known: '{prefix}{_nearest(key, known)}'")


def _list(table: dict, key: str, origin: str) -> list:
    v = table.get(key, [])
    if not isinstance(v, list):
        raise ValueError(f"{origin}: model.{key} must be an array of tables ([[model.{key}]])")
    return v


def _effect(entry: object, i: int, origin: str) -> Effect:
    where = f"model.effects[{i}]"
    if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
        raise ValueError(f"{origin}: {where} needs name = \"<effect>\"")
    name = entry["name"]
    if name not in EFFECTS:
        raise ValueError(f"{origin}: {where}: unknown effect '{name}'; nearest known: '{_nearest(name, EFFECTS)}'")
    params = {k: v for k, v in entry.items() if k not in ("name", "sigma")}
    _known_keys(params, tuple(EFFECTS[name].parameters) + ("name", "sigma"), f"{where}.", origin)
    sigma = entry.get("sigma", {})
    _known_keys(sigma, tuple(EFFECTS[name].parameters), f"{where}.sigma.", origin)
    try:
        return make_effect(name, params, sigma)
    except ValueError as exc:
        raise ValueError(f"{origin}: {where}: {exc}") from None


_HEADER = re.compile(r"^\s*\[\[?\s*([A-Za-z0-9_\-]+)[\s.\]]")


def _spec_text(text: str) -> str:
    """The text without the [model...] tables (and the marker line), so that to_toml does not repeat them."""
    out, in_model = [], False
    for line in text.splitlines():
        m = _HEADER.match(line)
        if m:
            in_model = m.group(1) == "model"
        if not in_model and not line.startswith(MODEL_MARKER):
            out.append(line)
    return "\n".join(out).rstrip() + "\n"


def _str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _terms_key(lib: TermLibrary) -> tuple:
    return tuple((t.name, t.equation, t.group, t.unit, t.prior) for t in lib)


def _same(a: object, b: object) -> bool:
    """Field-wise equality of (nested) frozen dataclasses holding numpy arrays; fields with compare=False skipped."""
    if dataclasses.is_dataclass(a) and type(a) is type(b):
        return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a) if f.compare)
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(a, b)
    return a == b


__all__ = ["EngineModel", "known_terms"]
