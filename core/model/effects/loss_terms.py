"""Loss terms outside Rezeka-Henein: the identification columns that effects add to the monitor's model.

Same contract as core.model.terms: a plain-numpy ``reference`` written from the equation and one numba ``kernel``
compiled with ``KERNEL_SIGNATURE``: ``kernel(samples (N_FIELDS, z, n), consts (N_CONSTS,), out (z, n))``.

    auxiliaries_quadratic   F = omega^2                                    engine-wide (fan, pumps, windage)
    extra_friction_c<k>     F = m + a cos(order angle + phase) in cylinder k, 0 elsewhere: the shape of one
                            extra_friction effect, one coefficient (its reference torque T_ref)

The extra-friction shape carries the effect's own numbers (m, a, order, phase, cylinder), so its kernel is compiled per
set of numbers by ``extra_friction_term``; numba compiles such a closure eagerly (with the common signature, ~0.2 s
on a quiet box) and cannot cache it on disk. The compiled kernels are kept per set of numbers in this process
(``_shape_kernel``, a bounded memo): the discrepancy workflow asks for the same shapes again and again (every
candidate's sizing asks twice, and its linearisation's unit directions recur in every fit), which cost it ~28 % of a
healthy k9k run (cProfile, load ~6).
"""

from __future__ import annotations

import functools

import numba
import numpy as np
from frictionwatch.core.model.terms import ANGLE, KERNEL_SIGNATURE, OMEGA, LossTerm, loss_kernel


def auxiliaries_quadratic_reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """F = omega^2: losses growing with the square of speed (cooling fan, windage, pumps at high flow)."""
    return s[OMEGA] ** 2


@loss_kernel
def auxiliaries_quadratic_kernel(s, c, out):
    for k in range(out.shape[0]):
        for i in range(out.shape[1]):
            out[k, i] = s[OMEGA, k, i] * s[OMEGA, k, i]


def auxiliaries_quadratic() -> LossTerm:
    """An engine-wide term proportional to omega^2 (coefficient in N m s^2, prior 0: off until identified)."""
    return LossTerm("auxiliaries_quadratic", "omega^2", "engine", "N m s^2", 0.0,
                    auxiliaries_quadratic_kernel, auxiliaries_quadratic_reference)


def order_shape_reference(s: np.ndarray, mean: float, amp: float, order: float, phase: float) -> np.ndarray:
    """F = mean + amp cos(order angle + phase), angle the cylinder's local crank angle [rad]."""
    return mean + amp * np.cos(order * s[ANGLE] + phase)


# a memo of compiled code keyed by the constants compiled in (the same numbers give the same kernel: no state), as
# numba's own dispatchers keep theirs; bounded, so a long-lived process asking for ever new shapes stays bounded
@functools.lru_cache(maxsize=256)
def _shape_kernel(k: int, mean: float, amp: float, order: float, phase: float):
    """The compiled kernel of ``extra_friction_term``'s shape for 0-based cylinder k (its numbers are constants)."""

    @numba.njit(KERNEL_SIGNATURE)
    def kernel(s, c, out):
        for j in range(out.shape[0]):
            for i in range(out.shape[1]):
                out[j, i] = mean + amp * np.cos(order * s[ANGLE, j, i] + phase) if j == k else 0.0

    return kernel


def extra_friction_term(cylinder: int, mean: float, amp: float, order: float, phase: float) -> LossTerm:
    """The torque shape of an ``extra_friction`` effect in ``cylinder`` (1-based) as one term that is zero in every
    other cylinder (group "engine": one coefficient, the reference torque T_ref [N m]; the simulator uses the
    cylinder's mean friction), prior 0."""
    k = int(cylinder) - 1
    mean, amp, order, phase = float(mean), float(amp), float(order), float(phase)
    kernel = _shape_kernel(k, mean, amp, order, phase)

    def reference(s: np.ndarray, c: np.ndarray) -> np.ndarray:
        """(N_FIELDS, z, n) -> (z, n), cylinder k only; (N_FIELDS, n) is taken as cylinder k itself."""
        shape = order_shape_reference(s, mean, amp, order, phase)
        if s.ndim == 3:
            shape = np.where(np.arange(s.shape[1])[:, None] == k, shape, 0.0)
        return shape

    equation = f"cylinder {k + 1}: {mean:g} + {amp:g} cos({order:g} angle + {phase:g} rad)"
    return LossTerm(f"extra_friction_c{k + 1}", equation, "engine", "N m", 0.0, kernel, reference)


__all__ = ["auxiliaries_quadratic", "auxiliaries_quadratic_kernel", "auxiliaries_quadratic_reference",
           "extra_friction_term", "order_shape_reference"]
