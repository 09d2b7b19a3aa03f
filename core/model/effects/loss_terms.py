"""Loss terms outside Rezeka-Henein: the identification columns that effects add to the monitor's model.

Same contract as core.model.terms: a plain-numpy ``reference`` written from the equation and one numba ``kernel``
with the signature ``kernel(samples (N_FIELDS, n), consts (N_CONSTS,), out (n,))``.

    auxiliaries_quadratic   F = omega^2                                    engine-wide (fan, pumps, windage)
    extra_friction_c<k>     F = m + a cos(order angle + phase)             the shape of one extra_friction effect

The extra-friction shape carries the effect's own numbers (m, a, order, phase), so its kernel is made per effect
instance by ``extra_friction_term``; numba compiles such a closure once per instance and cannot cache it on disk.
"""

from __future__ import annotations

import numba
import numpy as np

from frictionwatch.core.model.terms import ANGLE, OMEGA, LossTerm


def auxiliaries_quadratic_reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """F = omega^2: losses growing with the square of speed (cooling fan, windage, pumps at high flow)."""
    return s[OMEGA] ** 2


@numba.njit(cache=True)
def auxiliaries_quadratic_kernel(s, c, out):
    for i in range(out.shape[0]):
        out[i] = s[OMEGA, i] * s[OMEGA, i]


def auxiliaries_quadratic() -> LossTerm:
    """An engine-wide term proportional to omega^2 (coefficient in N m s^2, prior 0: off until identified)."""
    return LossTerm("auxiliaries_quadratic", "omega^2", "engine", "N m s^2", 0.0,
                    auxiliaries_quadratic_kernel, auxiliaries_quadratic_reference)


def order_shape_reference(s: np.ndarray, mean: float, amp: float, order: float, phase: float) -> np.ndarray:
    """F = mean + amp cos(order angle + phase), angle the cylinder's local crank angle [rad]."""
    return mean + amp * np.cos(order * s[ANGLE] + phase)


def extra_friction_term(cylinder: int, mean: float, amp: float, order: float, phase: float) -> LossTerm:
    """The torque shape of an ``extra_friction`` effect in ``cylinder`` as a per-cylinder term: its coefficient
    [N m] is the reference torque T_ref (the simulator uses the cylinder's mean friction), prior 0."""
    mean, amp, order, phase = float(mean), float(amp), float(order), float(phase)

    @numba.njit
    def kernel(s, c, out):
        for i in range(out.shape[0]):
            out[i] = mean + amp * np.cos(order * s[ANGLE, i] + phase)

    def reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
        return order_shape_reference(s, mean, amp, order, phase)

    equation = f"{mean:g} + {amp:g} cos({order:g} angle + {phase:g} rad)"
    return LossTerm(f"extra_friction_c{cylinder}", equation, "cylinder", "N m", 0.0, kernel, reference)


__all__ = ["auxiliaries_quadratic", "auxiliaries_quadratic_kernel", "auxiliaries_quadratic_reference",
           "extra_friction_term", "order_shape_reference"]
