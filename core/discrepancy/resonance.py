"""Two fits that read one resonance: the shaft line's stiffness and the flywheel's inertia (design note 109).

With one wheel, near the line's lowest mode (the flywheel and the load swinging against each other: k9k at 1800 rpm
puts order 2 at 60 Hz on a 62 Hz mode) the speed measures that mode's frequency, omega^2 ~ k / J, far more sharply
than it measures which of k and J moved: a flywheel 5 % heavier than the record was named a chain 2 % softer at
damping 1.1 (design note 106, k9k 1800/0.6 seed 8; seed 2, a tuning log: 0.979 +- 0.010, the inertia's own fit
1.025 +- 0.0097, held-out chi^2 16.4 against 33.8, the chain's damping fitting the line's own error there). Where
both fits are significant and put the lowest mode at the same frequency within their sigmas, the log has told the
frequency and not its cause: the workflow says the two as an ambiguity, with what would separate them. Where the
data do separate them, the loser's fit is pulled away from the winner's frequency by what else the log shows (the
swing at every firing order goes as 1 / J above the mode, not with k), and nothing is said here.

Both fits must also explain the held-out cycles as a right model would (``explains``): a fit far from the log has a
sigma wide enough to put any frequency within it. No number is tuned: 2 sigma is the coverage rule in force
(choice.unresolved), applied to the frequency and to the held-out chi^2's own distribution; the mode is the undamped
line's (core.model.chain.lowest_mode_hz, the load free), each fit's sigma propagated by one step of its sigma.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from frictionwatch.core.discrepancy.fit import Trial
from frictionwatch.core.discrepancy.residuals import Residuals
from frictionwatch.core.model.chain import lowest_mode_hz
from frictionwatch.core.model.effects.base import ViewSetup
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.engine_model import EngineModel

SIGMAS = 2.0  # one frequency within this many of the pair's combined sigma (the coverage rule, not tuned)


def _spec_with(model: EngineModel, t: Trial, x: np.ndarray) -> EngineSpec:
    """The model's record as its effects and the trial's effect at ``x`` make it (each effect's own monitor view,
    ``apply_view``: a chain or a flywheel the model already holds is in it)."""
    setup = ViewSetup.nominal(model.spec, model.terms, model.coefficients)
    for e in (*model.effects, t.candidate.effect_at(x)):
        setup = e.apply_view(setup)
    return setup.spec


def mode_of(model: EngineModel, t: Trial) -> tuple[float, float]:
    """(f, sigma_f) [Hz]: the lowest mode with the trial's fit in the model, and its sigma (each parameter moved by
    its sigma, the shifts added in quadrature); (NaN, NaN) for a toggle or a line without a mode; sigma 0 for an
    effect that does not move it."""
    if t.candidate.toggle:
        return float("nan"), float("nan")
    x = np.asarray(t.x, dtype=np.float64)
    f = lowest_mode_hz(_spec_with(model, t, x))
    shifts = []
    for i, s in enumerate(np.asarray(t.sigma, dtype=np.float64)):
        xi = x.copy()
        xi[i] = float(t.candidate.clip(xi + np.eye(x.size)[i] * s)[i])
        shifts.append(lowest_mode_hz(_spec_with(model, t, xi)) - f)
    return f, float(np.sqrt(np.sum(np.square(shifts))))


def moves_the_mode(model: EngineModel, t: Trial) -> bool:
    """Whether the trial's effect moves the line's lowest mode at all (the chain's stiffness and the flywheel's
    inertia do; a friction, a sensor error, a load ripple do not)."""
    if t.candidate.toggle or not model.spec.stiffness.size:
        return False
    f0 = lowest_mode_hz(_spec_with(model, t, np.asarray(t.candidate.x0, dtype=np.float64)))
    return bool(abs(lowest_mode_hz(_spec_with(model, t, np.asarray(t.x, dtype=np.float64))) - f0) > 1e-9 * f0)


def explains(chi2_floored: float, n_features: int) -> bool:
    """Whether a fit's held-out coherent chi^2 with the model-error floor allowed for (choice.chi2_floored, ~ chi^2
    of ``n_features`` degrees of freedom where the model explains the log within its noise and its own error) lies
    within SIGMAS of that distribution's sigma, sqrt(2 F), above its mean F: what the data cannot tell from a right
    model. A fit far beyond it leaves what the log shows unexplained (maruti 1500/0.5 seed 1, the chain 20 % softer:
    the chain 67.6, the flywheel's best 28,334 at F = 49), and its sigma, wide with that rest, says nothing of a
    frequency."""
    return chi2_floored <= n_features + SIGMAS * np.sqrt(2.0 * n_features)


def one_resonance(model: EngineModel, best: tuple[Trial, float], others: list[tuple[Trial, float]],
                  n_features: int) -> Trial | None:
    """The first of ``others`` (significant runners-up, best first, each (trial, held-out floored chi^2)) that is
    another effect than ``best``'s, moves the line's lowest mode as it does, puts it at its frequency within SIGMAS
    of the two sigmas combined, and where both explain the held-out cycles within the noise and the model's own error
    (``explains``): the second reading of one resonance (module doc); None when there is none."""
    best, chi_best = best
    if not (moves_the_mode(model, best) and explains(chi_best, n_features)):
        return None
    fa, sa = mode_of(model, best)
    for o, chi_o in others:
        if (o.candidate.effect == best.candidate.effect or not explains(chi_o, n_features)
                or not moves_the_mode(model, o)):
            continue
        fb, sb = mode_of(model, o)
        if abs(fa - fb) <= SIGMAS * float(np.hypot(sa, sb)):
            return o
    return None


def one_resonance_in(model: EngineModel, confirmed: list[tuple], significant: Callable[[Residuals], bool],
                     held_chi2: Callable[[Residuals], float], n_features: int) -> Trial | None:
    """``one_resonance`` over the workflow's confirmed fits (each (gap, trial, model, run), best first): the
    significant ones with their held-out floored chi^2 (``held_chi2`` of the run); None when fewer than one."""
    fits = [(c[1], held_chi2(c[3])) for c in confirmed if significant(c[3])]
    return one_resonance(model, fits[0], fits[1:], n_features) if fits else None


def said_as_one(best: Trial, twin: Trial) -> tuple[list[str], list[str]]:
    """The ambiguity's two names and what separates each (the workflow's ambiguous outcome)."""
    return [t.candidate.label for t in (best, twin)], [t.candidate.separated_by for t in (best, twin)]


__all__ = ["SIGMAS", "explains", "lowest_mode_hz", "mode_of", "moves_the_mode", "one_resonance", "one_resonance_in",
           "said_as_one"]
