"""A gain common to every pressure sensor as one more explanation of an engine-wide friction excess (issue 27 items
2 and 4, design note 104).

The torque balance books indicated - load - the model's friction as friction. A gain g on every cylinder's pressure
(a shared charge amplifier's or DAQ's scale) reads the indicated torque g times the truth, so the balance reads an
excess of (g - 1) x the true indicated torque: a constant torque the speed cannot place, as an extra friction in any
one cylinder or a friction law's constant part is. The pressure channel compares each cylinder with its siblings
(pressure_channel, the sensor-health stage, commissioning's sibling_gains), where a common gain cancels: nothing in
the log reads it. Sized here from the excess, the indicated torque and the load alone (physics, no tuned constant):

    indicated read  I = load L + the friction the balance measured
    excess          e = the mean balance residual (measured - model friction), sigma s (its scatter and the
                        balance's model-error floor in quadrature: the floor is what a healthy log leaves)
    the model's friction terms of the gas pressure (core.model.terms, P_GAUGE: the rings', the bearings' gas load)
    read the same sensors and so scale with g too: e = (g - 1) (I_true - F_p), F_p that part of the friction, between
    none and all of it (I_true - F_true = L), so g lies between
        g_low  = I / (I - e)       (no friction term reads the pressure), sigma g_low s / (I - e)
        g_high = 1 + e / L         (all of it does),                     sigma s / L
    (k9k 1800/0.6 seed 1 with 1.04 on every sensor: 1.033 +- 0.0024 and 1.039 +- 0.0027; design note 104).
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
    """The range of a common gain that reads the balance's ``excess_nm`` (+- ``excess_sigma_nm``) at a measured load
    torque ``load_nm`` and a measured friction ``friction_nm`` (module doc): gain_low / gain_high with their sigma;
    None where any is not finite or the load or the indicated torque without the excess is not positive (a motored
    log: no indicated work to scale)."""
    vals = (excess_nm, excess_sigma_nm, load_nm, friction_nm)
    if not all(math.isfinite(v) for v in vals):
        return None
    indicated = load_nm + friction_nm
    true = indicated - excess_nm
    if load_nm <= 0.0 or true <= 0.0:
        return None
    low = indicated / true
    return {"gain_low": low, "sigma_low": low * excess_sigma_nm / true, "gain_high": 1.0 + excess_nm / load_nm,
            "sigma_high": excess_sigma_nm / load_nm, "excess_nm": excess_nm, "excess_sigma_nm": excess_sigma_nm,
            "indicated_nm": indicated, "load_nm": load_nm}


def common_gain_of(loc: dict) -> dict | None:
    """``common_gain`` from a held-out localisation (features.localise): the balance residual's mean, its sigma and
    model-error floor in quadrature, the measured load and friction."""
    bal, fr = loc.get("balance") or {}, loc.get("friction") or {}
    sigma = math.hypot(bal.get("sigma_nm", math.nan), bal.get("floor_nm", 0.0) or 0.0)
    return common_gain(bal.get("mean_nm", math.nan), sigma, loc.get("load_nm", math.nan), fr.get("mean_nm", math.nan))


def said(cg: dict) -> str:
    """The common gain in an operator's words: its range with sigma, what it does to the indicated work, that nothing
    in the log reads it and what would tell it from friction."""
    return (f"a gain common to every pressure sensor, g = {cg['gain_low']:.4g} +- {cg['sigma_low']:.2g} to "
            f"{cg['gain_high']:.4g} +- {cg['sigma_high']:.2g} (the balance's excess {cg['excess_nm']:+.3g} +- "
            f"{cg['excess_sigma_nm']:.2g} N m as the indicated torque {cg['indicated_nm']:.3g} N m read high, the "
            "low end with none of the model's friction read from the pressure, the high end with all of it), "
            f"explains it too; {NOT_READ}; {SEPARATION} would tell it from friction")


__all__ = ["NOT_READ", "SEPARATION", "common_gain", "common_gain_of", "engine_wide_friction", "said"]
