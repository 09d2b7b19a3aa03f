"""What the monitor makes of an EngineModel's effects: the model as the monitor runs it (core.monitor.pipeline) and as
the discrepancy workflow predicts with it.

The monitor (core.monitor) reads a spec, a loss-term library and its coefficients. The effects of a model are
plant physics; each effect also says what the monitor makes of it (``Effect.apply_view`` and, for a friction shape
sized at an operating point, ``Effect.size_view``: core/model/effects), so that a model augmented with a found effect
predicts the flywheel speed with it. What the catalogue's effects do here:

    torsional_flexibility absent   the spec's shaft line collapsed to one rigid node
    variable_inertia absent        ``variable_inertia`` False: constant inertia, no mass torque
    chain_mismatch                 the spec's section stiffnesses and dampings x their scales
    tdc_offset                     the cylinder's kinematic phase: its firing angle + deg (cylinder 0, a wheel
                                   mounted off: every cylinder's), as the plant has it; the pressure stays as read
    pressure_gain, pressure_offset a correction of the measured pressure before the monitor (gain, pegging)
    thermal_shock                  its error added back to the measured pressure, at the cycle's own speed and
                                   load (torque over rated; the simulator's is its fuel's)
    ring_wear                      the scaled coefficients of its terms in its cylinder (``Effect.scales_terms``)
    extra_friction                 its shape as one more loss term (``Effect.monitor_terms``), T_ref = the
                                   cylinder's mean friction at the reference operating point
    friction laws (mismatch.py)    ``fraction`` of the base term's mean moved into the law's term, sized at the
                                   reference operating point as the simulator sizes it
    load_ripple                    a known load torque at the load node (the monitor subtracts it from the known
                                   node torques, core.monitor.balance.harmonic_balance)

One translation for every user: core.monitor.pipeline turns the view into the monitor's model and config
(``monitor_config``). The discrepancy workflow pins the friction scales to the model (its ``pinned_config``): its
question is whether the model, as it stands, reproduces the measured speed and mean torque balance, not what the
monitor would refit. ``analyze`` and ``serve`` pass their config as it is: the model's coefficients are the prior and
the identification is free, as for any model.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.model.effects.base import ShockView, ViewSetup
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.terms import TermLibrary, cylinder_samples
from frictionwatch.core.model.thermal_shock import cycle_error, load_scale
from frictionwatch.core.model.thermo import P_CRANKCASE
from frictionwatch.core.types import Cycle


@dataclass(frozen=True)
class Reference:
    """An operating point to size friction shapes at: mean speed [rad/s] and each cylinder's measured pressure
    (z, n) [Pa] on the cycle grid (n,) [rad] (a typical cycle of the log)."""

    omega: float
    grid: np.ndarray
    pressure: np.ndarray


def reference(cycles: Sequence[Cycle]) -> Reference:
    """A typical cycle: the mean speed of all cycles and the median pressure (robust to a misfire) on the grid."""
    omegas = [c.mean_omega for c in cycles]
    grid = cycles[0].grid
    same = [c.pressure for c in cycles if c.grid.shape == grid.shape]
    return Reference(float(np.median(omegas)), grid, np.median(np.stack(same), axis=0))


def needs_reference(model: EngineModel) -> bool:
    """Whether ``monitor_view`` sizes a friction shape of ``model`` at an operating point (extra_friction, a
    friction law): only then does it read its ``ref``."""
    return any(e.sized_at_reference for e in model.effects)


@dataclass(frozen=True)
class MonitorView:
    """spec (firing angles with any TDC offset), terms and coefficients the monitor identifies with; whether the
    inertia varies with crank angle (the model has ``variable_inertia``); the pressure corrections per cylinder:
    gain (z,), offset (z,) Pa, a thermal-shock error added back (``shock``, None: none); the model's calibration
    (what its sensor effects leave unknown); a known load-torque ripple (amplitude [N m], fraction of the mean load
    torque, order, phase [rad]; zeros: none)."""

    spec: EngineSpec
    terms: TermLibrary
    coefficients: np.ndarray
    variable_inertia: bool
    gain: np.ndarray
    offset: np.ndarray
    calibration: Calibration
    load_ripple: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    shock: ShockView | None = None

    @property
    def model(self) -> EngineModel:
        return EngineModel(self.spec, self.terms, self.coefficients, ())

    @property
    def corrects_pressure(self) -> bool:
        return bool(np.any(self.gain != 1) or np.any(self.offset != 0)
                    or (self.shock is not None and np.any(self.shock.size_pa != 0)))


def rigid_spec(spec: EngineSpec) -> EngineSpec:
    """The spec's shaft line as one rigid node (core.model.chain.drive_train's rigid equivalent)."""
    z = spec.n_cyl
    return dataclasses.replace(spec, node_names=("crank",), node_inertia=np.array([float(spec.node_inertia.sum())]),
                               stiffness=np.zeros(0), damping=np.zeros(0), cylinder_node=np.zeros(z, dtype=np.int64),
                               flywheel_node=0, load_node=0)


def basis_means(spec: EngineSpec, terms: TermLibrary, ref: Reference) -> np.ndarray:
    """(z, L) cycle means of every term's basis F_l in each cylinder at the reference point (measured pressure)."""
    consts = spec.friction_params()
    rows = [cylinder_samples(np.mod(ref.grid - spec.firing_angles[k], 4.0 * np.pi), ref.omega,
                             ref.pressure[k] - P_CRANKCASE, consts) for k in range(spec.n_cyl)]
    return terms.evaluate(np.stack(rows, axis=1), consts).mean(axis=2)


