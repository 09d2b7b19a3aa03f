"""Model mismatches: plant physics the monitor is never told about (issue 16 item 5).

The monitor identifies the six Rezeka-Henein terms through the model's drive train. These effects make a plant that
differs from that model the way a real engine may, so that the monitor's sigmas can be checked on data its model did
not make (bench/mismatch_coverage.py, tests/core/test_mismatch_coverage.py):

    chain_mismatch             the shaft line's section stiffnesses and dampings x scale (the spec's are +-20 % off)
    flywheel_inertia           the flywheel node's inertia x scale (a flywheel or pulley changed, the record not)
    stribeck_ring              ring boundary friction on a Stribeck curve over the whole stroke (piston speed),
                               instead of the mixed-friction window of +-90 deg about firing TDC
    side_thrust_skirt          skirt friction as Coulomb friction on the gas side thrust (p A tan beta |x'|),
                               instead of the hydrodynamic shear
    cam_valve_train            valve-train friction following the cam lobes (half-order content), not the piston lever
    auxiliaries_speed_squared  auxiliaries growing with omega^2 (fan, windage) instead of omega
    bearings_load              bearing friction proportional to the gas load at any speed (boundary, no 1/sqrt(omega))

A friction-law effect moves ``fraction`` of a Rezeka-Henein term's mean at the operating point into its own term
(``CylinderSetup.transfers``; the simulator sizes the coefficient so the two means agree there). Its term is a plant
term (``Effect.plant_terms``), never an identification column (``monitor_terms`` is ()): the friction the plant
dissipates keeps its size at the requested point and changes its shape, its speed and its load dependence.
"""

from __future__ import annotations

from dataclasses import replace
from types import MappingProxyType

import numpy as np
from frictionwatch.core.model.chain import scaled_flywheel
from frictionwatch.core.model.effects.base import (
    BasisMeans,
    CandidateSpec,
    ChainSetup,
    CylinderSetup,
    Effect,
    Param,
    ViewSetup,
)
from frictionwatch.core.model.effects.loss_terms import auxiliaries_quadratic_kernel, auxiliaries_quadratic_reference
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.terms import (
    ANGLE,
    DX,
    LS,
    NC,
    NV,
    OMEGA,
    P_GAUGE,
    PE,
    RB,
    SIN,
    D,
    E,
    L,
    LossTerm,
    R,
    loss_kernel,
)

STRIBECK_SPEED = 1.0  # m/s: piston speed below which boundary friction takes over (rings: 0.5..2 m/s)
LOBE_CENTRES = (np.radians(255.0), np.radians(465.0))  # exhaust and intake lobe centres, local crank angle
LOBE_HALF_WIDTH = np.radians(115.0)  # half the valve-open duration in crank angle
LOBE_WEIGHT = 3.0  # friction at full lift against the base-circle friction (spring load on the follower)


# ---- plant-only loss terms (same contract as core.model.terms) --------------------------------------------------

def stribeck_ring_reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """F = pi D n_c (P_e + p) |x'| exp(-|omega x'| / c_s): boundary ring friction where the piston is slow."""
    lever = np.abs(s[DX])
    return np.pi * c[D] * c[NC] * (c[PE] + s[P_GAUGE]) * lever * np.exp(-s[OMEGA] * lever / STRIBECK_SPEED)


@loss_kernel
def stribeck_ring_kernel(s, c, out):
    k = np.pi * c[D] * c[NC]
    for j in range(out.shape[0]):
        for i in range(out.shape[1]):
            lever = abs(s[DX, j, i])
            out[j, i] = k * (c[PE] + s[P_GAUGE, j, i]) * lever * np.exp(-s[OMEGA, j, i] * lever / STRIBECK_SPEED)


def side_thrust_reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """F = (pi/4) D^2 p |tan beta| |x'|: Coulomb skirt friction on the gas side thrust (beta the rod angle)."""
    sb = (c[R] * s[SIN] - c[E]) / c[L]
    return 0.25 * np.pi * c[D] ** 2 * s[P_GAUGE] * np.abs(sb / np.sqrt(1.0 - sb * sb)) * np.abs(s[DX])


@loss_kernel
def side_thrust_kernel(s, c, out):
    k = 0.25 * np.pi * c[D] * c[D]
    for j in range(out.shape[0]):
        for i in range(out.shape[1]):
            sb = (c[R] * s[SIN, j, i] - c[E]) / c[L]
            out[j, i] = k * s[P_GAUGE, j, i] * abs(sb / np.sqrt(1.0 - sb * sb)) * abs(s[DX, j, i])


def cam_lobes_reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """F = N_v L_s (1 + w sum_lobes cos^2(pi/2 (angle - centre) / half_width)) / sqrt(omega): friction on the cam,
    highest while a lobe lifts its valve against the spring (two lobes per cylinder and cycle)."""
    lift = np.zeros_like(s[ANGLE])
    for centre in LOBE_CENTRES:
        d = s[ANGLE] - centre
        lift += np.where(np.abs(d) < LOBE_HALF_WIDTH, np.cos(0.5 * np.pi * d / LOBE_HALF_WIDTH) ** 2, 0.0)
    return c[NV] * c[LS] * (1.0 + LOBE_WEIGHT * lift) / np.sqrt(s[OMEGA])


