"""The friction laws across operating points (issue 27, design notes 58, 62, 65): a friction law the speed steps
sized, checked against the torque balance read point by point on a log of several operating points, and -- where the
speed named nothing -- each law of the library fitted to that balance, beside a constant torque (laws.py holds the
fits; this module the workflow's steps with them).
"""

from __future__ import annotations

import numpy as np
from frictionwatch.core.discrepancy.candidates import candidate_library
from frictionwatch.core.discrepancy.choice import channel_worse, chi2, chi2_floored
from frictionwatch.core.discrepancy.discovery import Discovery, Step
from frictionwatch.core.discrepancy.features import balance_residual, feature_floor, gap, localise
from frictionwatch.core.discrepancy.fit import Trial
from frictionwatch.core.discrepancy.laws import (
    CONSTANT,
    constant_fit,
    fit_law,
    law_change,
    point_balance,
    rivals,
    speed_against_balance,
)
from frictionwatch.core.discrepancy.residuals import Residuals
from frictionwatch.core.discrepancy.words import ACROSS_POINTS_SEPARATION
from frictionwatch.core.model.effects import EFFECTS, make_effect
from frictionwatch.core.model.engine_model import EngineModel


def law_against_balance(t: Trial, current: EngineModel, cur_res: Residuals, full, parts) -> tuple[str, int, object]:
    """Why a friction law sized by the speed steps is refused on a log of several operating points: the same law
    fitted to the training cycles' balance point by point (laws.py) reads another share (laws.speed_against_balance);
    '' where it agrees, where the candidate is no friction law of one ``fraction`` or the log has one point. Refused,
    nothing is named by the speed, and the balance across the points is asked next (``laws_across_points``). Returns
    the reason, the monitor runs spent (one: the law at fraction 1 over the log) and the balance's laws.LawFit (None
    where none was made), which ``laws_across_points`` takes instead of a second run of the same law."""
    if not _is_friction_law(t.candidate):
        return "", 0, None
    base = point_balance(parts(cur_res)[0])
    if base is None:
        return "", 0, None
    fit = _balance_fit(t.candidate, current, base, full, parts)
    return ("" if fit is None else speed_against_balance(float(t.x[0]), float(t.sigma[0]), fit)), 1, fit


def sized_by_balance(t: Trial, law_fit, current: EngineModel, test: Residuals, full, parts, scale: np.ndarray,
                      significant) -> tuple | None:
    """Where the speed steps and the balance across the points read one friction law alike (``law_against_balance``
    found no disagreement), the law at the balance's share (laws.LawFit: its share within the law's range, its
    sigma): (model, its run, its held-out part, the step's channel in words), or None when that model makes the
    held-out speed worse (choice.channel_worse) or is not significant there (then the speed's share stands). Why the
    balance's: across operating points it sees the law's mean friction move with speed and load, which is what the
    law is; the speed sees its shape within a cycle, inside the model's own error at the engine orders. Measured
    once the monitor's kinetic term no longer carried the settling speed (design note 69): maruti 4000/0.8 <->
    1500/0.5 seed 7, a side-thrust skirt at 1, the speed 0.683 +- 0.110 (2.9 sigma off), the balance 1.02 +- 0.16;
    k9k 3000/0.9 <-> 1800/0.6 seed 2, a Stribeck ring at 1: the speed 0.20 +- 0.066, the balance 0.907 +- 0.10
    (note 62). One more monitor run. A balance that does not pin the law (its sigma over a quarter of the law's range:
    its 2-sigma interval wider than half of it) sizes nothing: deutz-1cyl 3000/1500 rpm seed 3, a cam-order
    valve-train friction, the balance's share 1 +- 56 (the single cylinder's cam law barely moves the mean
    friction between the points) beside the speed's 0.971 +- 0.17."""
    c = t.candidate
    if not float(law_fit.sigma) <= 0.25 * (float(c.hi[0]) - float(c.lo[0])):
        return None
    balanced = current.with_effect(make_effect(t.candidate.effect, {"fraction": float(law_fit.fraction)},
                                               {"fraction": float(law_fit.sigma)}))
    res = full(balanced)
    test_new = parts(res)[1]
    if channel_worse(test, test_new, scale) or not significant(res):
        return None
    words = (f"torque balance across points (the speed's step read {float(t.x[0]):.3g} +- "
             f"{float(t.sigma[0]):.2g}, within 2 sigma of it)")
    return balanced, res, test_new, words


def _is_friction_law(c) -> bool:
    """A candidate of one ``fraction`` whose effect is sized at the reference operating point: a friction law."""
    return c.params == ("fraction",) and EFFECTS[c.effect].sized_at_reference


def _balance_fit(c, current: EngineModel, base, full, parts):
    """laws.LawFit of friction law ``c`` to the training cycles' balance point by point (``base``, laws.PointBalance
    of the current model): one run of the law at fraction 1 over the log; None where its points differ from base's."""
    with_law = point_balance(parts(full(current.with_effect(make_effect(c.effect, {"fraction": 1.0}))))[0])
    if with_law is None or with_law.mean.shape != base.mean.shape:
        return None
    return fit_law(c.label, base, law_change(base, with_law), c.lo[0], c.hi[0])


