"""Arrays of the time-domain plant (core.plant.plant) built from an EngineSpec, its initial state and its linearisation.

The shaft line is ``spec``'s drive train (core.model.chain: the same model the monitor's balance uses), or with
torsional flexibility off its one rigid node holding the whole inertia, all cylinders, the flywheel and the load.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from frictionwatch.core.model.chain import DriveTrain, drive_train, scaled_flywheel
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.terms import TermLibrary, rezeka_henein
from frictionwatch.core.model.thermo import P_CRANKCASE, CylinderModel
from frictionwatch.core.plant.plant import (
    NQ_GLOBAL,
    S_AREA,
    S_E,
    S_FLY,
    S_GRID,
    S_GRID_FRICTION,
    S_LOAD,
    S_MREC,
    S_NSC,
    S_PCC,
    S_R,
    S_VARJ,
    PlantArrays,
    PressureTraces,
    nq_cyl,
    plant_rhs,
    work_arrays,
)


@dataclass(frozen=True)
class PlantModel:
    """Numeric arrays of the plant: the drive train ``train`` (core.model.chain), ``phase`` (z,) true firing angles
    [rad], ``coef`` (z, L) coefficients of the L terms of ``library`` (core.model.terms), ``extra`` (z, 4) = [mean
    N m, amplitude N m, order, phase rad], and whether the throws' inertia varies with angle (physics.md §3)."""

    train: DriveTrain
    phase: np.ndarray
    coef: np.ndarray
    extra: np.ndarray
    variable_inertia: bool
    library: TermLibrary

    @property
    def inertia(self) -> np.ndarray:
        """(n,) inertia the kernel integrates with [kg m^2]: rotating, plus the mean reciprocating inertia of each
        throw when ``variable_inertia`` is off (on, the kernel adds m_rec x'^2 itself)."""
        return self.train.rotating if self.variable_inertia else self.train.mass

    @property
    def stiff(self) -> np.ndarray:
        return self.train.stiffness

    @property
    def damp(self) -> np.ndarray:
        return self.train.damping

    @property
    def cyl_node(self) -> np.ndarray:
        return self.train.cylinder_node

    @property
    def fly(self) -> int:
        return self.train.flywheel

    @property
    def load(self) -> int:
        return self.train.load

    @property
    def rec_mean(self) -> np.ndarray:
        return self.train.recip_inertia

    @property
    def cylinders(self) -> tuple:
        """The plant kernel's per-cylinder tuple ``cy``: (cyl_node, phase, coef, extra, the library's kernels)."""
        return (self.cyl_node, self.phase, self.coef, self.extra, self.library.kernels)

    @property
    def nq_cyl(self) -> int:
        """Integrated powers per cylinder (gas, one per loss term, extra friction)."""
        return nq_cyl(len(self.library))

    @property
    def n(self) -> int:
        return self.train.n_nodes

    @property
    def mean_inertia(self) -> np.ndarray:
        """Constant-inertia (M) diagonal [kg m^2]: rotating plus mean reciprocating inertia per node."""
        return self.train.mass


def build_plant(spec: EngineSpec, *, flexible: bool, variable: bool, coef: np.ndarray, phase: np.ndarray,
                extra: np.ndarray, library: TermLibrary | None = None, stiffness_scale: float = 1.0,
                damping_scale: float = 1.0, flywheel_inertia_scale: float = 1.0) -> PlantModel:
    """The plant of ``spec``: its drive train (core.model.chain.drive_train, one rigid node unless ``flexible``; the
    sections' stiffness and damping x the scales, the flywheel node's inertia x its scale before a rigid line sums
    the nodes: a chain the monitor is not told about); coef (z, L) the coefficients of the terms of ``library``
    (default: the six Rezeka-Henein terms, core.model.terms.rezeka_henein)."""
    z = spec.n_cyl
    lib = rezeka_henein(spec.friction.coefficients) if library is None else library
    if np.shape(coef) != (z, len(lib)):
        raise ValueError(f"coef must be (z, L) = ({z}, {len(lib)}) for the library's terms, got {np.shape(coef)}")
    if flywheel_inertia_scale != 1.0:
        spec = scaled_flywheel(spec, flywheel_inertia_scale)
    train = drive_train(spec, flexible)
    if stiffness_scale != 1.0 or damping_scale != 1.0:
        train = replace(train, stiffness=train.stiffness * stiffness_scale, damping=train.damping * damping_scale)
    return PlantModel(train, np.asarray(phase, dtype=np.float64).copy(),
                      np.ascontiguousarray(coef, dtype=np.float64), np.ascontiguousarray(extra, dtype=np.float64),
                      bool(variable), lib)