@loss_kernel
def cam_lobes_kernel(s, c, out):
    k = c[NV] * c[LS]
    for j in range(out.shape[0]):
        for i in range(out.shape[1]):
            lift = 0.0
            for centre in LOBE_CENTRES:
                d = s[ANGLE, j, i] - centre
                if abs(d) < LOBE_HALF_WIDTH:
                    lift += np.cos(0.5 * np.pi * d / LOBE_HALF_WIDTH) ** 2
            out[j, i] = k * (1.0 + LOBE_WEIGHT * lift) / np.sqrt(s[OMEGA, j, i])


def load_bearings_reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """F = (pi/4) D^2 r_b p: boundary bearing friction proportional to the gas load, independent of speed."""
    return 0.25 * np.pi * c[D] ** 2 * c[RB] * s[P_GAUGE]


@loss_kernel
def load_bearings_kernel(s, c, out):
    k = 0.25 * np.pi * c[D] * c[D] * c[RB]
    for j in range(out.shape[0]):
        for i in range(out.shape[1]):
            out[j, i] = k * s[P_GAUGE, j, i]


# ---- effects -----------------------------------------------------------------------------------------------------

def _fraction(default: float, base: str) -> Param:
    return Param(default, "-", 0.0, 1.0, doc=f"share of the {base} term's mean friction at the operating point moved "
                                             "into this shape")


class _FrictionLaw(Effect):
    """A friction law of another shape: ``fraction`` of term ``base`` moved into the plant term ``term``."""

    base: str = ""
    term: LossTerm | None = None
    sized_at_reference = True
    candidate = CandidateSpec(("fraction",), (0.0,), (0.25,), (0.0,), (1.0,),
                              separated_by="another speed or load (friction laws agree where they were sized and part "
                                           "away from it)")

    def plant_terms(self, spec: EngineSpec) -> tuple[LossTerm, ...]:
        return (self.term,) if self.term is not None else ()

    def apply_cylinders(self, setup: CylinderSetup) -> CylinderSetup:
        if self.term is None or self.base not in setup.term_names:
            raise ValueError(f"effect '{self.name}': the model has no '{self.base}' term to reshape")
        return replace(setup, transfers=setup.transfers + ((self.base, self.term.name, self.values["fraction"]),))

    def size_view(self, setup: ViewSetup, means: BasisMeans) -> ViewSetup:
        """The law's term beside its base, ``fraction`` of the base's mean at the reference point moved into it by
        the simulator's rule (core.plant.operating_point.sized_transfers): the view predicts as the plant runs."""
        terms = setup.terms
        if self.term is None or self.base not in terms.names or self.term.name in terms.names:
            return setup
        lib = terms + self.term
        coef = np.column_stack([setup.coefficients, np.zeros(setup.spec.n_cyl)])
        m = means(setup.spec, lib)
        i, j, frac = lib.index(self.base), lib.index(self.term.name), self.values["fraction"]
        for k in range(setup.spec.n_cyl):
            moved = frac * coef[k, i] * m[k, i]
            if moved > 0.0 and m[k, j] > 0.0:
                coef[k, j] += moved / m[k, j]
                coef[k, i] *= 1.0 - frac
        return replace(setup, terms=lib, coefficients=coef)


class ChainMismatch(Effect):
    name = "chain_mismatch"
    # the speed is far from linear in the stiffness where a resonance moves through the engine orders: one
    # linearisation at the spec's line can point the wrong way (genset-v20 20 % softer: the candidate never reached
    # the held-out test). Refinements also start a third softer and a third stiffer than the spec (a shaft line
    # modelled from drawings is rarely known better; not set from the matrix's 0.8 and 1.5)
    candidate = CandidateSpec(("stiffness_scale", "damping_scale"), (1.0, 1.0), (0.1, 0.5), (0.5, 0.2), (2.0, 5.0),
                              requires="torsional_flexibility",
                              separated_by="the second wheel at the free end (the shaft line's twist)",
                              seeds=((0.75, 1.0), (4.0 / 3.0, 1.0)))
    description = "the shaft line's section stiffnesses and dampings differ from the spec's by a factor"
    parameters = MappingProxyType({
        "stiffness_scale": Param(1.2, "-", 0.5, 2.0, doc="plant stiffness / spec stiffness, every section"),
        "damping_scale": Param(1.0, "-", 0.2, 5.0, doc="plant damping / spec damping, every section"),
    })

    def apply_chain(self, setup: ChainSetup) -> ChainSetup:
        return replace(setup, stiffness_scale=setup.stiffness_scale * self.values["stiffness_scale"],
                       damping_scale=setup.damping_scale * self.values["damping_scale"])

    def apply_view(self, setup: ViewSetup) -> ViewSetup:
        spec = setup.spec
        return replace(setup, spec=replace(spec, stiffness=spec.stiffness * self.values["stiffness_scale"],
                                           damping=spec.damping * self.values["damping_scale"]))