def laws_across_points(found: Discovery, current: EngineModel, cur_res: Residuals, test: Residuals, full, parts,
                        scale: np.ndarray, spec, speed_law: tuple | None = None
                        ) -> tuple[EngineModel, Residuals, Residuals, int]:
    """Where nothing was named and the held-out balance residual is beyond its null at a log of several operating
    points: each friction law of the library (a candidate of one ``fraction``, sized at the reference) fitted to the
    training cycles' balance point by point (laws.py), beside a constant torque. The best is added, as a step of the
    torque balance, when no other physical fit (the constant included) is within laws.AMBIGUOUS_CHI2 of it, and its
    run leaves the held-out balance back inside its null without making the speed worse (choice.channel_worse);
    two or more within it are an ambiguity, said with what would part them; the constant best: left to the
    remainder's words. One whole-log run per law and one for the chosen fit. Returns the model, its held-out part,
    its run and the runs spent.
    ``speed_law``: (label, its balance LawFit) of the law the speed steps sized and the balance refused
    (``law_against_balance``, on this same model: that fit is taken, not run again). Where the balance
    then names another law, the two channels name two laws: an ambiguity, said, nothing added -- neither channel's
    model error is known well enough to prefer it (maruti 4000/0.8 <-> 1500/0.5 seed 2, a side-thrust skirt at 1: the
    speed sized the skirt at 0.71 +- 0.12, the balance read the skirt at 1.68 +- 0.19, beyond its range, and a
    Stribeck ring at 0.22 +- 0.025; healthy logs there read +0.13 to +0.41 N m at 1500 rpm against a floor of 0.09;
    design note 65). The same law from both (k9k's Stribeck ring, note 62): the balance's share, as before."""
    base = point_balance(parts(cur_res)[0])
    if base is None or point_balance(test) is None or not balance_residual(test)["significant"]:
        return current, test, cur_res, 0
    laws = [c for c in candidate_library(current) if _is_friction_law(c)]
    speed_label, speed_fit = speed_law if speed_law is not None else (None, None)
    known = {speed_label: speed_fit} if speed_fit is not None else {}
    fits = [(f, c) for c in laws
            if (f := known[c.label] if c.label in known else _balance_fit(c, current, base, full, parts)) is not None]
    runs = len(laws) - len(known)
    const = constant_fit(base)
    found.across_points = [{"label": f.label, "fraction": f.fraction, "sigma": f.sigma, "chi2": f.chi2,
                            "physical": f.physical} for f in [const, *(f for f, _ in fits)]]
    close = rivals([const, *(f for f, _ in fits)])
    if not close or close[0].label == CONSTANT and len(close) == 1:
        return current, test, cur_res, runs
    if len(close) > 1:  # the points cannot tell them apart: said, nothing added
        found.ambiguous = {"candidates": [f.label if f.label != CONSTANT else "a constant torque" for f in close],
                           "separated_by": [ACROSS_POINTS_SEPARATION], "inside_floor": None}
        return current, test, cur_res, runs
    fit, cand = next((f, c) for f, c in fits if f is close[0])
    if speed_label is not None and cand.label != speed_label:  # the speed named one law, the balance another: said
        found.ambiguous = {"candidates": [f"{speed_label} (by the speed)", f"{cand.label} (by the torque balance)"],
                           "separated_by": [ACROSS_POINTS_SEPARATION], "inside_floor": None, "channels": True}
        return current, test, cur_res, runs
    new_model = current.with_effect(make_effect(cand.effect, {"fraction": fit.fraction}, {"fraction": fit.sigma}))
    res = full(new_model)
    runs += 1
    test_new = parts(res)[1]
    why = channel_worse(test, test_new, scale)
    floor = feature_floor(parts(cur_res)[0], scale)
    grow = chi2_floored(test_new, scale, floor) - chi2_floored(test, scale, floor)
    if not why and grow > 0.0:  # worse over all, even with the model's own error in each feature's variance
        why = f"it makes the held-out residual worse with the model-error floor allowed for (chi^2 +{grow:.3g})"
    if not why and balance_residual(test_new)["significant"]:
        why = "the held-out torque balance stays beyond its null with it"
    if why:
        found.refused.append({"candidate": cand.label, "reason": why, "channel": "torque balance across points",
                              "gap_before": gap(test, scale), "gap_after": gap(test_new, scale)})
        return current, test, cur_res, runs
    runner = sorted((f for f in [const, *(f for f, _ in fits)] if f is not fit and f.physical),
                    key=lambda f: f.chi2)
    reading = (f"fraction {fit.fraction:.3g} +- {fit.sigma:.2g} from the torque balance at {base.mean.size} "
               "operating points (" + ", ".join(f"{w * 30.0 / np.pi:.0f} rpm {ld:.0f} N m: {b:+.2f} N m"
                                               for b, w, ld in zip(base.mean, base.omega, base.load)) + ")")
    found.ambiguous = None  # the balance across the points told what the speed's step could not
    found.steps.append(Step(None, new_model.effects[-1], gap(test, scale), gap(test_new, scale), chi2(test, scale),
                            chi2(test_new, scale), runner[0].label if runner else None, localise(test, spec, scale),
                            localise(test_new, spec, scale), (), (reading,), "torque balance across points",
                            floored_fall=-grow))
    found.curves.append((f"+ {cand.label}", test_new.angles, test_new.speed.mean(axis=0)))
    return new_model, test_new, res, runs


__all__ = ["law_against_balance", "laws_across_points", "sized_by_balance"]