def scalars(spec: EngineSpec, plant: PlantModel) -> np.ndarray:
    """The constant part of the kernel's scalar vector (the simulator fills the event and timing slots)."""
    sc = np.zeros(S_NSC)
    sc[S_R:S_E + 1] = spec.kinematics_params()
    sc[S_AREA] = spec.piston_area
    sc[S_PCC] = P_CRANKCASE
    sc[S_MREC] = spec.reciprocating_mass
    sc[S_VARJ] = 1.0 if plant.variable_inertia else 0.0
    sc[S_FLY] = plant.fly
    sc[S_LOAD] = plant.load
    sc[S_GRID] = np.pi / 180.0
    sc[S_GRID_FRICTION] = 1.0  # the friction on the 1-deg grid evaluated (PlantRun may turn it off)
    return sc


def static_twist(plant: PlantModel, node_torque: np.ndarray) -> np.ndarray:
    """Node angles [rad] relative to the flywheel under constant node torques (the drive train's static twist)."""
    return plant.train.static_twist(node_torque)


def chain_matrices(plant: PlantModel, grid_stiffness: float = 0.0, grid_damping: float = 0.0
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M, K, C) of the linear model (mean inertia; load-to-grid spring and damper on the load node)."""
    return plant.train.matrices(grid_stiffness, grid_damping)


def linearised_stiffness(spec: EngineSpec, plant: PlantModel, tmodel: CylinderModel, load_law: np.ndarray,
                         step: float = 1e-6) -> np.ndarray:
    """-d(alpha)/d(theta) of the plant kernel's own right-hand side by central differences (no gas, no friction,
    constant inertia), i.e. M^-1 K as the simulator integrates it."""
    n, z = plant.n, spec.n_cyl
    sc = scalars(spec, plant)
    sc[S_VARJ] = 0.0
    inertia = plant.mean_inertia.copy()
    nd = (inertia, plant.stiff, plant.damp, np.zeros(n), np.zeros(n), np.zeros(n))
    cy = (plant.cyl_node, plant.phase, np.zeros_like(plant.coef), np.zeros((z, 4)), plant.library.kernels)
    traces = np.full((z, 3, tmodel.theta.shape[0]), P_CRANKCASE)
    slots = np.array([[0, 1, -1]] * z, dtype=np.int64)  # slot c % 3 holds cycle c = -1, 0, 1, all at crankcase pressure
    w = work_arrays(z, len(plant.library))
    acc = np.zeros(n)
    pw = np.zeros(z * plant.nq_cyl + NQ_GLOBAL)
    law = load_law.copy()
    law[6] = 0.0  # no damping
    model = PlantArrays(nd, cy, sc, spec.friction_params(), law, PressureTraces(traces, slots, tmodel.step))
    jac = np.zeros((n, n))
    for i in range(n):
        cols = []
        for sgn in (1.0, -1.0):
            th = np.zeros(n)
            th[i] = sgn * step
            plant_rhs(0.0, th, np.full(n, law[8]), model, w, acc, pw)
            cols.append(acc.copy())
        jac[:, i] = -(cols[0] - cols[1]) / (2 * step)
    return jac
