"""Step 1b of a cycle with a second (free-end) wheel: its own motion from its own tooth times (issue 29 item 1).

The second wheel's edges (``Cycle.wheel2``, cut by the assembler on the crank angle of that wheel) go through the very
fit the flywheel's do (core.monitor.teeth.tooth_fit.fit_cycle_teeth: harmonics of the cycle period in time, the
in-band tooth pattern as nuisance columns, the out-of-band tooth-spacing error learnt from the residuals) with a
``ToothLearner`` and pattern cache of its own: a wheel with another tooth count, another gap and other tooth errors.

``FreeEndSpeed`` keeps what the balance needs of it: the mean speed, the angle harmonics of the free-end node and
the time of its window's first edge relative to the flywheel's (each fit's harmonics are referred to its own first
edge; ``harmonics_at(t)`` refers them to another origin). The joint fit of both wheels (its half-order speed
equations with the flywheel's): core.monitor.identify.noise_model.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.balance.harmonic_balance import OperatingPoint
from frictionwatch.core.monitor.identify.noise_model import ResidualStats
from frictionwatch.core.monitor.teeth.flywheel import ToothLearner
from frictionwatch.core.monitor.teeth.tooth_fit import ToothPatterns, fit_cycle_teeth
from frictionwatch.core.types import Cycle

FOUR_PI = 4.0 * np.pi


@dataclass(frozen=True)
class SecondWheelState:
    """The second wheel's tooth learner (its positions) and in-band pattern cache, carried cycle to cycle, and the
    residual statistics of its speed equations in the joint fit (core.monitor.identify.noise_model)."""

    teeth: ToothLearner
    patterns: ToothPatterns | None = None
    stats: ResidualStats | None = None


@dataclass(frozen=True)
class FreeEndSpeed:
    """The free-end node's motion over one cycle, from the second wheel.

    omega_mean [rad/s]; harmonics (M,) complex Phi_m [rad] of the angle deviation, order m/2, referred to the time of
    its own first edge; t_first_s [s] that time minus the flywheel window's first edge; residual_rms [rad] of its
    fit (timing noise, tooth errors not yet learnt, orders above the band); n_edges used."""

    omega_mean: float
    harmonics: np.ndarray
    t_first_s: float
    residual_rms: float
    n_edges: int
    drift_harmonics: np.ndarray | None = None  # (M,) complex [rad]: its fit's drift pattern q(u), same reference
    # (M, n_nuisance) complex [rad per rad]: its in-band tooth-error patterns through its fit, same reference. Fixed
    # in angle, they are integer orders; seen in time on a shaft whose speed ripples at half orders they leak into
    # the half orders too (bench/drive_train_model_error.py: up to ~50 % of the free end's small harmonics at orders
    # 7.5-8.5 on genset-v20). The drive train's identification counts that leak as noise of its free-end rows.
    pattern_harmonics: np.ndarray | None = None

    def harmonics_at(self, t_s: float, values: np.ndarray | None = None) -> np.ndarray:
        """The harmonics referred to an origin ``t_s`` [s] after the flywheel window's first edge (0: that edge):
        phi(tau) = sum Re(Phi_m exp(i w_m tau)) with tau from its own first edge (core.monitor.teeth.flywheel) is
        sum Re(Phi_m exp(-i w_m (t_first_s - t_s)) exp(i w_m tau')) with tau' from ``t_s``. ``values``: other
        harmonics of the same reference (the drift pattern's) instead of the angle's."""
        h = self.harmonics if values is None else values
        w = 0.5 * self.omega_mean * np.arange(1, h.shape[0] + 1)
        return h * np.exp(-1j * w * (self.t_first_s - t_s))

    @property
    def speed_harmonics(self) -> np.ndarray:
        """(M,) complex [rad/s] speed harmonics i w_m Phi_m (same reference as ``harmonics``)."""
        return 1j * 0.5 * self.omega_mean * np.arange(1, self.harmonics.shape[0] + 1) * self.harmonics


def fit_second_wheel(cycle: Cycle, state: SecondWheelState | None, n_harmonics: int, n_nuisance: int,
                     settings: tuple) -> tuple[FreeEndSpeed | None, SecondWheelState | None, str | None]:
    """The second wheel's fit of ``cycle`` (None and the state unchanged when the cycle has no second wheel), its
    learner updated, and a flag when its edges could not be fitted ('second_wheel_bad_teeth': the flywheel's cycle
    goes on without it).

    settings : (drift_nuisance, fit_harmonics, fit_drift, learning: LearnerSettings), the
    flywheel fit's own (core.monitor.teeth.tooth_fit.fit_cycle_teeth)."""
    w = cycle.wheel2
    if w is None:
        return None, state, None
    if state is None or state.teeth.correction.shape[0] != w.teeth:  # first sight, or another wheel stated
        state = SecondWheelState(ToothLearner.empty(w.teeth), None, None if state is None else state.stats)
    view = replace(cycle, tooth_ticks=w.ticks, tooth_angle=w.angle, tooth_index=w.index, wheel2=None)
    try:
        fly, teeth, _, patterns = fit_cycle_teeth(view, w.teeth, n_harmonics, n_nuisance, state.teeth,
                                                  state.patterns, *settings)
    except ValueError:
        return None, state, "second_wheel_bad_teeth"
    speed = FreeEndSpeed(omega_mean=fly.omega_mean, harmonics=fly.harmonics.copy(),
                         t_first_s=float(w.ticks[0] - cycle.tooth_ticks[0]) / cycle.tick_hz,
                         residual_rms=fly.residual_rms, n_edges=fly.n_edges,
                         drift_harmonics=fly.pattern_harmonics[:, -1].copy() if settings[0] else None,
                         pattern_harmonics=fly.pattern_harmonics[:, :n_nuisance].copy())
    return speed, SecondWheelState(teeth, patterns, state.stats), None


def free_end_input(spec: EngineSpec, op: OperatingPoint, free: FreeEndSpeed | None
                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """What the harmonic balance needs for the second wheel's equations (core.monitor.balance.harmonic_balance):
    the chain's speed transfer to its node (the engine file's [sensors.second_wheel] node; a one-node chain: that
    node) and its harmonics referred to the flywheel window's first edge; None without a fit or a stated node."""
    if free is None or spec.sensors.second_wheel is None:
        return None
    n_nodes = op.receptance.inverse.shape[1]
    node = spec.sensors.second_wheel.node if n_nodes == len(spec.node_names) else 0
    return op.receptance.speed_transfer(node), free.harmonics_at(0.0)
