"""Engine specification: geometry, masses, shaft line, friction parameters, combustion defaults, sensors — the
records an engine file becomes (``core/model/engine.py`` reads and checks the file).

Crank-angle convention (design.md §3): 0 = firing TDC of cylinder 1, cycle 0..4*pi. ``firing_angles`` are the
cylinder-1 crank angles at which each cylinder is at its own firing TDC.

Shaft line (physics.md §11): nodes front to rear (damper ring, hub, throws, flywheel, load); ``stiffness[i]`` and
``damping[i]`` join node i and i+1. A single-node shaft is a rigid engine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


def mep_per_torque(displacement_m3: float) -> float:
    """4 pi / V_d [Pa per N m]: the one definition of a mean effective pressure from a mean torque (4-stroke: one
    cycle is 4 pi rad). ``displacement_m3``: one cylinder's swept volume for a cylinder's figure, the engine's total
    for the engine's (its total torque). Every FMEP, IMEP-from-torque and MEP-to-torque in the package goes through
    it (``EngineSpec.torque_to_mep`` / ``mep_to_torque``, the estimates, the cycle documents)."""
    return 4.0 * math.pi / displacement_m3


class SpecError(ValueError):
    """An engine file is missing a field or holds an impossible value."""


@dataclass(frozen=True)
class FrictionParams:
    """Rezeka-Henein physical parameters (physics.md §7, engines.md §4.1) and the truth coefficients a_l."""

    oil_viscosity_pa_s: float
    ring_tension_pa: float
    ring_thickness_m: float
    compression_rings: int
    oil_rings: int
    skirt_length_m: float
    skirt_film_m: float
    valves: int
    valve_spring_n_per_m: float
    bearing_radius_m: float
    coefficients: np.ndarray  # (6,) raw a_l used by the simulator as truth


@dataclass(frozen=True)
class CombustionParams:
    """Single-zone model defaults at full load (physics.md §13, engines.md §3)."""

    fuel_mass_kg: float  # per cylinder per cycle at load fraction 1
    lhv_j_per_kg: float
    combustion_efficiency: float
    start_deg: float  # start of combustion, deg relative to firing TDC (negative = BTDC)
    premixed_fraction: float  # beta_p; 0 gives a single Wiebe
    premixed_duration_deg: float
    diffusion_duration_deg: float
    wiebe_a: float
    premixed_exponent: float  # exponent of ((theta-theta_s)/dtheta), i.e. m+1
    diffusion_exponent: float
    p_ivc_pa: float  # at load fraction 1
    t_ivc_k: float
    p_intake_pa: float
    p_exhaust_pa: float
    t_wall_k: float
    ivc_deg: float  # relative to firing TDC, e.g. -150
    evo_deg: float  # e.g. +130
    part_load_p_ivc_scaling: bool  # gensets: p_IVC scales with load (boost); benches: it does not


@dataclass(frozen=True)
class LoadParams:
    """Load torque model (physics.md §5). kind: 'speed_power' T = c + k*omega**s, or 'grid'."""

    kind: str
    exponent: float  # s
    grid_stiffness_nm_per_rad: float
    grid_damping_nms_per_rad: float


@dataclass(frozen=True)
class SecondWheelParams:
    """A second tooth wheel (``[sensors.second_wheel]``), at shaft node ``node`` (index into ``EngineSpec.node_names``;
    default the free end, node 0): its own tooth count, missing-tooth gap and first edge after the gap, in the
    crank angle of cylinder 1's convention measured at that node."""

    teeth: int  # tooth positions including the missing ones
    missing: int
    first_tooth_deg: float
    node: int


@dataclass(frozen=True)
class SensorParams:
    wheel_teeth: int  # teeth positions on the wheel including the missing ones
    wheel_missing: int
    first_tooth_deg: float  # crank angle (cyl-1 convention) of the first tooth edge after the gap
    tick_hz: float  # acquisition timer clock
    pressure_rate_hz: float
    pressure_noise_pa: float
    pressure_adc_bits: int
    pressure_range_pa: float
    has_cam: bool
    second_wheel: SecondWheelParams | None = None  # none unless the engine file has [sensors.second_wheel]


