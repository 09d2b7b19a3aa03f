"""Engine files: an ``EngineSpec`` (core/model/engine_spec.py) loaded from a TOML file in SI units (presets in
``core/model/engines/*.toml``; the keys carry their unit as a suffix, e.g. ``bore_m``). Validation names the bad
field, its value and the expected unit/range; a misspelt key is named with the nearest known one.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from pathlib import Path

import numpy as np

# the records live in engine_spec.py; most callers import them from here, beside load_engine
from frictionwatch.core.model.engine_spec import (  # noqa: F401
    CombustionParams,
    EngineSpec,
    FrictionParams,
    LoadParams,
    SecondWheelParams,
    SensorParams,
    SpecError,
    mep_per_torque,
)

PRESET_DIR = Path(__file__).parent / "engines"


def available_presets() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.toml"))


def load_engine(name_or_path: str | Path) -> EngineSpec:
    """Load a preset by name (``k9k-4cyl``) or a user TOML file by path. Raises ``SpecError`` with the field named."""
    p = Path(name_or_path)
    if not p.suffix:
        p = PRESET_DIR / f"{name_or_path}.toml"
        if not p.exists():
            raise SpecError(f"unknown engine '{name_or_path}'; presets: {', '.join(available_presets())}")
    if not p.exists():
        raise SpecError(f"engine file not found: {p}")
    text = read_engine_text(p)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{p.name}: not valid TOML: {exc}") from exc
    return spec_from_dict(data, source_text=text, origin=p.name)


def read_engine_text(path: Path) -> str:
    """The text of an engine or model file; SpecError naming the file when it is not UTF-8 text (a binary file)."""
    raw = path.read_bytes()
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SpecError(f"{path.name}: not a TOML text file (byte {exc.start} is not UTF-8 text)") from None


def nearest_known(key: str, known) -> str:
    """The known name closest to ``key`` (difflib), for 'unknown key ...; nearest known: ...' messages."""
    match = difflib.get_close_matches(key, list(known), n=1, cutoff=0.0)
    return match[0] if match else ""


def spec_from_toml_text(text: str, origin: str = "<text>") -> EngineSpec:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{origin}: not valid TOML: {exc}") from exc
    return spec_from_dict(data, source_text=text, origin=origin)


def _second_wheel(se: _Reader, names: list[str], origin: str) -> SecondWheelParams:
    """``[sensors.second_wheel]``: teeth, missing, first_tooth_deg, node (a shaft node name, default the free end)."""
    w = se.table("second_wheel")
    teeth = w.int_("teeth", 4, 2000)
    missing = w.int_("missing", 0, 4)
    if missing >= teeth // 2:
        raise SpecError(f"{origin}: sensors.second_wheel.missing = {missing} is too many for {teeth} teeth")
    node = w.str_("node", default=names[0])
    if node not in names:
        raise SpecError(f"{origin}: sensors.second_wheel.node = {node!r} is not in shaft.nodes")
    return SecondWheelParams(teeth=teeth, missing=missing,
                             first_tooth_deg=w.num("first_tooth_deg", -360.0, 360.0, "deg", default=0.0),
                             node=names.index(node))


SAME_ANGLE_DEG = 1e-3  # two firing angles closer than this (mod 720 deg) are one angle


def _one_angle_each(deg: np.ndarray, origin: str) -> np.ndarray:
    """``cylinders.firing_angles_deg`` as the crank-angle convention needs it: cylinder 1 at 0 (the angle's origin)
    and every cylinder at its own angle, 720 being 0 again. Else a pressure trace is placed at another cylinder's
    TDC and every figure is wrong, not refused."""
    if deg[0] != 0.0:
        raise SpecError(f"{origin}: cylinders.firing_angles_deg[0] = {deg[0]:g}; cylinder 1 fires at 0 deg (the "
                        "crank angle's origin)")
    for i in range(1, deg.shape[0]):
        gap = np.abs((deg[:i] - deg[i] + 360.0) % 720.0 - 360.0)
        if gap.min() < SAME_ANGLE_DEG:
            j = int(np.argmin(gap))
            raise SpecError(f"{origin}: cylinders.firing_angles_deg[{i}] = {deg[i]:g} is cylinder {j + 1}'s angle "
                            "too; each cylinder fires at its own angle in 0..720 deg")
    return deg


class _Reader:
    """Reads fields from one TOML table and names the path of a missing or bad one."""

    def __init__(self, data: dict, path: str, origin: str):
        self.data, self.path, self.origin = data, path, origin
        self.known: set[str] = set()  # every key this reader was asked for (present or defaulted)
        self.children: list[_Reader] = []

    def get(self, key: str, default: object = None) -> object:
        self.known.add(key)
        return self.data.get(key, default)

    def table(self, key: str) -> _Reader:
        v = self.get(key)
        if not isinstance(v, dict):
            raise self.missing(key, f"table [{self._name(key)}]")
        child = _Reader(v, self._name(key), self.origin)
        self.children.append(child)
        return child

    def missing(self, key: str, what: str) -> SpecError:
        """The error for a missing ``key``: a misspelling of it present in the table is named as the unknown key
        (``bore_mm`` for ``bore_m``), else the field is missing."""
        strays = [k for k in self.data if k not in self.known]
        close = difflib.get_close_matches(key, strays, n=1, cutoff=0.6)
        if close:
            return SpecError(f"{self.origin}: unknown key '{self._name(close[0])}'; nearest known: '{self._name(key)}'")
        return SpecError(f"{self.origin}: missing {what}")

    def refuse_unknown(self) -> None:
        """SpecError for the first key no field reads (a misspelling such as ``bore_mm`` would otherwise be ignored
        and its field take its default or fail as 'missing'), naming the nearest known key."""
        for key in self.data:
            if key not in self.known:
                raise SpecError(f"{self.origin}: unknown key '{self._name(key)}'; nearest known: "
                                f"'{self._name(nearest_known(key, self.known))}'")
        for child in self.children:
            child.refuse_unknown()

    def _name(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def num(self, key: str, lo: float, hi: float, unit: str, default: float | None = None) -> float:
        v = self.get(key, default)
        if v is None:
            raise self.missing(key, f"field {self._name(key)} [{unit}]")
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise SpecError(f"{self.origin}: {self._name(key)} = {v!r}: expected a number [{unit}]")
        if not math.isfinite(v) or not lo <= v <= hi:
            raise SpecError(f"{self.origin}: {self._name(key)} = {v!r} is out of range; expected {lo:g}..{hi:g} {unit}")
        return float(v)

    def int_(self, key: str, lo: int, hi: int, default: int | None = None) -> int:
        v = self.get(key, default)
        if v is None:
            raise self.missing(key, f"field {self._name(key)} (an integer)")
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise SpecError(f"{self.origin}: {self._name(key)} = {v!r}; expected an integer {lo}..{hi}")
        return v

    def arr(self, key: str, lo: float, hi: float, unit: str, length: int | None = None) -> np.ndarray:
        v = self.get(key)
        if v is None:
            raise self.missing(key, f"list {self._name(key)} [{unit}]")
        if not isinstance(v, list) or not v:
            raise SpecError(f"{self.origin}: {self._name(key)} = {v!r}; expected a list of numbers [{unit}]")
        for i, x in enumerate(v):
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise SpecError(f"{self.origin}: {self._name(key)}[{i}] = {x!r}: expected a number [{unit}]")
        a = np.asarray(v, dtype=np.float64)
        if length is not None and a.shape[0] != length:
            raise SpecError(f"{self.origin}: {self._name(key)} has {a.shape[0]} values; expected {length}")
        bad = ~np.isfinite(a) | (a < lo) | (a > hi)
        if bad.any():
            i = int(np.argmax(bad))
            raise SpecError(
                f"{self.origin}: {self._name(key)}[{i}] = {a[i]!r} is out of range; expected {lo:g}..{hi:g} {unit}"
            )
        return a

    def str_(self, key: str, choices: tuple[str, ...] | None = None, default: str | None = None) -> str:
        v = self.get(key, default)
        if v is None:
            raise self.missing(key, f"field {self._name(key)} (a string)")
        if not isinstance(v, str) or (choices and v not in choices):
            want = f"one of {', '.join(choices)}" if choices else "a string"
            raise SpecError(f"{self.origin}: {self._name(key)} = {v!r}; expected {want}")
        return v

    def bool_(self, key: str, default: bool) -> bool:
        v = self.get(key, default)
        if not isinstance(v, bool):
            raise SpecError(f"{self.origin}: {self._name(key)} = {v!r}; expected true or false")
        return v


def spec_from_dict(data: dict, source_text: str = "", origin: str = "<dict>") -> EngineSpec:
    r = _Reader(data, "", origin)
    name = r.str_("name")
    g = r.table("geometry")
    bore = g.num("bore_m", 0.01, 1.0, "m")
    stroke = g.num("stroke_m", 0.01, 3.0, "m")
    conrod = g.num("conrod_m", 0.02, 6.0, "m")
    if conrod <= 0.5 * stroke * 1.5:
        raise SpecError(f"{origin}: geometry.conrod_m = {conrod} must exceed 1.5 x crank radius ({0.75 * stroke:g} m)")
    cr = g.num("compression_ratio", 3.0, 30.0, "-")
    pin = g.num("pin_offset_m", -0.05, 0.05, "m", default=0.0)

    c = r.table("cylinders")
    z = c.int_("count", 1, 24)
    firing = np.radians(_one_angle_each(c.arr("firing_angles_deg", 0.0, 720.0, "deg", length=z), origin))
    m_rec = c.num("reciprocating_mass_kg", 0.01, 500.0, "kg")

    s = r.table("shaft")
    names = s.get("nodes")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise SpecError(f"{origin}: shaft.nodes must be a list of node names")
    twice = [x for i, x in enumerate(names) if x in names[:i]]
    if twice:  # a cylinder or the flywheel named by it would silently go to the first
        raise SpecError(f"{origin}: shaft.nodes names {twice[0]!r} twice; each node needs its own name")
    n = len(names)
    inertia = s.arr("inertia_kgm2", 1e-6, 1e5, "kg m^2", length=n)
    if n > 1:
        stiff = s.arr("stiffness_nm_per_rad", 0.0, 1e11, "N m/rad", length=n - 1)
        damp = s.arr("damping_nms_per_rad", 0.0, 1e7, "N m s/rad", length=n - 1)
    else:  # a rigid engine: couplings are not read (an empty list given for them is not an unknown key)
        for key in ("stiffness_nm_per_rad", "damping_nms_per_rad"):
            s.get(key)
        stiff = np.zeros(0)
        damp = np.zeros(0)
    nodes_of_cyl = c.get("node")
    if not isinstance(nodes_of_cyl, list) or len(nodes_of_cyl) != z:
        raise SpecError(f"{origin}: cylinders.node must list the shaft node name of each of the {z} cylinders")
    try:
        cyl_node = np.array([names.index(x) for x in nodes_of_cyl], dtype=np.int64)
    except ValueError as exc:
        raise SpecError(f"{origin}: cylinders.node names a node not in shaft.nodes: {exc}") from exc
    try:
        fly = names.index(s.str_("flywheel_node"))
        loadn = names.index(s.str_("load_node"))
    except ValueError as exc:
        raise SpecError(f"{origin}: shaft.flywheel_node/load_node must name a node in shaft.nodes") from exc

    f = r.table("friction")
    fr = FrictionParams(
        oil_viscosity_pa_s=f.num("oil_viscosity_pa_s", 1e-4, 1.0, "Pa s"),
        ring_tension_pa=f.num("ring_tension_pa", 1e4, 5e6, "Pa"),
        ring_thickness_m=f.num("ring_thickness_m", 1e-4, 0.02, "m"),
        compression_rings=f.int_("compression_rings", 1, 6),
        oil_rings=f.int_("oil_rings", 0, 4),
        skirt_length_m=f.num("skirt_length_m", 0.005, 0.5, "m"),
        skirt_film_m=f.num("skirt_film_m", 1e-6, 1e-3, "m"),
        valves=f.int_("valves", 1, 8),
        valve_spring_n_per_m=f.num("valve_spring_n_per_m", 1e2, 1e7, "N/m"),
        bearing_radius_m=f.num("bearing_radius_m", 0.003, 0.5, "m"),
        coefficients=f.arr("coefficients", 0.0, 1e6, "-", length=6),
    )

    b = r.table("combustion")
    comb = CombustionParams(
        fuel_mass_kg=b.num("fuel_mass_kg", 1e-7, 0.1, "kg"),
        lhv_j_per_kg=b.num("lhv_j_per_kg", 1e7, 1.5e8, "J/kg"),
        combustion_efficiency=b.num("combustion_efficiency", 0.5, 1.0, "-", default=0.98),
        start_deg=b.num("start_deg", -60.0, 30.0, "deg"),
        premixed_fraction=b.num("premixed_fraction", 0.0, 1.0, "-"),
        premixed_duration_deg=b.num("premixed_duration_deg", 1.0, 120.0, "deg"),
        diffusion_duration_deg=b.num("diffusion_duration_deg", 1.0, 180.0, "deg"),
        wiebe_a=b.num("wiebe_a", 1.0, 20.0, "-", default=6.9),
        premixed_exponent=b.num("premixed_exponent", 1.0, 10.0, "-", default=5.0),
        diffusion_exponent=b.num("diffusion_exponent", 1.0, 10.0, "-", default=2.5),
        p_ivc_pa=b.num("p_ivc_pa", 2e4, 1e6, "Pa"),
        t_ivc_k=b.num("t_ivc_k", 200.0, 600.0, "K"),
        p_intake_pa=b.num("p_intake_pa", 2e4, 1e6, "Pa"),
        p_exhaust_pa=b.num("p_exhaust_pa", 5e4, 1e6, "Pa"),
        t_wall_k=b.num("t_wall_k", 300.0, 800.0, "K", default=450.0),
        ivc_deg=b.num("ivc_deg", -220.0, -90.0, "deg", default=-150.0),
        evo_deg=b.num("evo_deg", 90.0, 180.0, "deg", default=130.0),
        part_load_p_ivc_scaling=b.bool_("part_load_p_ivc_scaling", False),
    )

    ld = r.table("load")
    load = LoadParams(
        kind=ld.str_("kind", ("speed_power", "grid")),
        exponent=ld.num("exponent", 0.0, 3.0, "-", default=1.0),
        grid_stiffness_nm_per_rad=ld.num("grid_stiffness_nm_per_rad", 0.0, 1e9, "N m/rad", default=0.0),
        grid_damping_nms_per_rad=ld.num("grid_damping_nms_per_rad", 0.0, 1e8, "N m s/rad", default=0.0),
    )

    se = r.table("sensors")
    teeth = se.int_("wheel_teeth", 4, 2000)
    sensors = SensorParams(
        wheel_teeth=teeth,
        wheel_missing=se.int_("wheel_missing", 0, 4),
        first_tooth_deg=se.num("first_tooth_deg", -360.0, 360.0, "deg", default=0.0),
        tick_hz=se.num("tick_hz", 1e5, 1e9, "Hz", default=10e6),
        pressure_rate_hz=se.num("pressure_rate_hz", 1e3, 1e6, "Hz", default=20e3),
        pressure_noise_pa=se.num("pressure_noise_pa", 0.0, 1e6, "Pa", default=2e3),
        pressure_adc_bits=se.int_("pressure_adc_bits", 8, 24, default=16),
        pressure_range_pa=se.num("pressure_range_pa", 1e6, 1e8, "Pa", default=25e6),
        has_cam=se.bool_("has_cam", True),
        second_wheel=_second_wheel(se, names, origin) if "second_wheel" in se.data else None,
    )
    if sensors.wheel_missing >= teeth // 2:
        raise SpecError(f"{origin}: sensors.wheel_missing = {sensors.wheel_missing} is too many for {teeth} teeth")

    op = r.table("operating")
    rated = op.num("rated_speed_rpm", 100.0, 20000.0, "rpm")
    rng = op.arr("speed_range_rpm", 50.0, 25000.0, "rpm", length=2)
    if not rng[0] < rated <= rng[1]:
        raise SpecError(f"{origin}: operating.speed_range_rpm {rng.tolist()} must contain rated_speed_rpm {rated}")
    rated_torque = op.num("rated_torque_nm", 0.1, 1e6, "N m")
    description = r.get("description", "")
    r.refuse_unknown()
    return EngineSpec(
        name=name,
        description=str(description),
        bore=bore,
        stroke=stroke,
        conrod=conrod,
        compression_ratio=cr,
        pin_offset=pin,
        firing_angles=firing,
        cylinder_node=cyl_node,
        reciprocating_mass=m_rec,
        node_names=tuple(names),
        node_inertia=inertia,
        stiffness=stiff,
        damping=damp,
        flywheel_node=fly,
        load_node=loadn,
        friction=fr,
        combustion=comb,
        load=load,
        sensors=sensors,
        rated_speed_rpm=rated,
        rated_torque_nm=rated_torque,
        speed_range_rpm=(float(rng[0]), float(rng[1])),
        source_text=source_text,
    )
