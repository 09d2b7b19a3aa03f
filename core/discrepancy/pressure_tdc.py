"""A TDC offset the pressure names, refined by the speed only within the pressure's own noise (design note 43).

The pressure's thermodynamic fit reads a cylinder's TDC from the phase of its own compression and expansion
(pressure_channel.tdc_beyond, sigma ~0.2 deg: mostly the method's systematic error). The speed reads it ten times
finer where the TDC is all that is missing (deutz 3000 rpm: 1.456 +- 0.028 deg for 1.5) but through the indicated
work, so its fit also takes whatever else moves that work or the friction (the same engine with a worn ring as well:
3.37 deg, and the ring's friction with it). So one Gauss-Newton step of the speed on the training cycles starts at
the pressure's reading, and where the two readings agree, within REFINE_SIGMAS of the pressure's sigma, the TDC is
their inverse-variance mean (the speed's sigma carries what its fit leaves coherent: large where another effect
pulls it, k9k 3000 rpm with a worn ring in another cylinder: 1.73 +- 0.18 against the pressure's 1.58 +- 0.21);
otherwise the TDC is held at the pressure's reading with the pressure's sigma, and what the speed asked for beyond
it is left to the speed's own steps.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
from frictionwatch.core.discrepancy.candidates import candidate_library
from frictionwatch.core.discrepancy.fit import Trial, polish
from frictionwatch.core.discrepancy.pressure_channel import PressureFinding
from frictionwatch.core.discrepancy.residuals import Residuals
from frictionwatch.core.model.effects import make_effect
from frictionwatch.core.model.engine_model import EngineModel

# the speed's TDC is taken where it lies within this many of the pressure's sigmas of the pressure's reading (the
# two agree: the 2-sigma rule the matrix judges sigma by, not tuned); beyond, the pressure's reading is held
REFINE_SIGMAS = 2.0


def with_findings(model: EngineModel, findings: list[PressureFinding]) -> EngineModel:
    """``model`` with each finding's effect (its value and sigma) added, in order."""
    for f in findings:
        model = model.with_effect(make_effect(f.effect, {"cylinder": f.cylinder, f.parameter: f.value},
                                              {f.parameter: f.sigma}))
    return model


def refined_by_speed(base: EngineModel, tdcs: list[PressureFinding], full: Callable[[EngineModel], Residuals],
                     train_of: Callable[[Residuals], Residuals], scale: np.ndarray, floor: np.ndarray,
                     held: Sequence[EngineModel] = ()) -> tuple[list[PressureFinding], Residuals, int]:
    """The TDC findings ``tdcs`` on top of ``base``, each refined by one speed step on the training cycles
    (``fit.polish`` from the pressure's reading, the others held) where that step lowers the training cost and stays
    within REFINE_SIGMAS of the reading: then the two readings' inverse-variance mean; returns the findings (refined or as read), the whole-log run of ``base`` with
    all of them, and the monitor runs spent. ``held``: ``base`` with a parameter it holds moved by its sigma (a
    friction fitted beside the TDC: pair.tdc_and_friction), whose shift of the speed's TDC enters the speed's sigma
    (fit.polish's ``held``): a friction in the TDC's own cylinder takes its indicated work too, and the speed's TDC
    with that friction fixed read 1.05 +- 0.11 deg for 0.8 (maruti 1500/0.5 s1, a ring on the same cylinder;
    design note 91)."""
    out = list(tdcs)
    res = full(with_findings(base, out))
    runs = 1
    for i, f in enumerate(tdcs):
        others = with_findings(base, out[:i] + out[i + 1:])
        cand = next((c for c in candidate_library(others) if c.label == f.label), None)
        if cand is None:
            continue
        start = Trial(cand, np.array([f.value]), np.array([f.sigma]), 0.0, 0.0, 0)
        t, _, new_res, spent = polish(start, others, with_findings(others, [f]), res, full, train_of, scale, floor,
                                      [with_findings(h, out[:i] + out[i + 1:]) for h in held])
        runs += spent
        moved = float(t.x[0]) - f.value
        if moved != 0.0 and abs(moved) <= REFINE_SIGMAS * f.sigma and np.isfinite(t.sigma[0]) and t.sigma[0] > 0:
            # two readings of one offset, each with its own sigma: their inverse-variance mean
            w = np.array([f.sigma, t.sigma[0]]) ** -2.0
            value = float(w @ np.array([f.value, t.x[0]]) / w.sum())
            out[i] = replace(f, value=value, sigma=float(w.sum() ** -0.5),
                             reading=f"{f.reading}; the speed reads {t.x[0]:+.3f} +- {t.sigma[0]:.3f} deg, both "
                                     f"{value:+.3f} deg")
            res = full(with_findings(base, out))
            runs += 1
        elif moved != 0.0:
            out[i] = replace(f, reading=f"{f.reading}; held there: the speed asks for {t.x[0]:+.2f} deg, beyond "
                                        f"{REFINE_SIGMAS:g} sigma of it (something else moves the indicated work)")
    return out, res, runs


def moved_by_sigma(model: EngineModel, f: PressureFinding) -> EngineModel:
    """``model`` with the effect the finding ``f`` named (same effect and cylinder) moved by its sigma: what a fit
    after it would read were the pressure's reading off by that much (fit.polish's ``held``)."""
    def moved(e):
        if e.name != f.effect or e.values.get("cylinder") != f.cylinder:
            return e
        return make_effect(e.name, {**e.values, f.parameter: e.values[f.parameter] + f.sigma}, dict(e.sigma))
    return dataclasses.replace(model, effects=tuple(moved(e) for e in model.effects))


__all__ = ["REFINE_SIGMAS", "moved_by_sigma", "refined_by_speed", "with_findings"]