@dataclass(frozen=True)
class EngineSpec:
    name: str
    description: str
    # geometry
    bore: float
    stroke: float
    conrod: float
    compression_ratio: float
    pin_offset: float
    # cylinders
    firing_angles: np.ndarray  # (z,) rad
    cylinder_node: np.ndarray  # (z,) int, shaft node index that carries each cylinder
    reciprocating_mass: float  # kg per cylinder
    # shaft line
    node_names: tuple[str, ...]
    node_inertia: np.ndarray  # (n,) kg m^2, rotating parts only
    stiffness: np.ndarray  # (n-1,) N m/rad
    damping: np.ndarray  # (n-1,) N m s/rad
    flywheel_node: int
    load_node: int
    friction: FrictionParams
    combustion: CombustionParams
    load: LoadParams
    sensors: SensorParams
    rated_speed_rpm: float
    rated_torque_nm: float
    speed_range_rpm: tuple[float, float]
    source_text: str = field(default="", repr=False, compare=False)

    # ---- derived quantities -------------------------------------------------------------------------------
    # Made once, at construction, from what cannot change (floats of a frozen record, array shapes), and plain
    # attributes rather than properties: the monitor reads them ~40 times a cycle, and as properties each read was
    # a call back into this file (design note 82). Not fields: equality, repr, asdict and replace see the record as
    # before (replace makes them again). n_cyl, n_nodes; piston_area [m^2]; displacement_cyl, displacement [m^3]
    # (one cylinder's swept volume, the engine's); mep_per_torque_cyl, mep_per_torque_engine [Pa per N m]:
    # mep_per_torque of those two volumes.
    def __post_init__(self) -> None:
        put = object.__setattr__  # a frozen record: its derived constants are set once, at construction
        put(self, "n_cyl", int(self.firing_angles.shape[0]))
        put(self, "n_nodes", int(self.node_inertia.shape[0]))
        put(self, "piston_area", math.pi * self.bore**2 / 4.0)
        put(self, "displacement_cyl", self.piston_area * self.stroke)
        put(self, "displacement", self.displacement_cyl * self.n_cyl)
        put(self, "mep_per_torque_cyl", mep_per_torque(self.displacement_cyl))
        put(self, "mep_per_torque_engine", mep_per_torque(self.displacement))

    @property
    def crank_radius(self) -> float:
        return 0.5 * self.stroke

    @property
    def clearance_volume(self) -> float:
        return self.displacement_cyl / (self.compression_ratio - 1.0)

    @property
    def total_inertia(self) -> float:
        """Constant (rotating) inertia of the whole shaft line, kg m^2."""
        return float(self.node_inertia.sum())

    def mep_to_torque(self, mep_pa: float, cylinders: int | None = None) -> float:
        """Mean torque [N m] of a mean effective pressure [Pa] over ``cylinders`` (default all), 4-stroke."""
        n = self.n_cyl if cylinders is None else cylinders
        return mep_pa / mep_per_torque(self.displacement_cyl * n)

    def torque_to_mep(self, torque_nm: float, cylinders: int | None = None) -> float:
        n = self.n_cyl if cylinders is None else cylinders
        return torque_nm * mep_per_torque(self.displacement_cyl * n)

    def kinematics_params(self) -> np.ndarray:
        """[R, L, pin_offset] for the kinematics kernels."""
        return np.array([self.crank_radius, self.conrod, self.pin_offset], dtype=np.float64)

    def friction_params(self) -> np.ndarray:
        """Constant parameters of the six Rezeka-Henein basis terms, in the order core.model.terms names them (CONSTS)."""
        f = self.friction
        return np.array(
            [
                self.crank_radius,
                self.conrod,
                self.pin_offset,
                self.bore,
                f.oil_viscosity_pa_s,
                f.ring_tension_pa,
                f.ring_thickness_m,
                float(f.compression_rings),
                float(f.oil_rings),
                f.skirt_length_m,
                f.skirt_film_m,
                float(f.valves),
                f.valve_spring_n_per_m,
                f.bearing_radius_m,
            ],
            dtype=np.float64,
        )


# ---- loading and validation --------------------------------------------------------------------------------
