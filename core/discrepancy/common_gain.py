"""A gain common to every pressure sensor as one more explanation of an engine-wide friction excess (issue 27 items
2 and 4, design note 104).

The torque balance books indicated - load - the model's friction as friction. A gain g on every cylinder's pressure
(a shared charge amplifier's or DAQ's scale) reads the indicated torque g times the truth, so the balance reads an
excess of (g - 1) x the true indicated torque: a constant torque the speed cannot place, as an extra friction in any
one cylinder or a friction law's constant part is. The pressure channel compares each cylinder with its siblings
(pressure_channel, the sensor-health stage, commissioning's sibling_gains), where a common gain cancels: nothing in
the log reads it. Sized here from the excess and the indicated torque alone (physics, no tuned constant):

    indicated read  I = load + the friction the balance measured
    excess          e = the mean balance residual (measured - model friction), sigma s (its scatter and the
                        balance's model-error floor in quadrature: the floor is what a healthy log leaves)
    g = I / (I - e)     (I - e the indicated torque with the excess taken as the gain's), sigma_g = g s / (I - e)

A mean over several operating points is the same relation (linear in each cycle's indicated torque). Pure numbers
in, a dict out; said, never named (words.py)."""

from __future__ import annotations

import math

from frictionwatch.core.model.effects import EFFECTS

# what tells a common gain from friction, in words (the verdict's): the pressure against the engine's geometry,
# not against the siblings, or a sensor whose gain is known
SEPARATION = ("each cylinder's compression against the engine's geometry (a polytrope from the pegged intake "
              "pressure at IVC: a common gain reads its rise g times too large), or a reference transducer on one "
              "cylinder (its gain stated to `frictionwatch commission`, which compares the others with it)")
# what the log itself reads of it: nothing (module doc; core.monitor.calibration.pressure_gain)
NOT_READ = ("nothing in this log reads it: the pressure channel and `frictionwatch commission` compare each cylinder "
            "with its siblings, where a gain common to all cancels")


def engine_wide_friction(cand) -> bool:
    """Whether candidate ``cand`` (candidates.Candidate) is a friction excess the speed cannot place in a cylinder:
    an extra friction said 'in any one of the cylinders' (its constant or a cam-order stand-in), or a friction law
    (one ``fraction`` of a term sized at the reference point, across_points' test) whose constant part at one point
    is what the balance reads."""
    if cand.effect == "extra_friction":
        return not cand.places_cylinder
    return not cand.toggle and cand.params == ("fraction",) and EFFECTS[cand.effect].sized_at_reference


def common_gain(excess_nm: float, excess_sigma_nm: float, load_nm: float, friction_nm: float) -> dict | None:
    """The common gain that reads the balance's ``excess_nm`` (+- ``excess_sigma_nm``) at a measured load torque
    ``load_nm`` and a measured friction ``friction_nm`` (module doc); None where any is not finite or the indicated
    torque is not positive (a motored log: no indicated work to scale)."""
    vals = (excess_nm, excess_sigma_nm, load_nm, friction_nm)
    if not all(math.isfinite(v) for v in vals):
        return None
    indicated = load_nm + friction_nm
    true = indicated - excess_nm
    if indicated <= 0.0 or true <= 0.0:
        return None
    g = indicated / true
    return {"gain": g, "sigma": g * excess_sigma_nm / true, "excess_nm": excess_nm, "excess_sigma_nm": excess_sigma_nm,
            "indicated_nm": indicated}


def common_gain_of(loc: dict) -> dict | None:
    """``common_gain`` from a held-out localisation (features.localise): the balance residual's mean, its sigma and
    model-error floor in quadrature, the measured load and friction."""
    bal, fr = loc.get("balance") or {}, loc.get("friction") or {}
    sigma = math.hypot(bal.get("sigma_nm", math.nan), bal.get("floor_nm", 0.0) or 0.0)
    return common_gain(bal.get("mean_nm", math.nan), sigma, loc.get("load_nm", math.nan), fr.get("mean_nm", math.nan))


def said(cg: dict) -> str:
    """The common gain in an operator's words: its size with sigma, what it does to the indicated work, that nothing
    in the log reads it and what would tell it from friction."""
    return (f"a gain common to every pressure sensor, g = {cg['gain']:.4g} +- {cg['sigma']:.2g} (the indicated "
            f"torque {cg['indicated_nm']:.3g} N m read {100 * (cg['gain'] - 1):+.2g} % against the truth: the "
            f"balance's excess {cg['excess_nm']:+.3g} +- {cg['excess_sigma_nm']:.2g} N m as the gain's), explains it "
            f"too; {NOT_READ}; {SEPARATION} would tell it from friction")


__all__ = ["NOT_READ", "SEPARATION", "common_gain", "common_gain_of", "engine_wide_friction", "said"]