def monitor_view(model: EngineModel, ref: Reference | None) -> MonitorView:
    """The monitor's side of ``model``: every effect's ``apply_view``, then every shape's ``size_view`` at ``ref``
    (None only when ``needs_reference(model)`` is false), then the shaft line made rigid where no effect made it
    flexible, and the phases moved (after the shapes: the plant sizes them at the stated phases)."""
    if ref is None and needs_reference(model):
        raise ValueError("the model's friction shapes are sized at an operating point: monitor_view needs a Reference")
    setup = ViewSetup.nominal(model.spec, model.terms, model.coefficients)
    for e in model.effects:
        setup = e.apply_view(setup)
    for e in model.effects:
        setup = e.size_view(setup, lambda spec, terms: basis_means(spec, terms, ref))
    spec = setup.spec if setup.flexible else rigid_spec(setup.spec)
    if np.any(setup.tdc):
        spec = dataclasses.replace(spec, firing_angles=spec.firing_angles + setup.tdc)
    return MonitorView(spec, setup.terms, setup.coefficients, setup.variable_inertia, setup.gain, setup.offset,
                       model.calibration, setup.load_ripple, setup.shock)


def corrected_pressure(view: MonitorView, pressure: np.ndarray, shock_error: np.ndarray | None = None) -> np.ndarray:
    """The measured pressure (z, n) as the model says it truly is: p = (p_read - offset) / gain - shock_error (the
    reading's thermal-shock error (z, n), <= 0, on the same samples: ``cycle_shock_error``; None: none)."""
    if not view.corrects_pressure:
        return pressure
    p = (np.asarray(pressure, dtype=np.float64) - view.offset[:, None]) / view.gain[:, None]
    return p if shock_error is None else p - shock_error


def cycle_shock_error(view: MonitorView, cycle: Cycle) -> np.ndarray | None:
    """(z, n) the thermal-shock error [Pa] of ``cycle``'s readings under ``view`` (None: the view has none): at the
    cycle's mean speed, sized at its load as the measured torque over the rated one (1 where it is not measured)."""
    s = view.shock
    if s is None or not np.any(s.size_pa != 0):
        return None
    load = cycle.load_torque / view.spec.rated_torque_nm if np.isfinite(cycle.load_torque) else 1.0
    return cycle_error(cycle.grid, view.spec.firing_angles, cycle.mean_omega, view.spec.combustion.start_deg,
                       s.size_pa * load_scale(load, s.idle), s.tau_s)


def viewed_cycle(view: MonitorView, cycle: Cycle) -> Cycle:
    """``cycle`` as the monitor gets it under ``view``: its pressure corrected (the cycle itself when nothing is)."""
    if not view.corrects_pressure:
        return cycle
    return dataclasses.replace(cycle, pressure=corrected_pressure(view, cycle.pressure, cycle_shock_error(view, cycle)))


__all__ = ["MonitorView", "Reference", "basis_means", "corrected_pressure", "cycle_shock_error", "monitor_view", "needs_reference",
           "reference", "rigid_spec", "viewed_cycle"]