class FlywheelInertia(Effect):
    name = "flywheel_inertia"
    # a flywheel replaced, a pulley or coupling added, and the engine record not updated (design note 109). Above
    # the line's lowest resonance the flywheel speed's swing at the firing orders goes as 1 / J, the same share at
    # every order; near it the inertia also moves the resonance (omega^2 = k / J) as a softer line would, which is
    # where one wheel cannot tell the two apart (design note 106: maruti 4000 rpm, k9k 1800 rpm). The range holds a
    # plant's flywheel swapped for a lighter or heavier one; no start points: the response was scanned smooth over
    # it (design note 109)
    candidate = CandidateSpec(("inertia_scale",), (1.0,), (0.05,), (0.7,), (1.5,),
                              separated_by="a motored run-down (its deceleration is the inertia alone), another "
                                           "speed (the line's resonance moves with its stiffness, the swing at every "
                                           "firing order with the inertia) or the second wheel at the free end")
    description = "the flywheel node's inertia differs from the record's by a factor (a flywheel or pulley changed)"
    parameters = MappingProxyType({
        "inertia_scale": Param(1.05, "-", 0.5, 2.0, doc="plant flywheel-node inertia / the record's"),
    })

    def apply_chain(self, setup: ChainSetup) -> ChainSetup:
        return replace(setup, flywheel_inertia_scale=setup.flywheel_inertia_scale * self.values["inertia_scale"])

    def apply_view(self, setup: ViewSetup) -> ViewSetup:
        return replace(setup, spec=scaled_flywheel(setup.spec, self.values["inertia_scale"]))


class StribeckRing(_FrictionLaw):
    name = "stribeck_ring"
    description = "ring boundary friction on a Stribeck curve of piston speed (replaces the +-90 deg mixed window)"
    parameters = MappingProxyType({"fraction": _fraction(1.0, "ring_mixed")})
    base = "ring_mixed"
    term = LossTerm("plant_stribeck_ring", "pi D n_c (P_e + p) |x'| exp(-|omega x'| / c_s)", "cylinder", "m", 0.0,
                    stribeck_ring_kernel, stribeck_ring_reference)


class SideThrustSkirt(_FrictionLaw):
    name = "side_thrust_skirt"
    description = "skirt friction as Coulomb friction on the gas side thrust (replaces part of the skirt shear)"
    parameters = MappingProxyType({"fraction": _fraction(0.5, "skirt_viscous")})
    base = "skirt_viscous"
    term = LossTerm("plant_side_thrust_skirt", "(pi/4) D^2 p |tan beta| |x'|", "cylinder", "-", 0.0,
                    side_thrust_kernel, side_thrust_reference)


class CamValveTrain(_FrictionLaw):
    name = "cam_valve_train"
    description = "valve-train friction following the cam lobes (half-order content) instead of the piston lever"
    parameters = MappingProxyType({"fraction": _fraction(1.0, "valve_train")})
    base = "valve_train"
    term = LossTerm("plant_cam_valve_train", "N_v L_s (1 + 3 lobe lift) / sqrt(omega)", "engine", "m s^-0.5", 0.0,
                    cam_lobes_kernel, cam_lobes_reference)


class SpeedSquaredAuxiliaries(_FrictionLaw):
    name = "auxiliaries_speed_squared"
    description = "auxiliary losses growing with omega^2 (fan, windage) instead of omega"
    parameters = MappingProxyType({"fraction": _fraction(0.5, "auxiliaries")})
    base = "auxiliaries"
    term = LossTerm("plant_auxiliaries_speed_squared", "omega^2", "engine", "N m s^2", 0.0,
                    auxiliaries_quadratic_kernel, auxiliaries_quadratic_reference)


class LoadBearings(_FrictionLaw):
    name = "bearings_load"
    description = "bearing friction proportional to the gas load at any speed (replaces the 1/sqrt(omega) law)"
    parameters = MappingProxyType({"fraction": _fraction(1.0, "loaded_bearings")})
    base = "loaded_bearings"
    term = LossTerm("plant_bearings_load", "(pi/4) D^2 r_b p", "engine", "m", 0.0, load_bearings_kernel,
                    load_bearings_reference)


MISMATCHES = (ChainMismatch, FlywheelInertia, StribeckRing, SideThrustSkirt, CamValveTrain, SpeedSquaredAuxiliaries,
              LoadBearings)

__all__ = ["MISMATCHES", "CamValveTrain", "ChainMismatch", "FlywheelInertia", "LoadBearings", "SideThrustSkirt",
           "SpeedSquaredAuxiliaries", "StribeckRing", "cam_lobes_reference", "load_bearings_reference",
           "side_thrust_reference", "stribeck_ring_reference"]
