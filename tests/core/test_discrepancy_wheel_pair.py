"""The whole wheel's TDC against one cylinder's TDC with a friction beside it (issue 27; design note 106): where the
step's one explanation is the wheel's TDC and the pressure reads no common offset but one cylinder's own off by more
than SEED_MIN_DEG (however few of its sigmas), the pair (that TDC as the pressure reads it, the step's other
explanations refitted beside it) is tried and weighed against the wheel on the held-out cycles (maruti 1500/0.5 s6:
TDC 1.5 deg on cylinder 2 and a worn ring on 3 named the wheel at 1.30 +- 0.028 deg)."""

from __future__ import annotations

import numpy as np
from frictionwatch.core.discrepancy import pair as pair_module
from frictionwatch.core.discrepancy.candidates import candidate_library
from frictionwatch.core.discrepancy.choice import AMBIGUOUS_DCHI2
from frictionwatch.core.discrepancy.fit import Trial
from frictionwatch.core.discrepancy.pair import Pair, wheel_not_read, wheel_or_pair
from frictionwatch.core.discrepancy.residuals import Residuals
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel

MODEL = EngineModel.from_spec(load_engine("maruti-3cyl"))


def _trial(label: str, x: float) -> Trial:
    cand = next(c for c in candidate_library(MODEL) if c.label == label)
    return Trial(cand, np.array([x]), np.array([0.03]), 10.0, 100.0, 1)


def _read(deg, sigma) -> Residuals:
    z = np.zeros(1)
    return Residuals(z, z, z, np.zeros((1, 1), complex), z, np.zeros((1, 2)), np.zeros(2),
                     tdc_deg=np.asarray(deg, float), tdc_sigma_deg=np.asarray(sigma, float))


S6 = _read([-0.139, 1.549, 0.018], [0.823, 0.699, 0.71])  # maruti 1500/0.5 s6 as the pressure read it


def test_the_wheel_is_questioned_only_where_the_pressure_reads_one_cylinder_and_no_wheel():
    wheel, two = _trial("tdc_offset[cyl 0]", 1.3), _trial("tdc_offset[cyl 2]", 1.5)
    assert wheel_not_read(wheel, S6) == 2
    assert wheel_not_read(two, S6) is None  # a cylinder's TDC: nothing to question here
    assert wheel_not_read(wheel, _read([1.4, 1.6, 1.5], [0.5, 0.5, 0.5])) is None  # every cylinder off: the wheel
    assert wheel_not_read(wheel, _read([0.1, 1.2, 0.0], [0.8, 0.7, 0.7])) == 2  # 1.7 sigma: read however small
    assert wheel_not_read(wheel, _read([0.6, -0.9, 0.0], [0.4, 0.7, 0.7])) == 1  # the clearest, not the largest
    assert wheel_not_read(wheel, _read([0.1, 0.15, -0.1], [0.8, 0.7, 0.7])) is None  # none off by SEED_MIN_DEG


def test_the_pair_against_the_wheel_named_said_or_left(monkeypatch):
    wheel = _trial("tdc_offset[cyl 0]", 1.3)
    ring = _trial("ring_wear[cyl 3]", 3.4)
    cost = {"wheel": 1000.0}
    reading = pair_module.PressureFinding("tdc_offset", 2, "deg", 1.55, 0.7, "")
    found = Pair(reading, ring, "pair model", "pair run", None, None, "")
    monkeypatch.setattr(pair_module, "tdc_and_friction", lambda *a, **k: (found, 7, "", None))
    monkeypatch.setattr(pair_module, "chi2_floored", lambda res, scale, floor: cost[res])

    def decide(pair_chi2: float):
        cost["pair run"] = pair_chi2
        return wheel_or_pair((wheel, "wheel model", "wheel"), [(ring, "ring run")], MODEL, S6, None,
                                lambda r: (r, r), None, None, lambda m: 0.0, 1e3, 40.0, lambda r: True)

    assert decide(1000.0 - AMBIGUOUS_DCHI2 - 1.0)[:3] == (found, False, 7)  # clearly better: the pair is added
    assert decide(1000.0 - AMBIGUOUS_DCHI2 + 1.0)[:3] == (found, True, 7)  # as good: an ambiguity, nothing added
    assert decide(1000.0 + AMBIGUOUS_DCHI2 - 1.0)[:3] == (found, True, 7)
    got = decide(1000.0 + AMBIGUOUS_DCHI2 + 1.0)  # worse: the wheel stands, and why is said
    assert got[0] is None and got[1] is False
    assert got[3] == "tdc_offset[cyl 2] with ring_wear[cyl 3]: held-out chi^2 1011 against the whole wheel's 1000"
    for read, significant in ((S6, False), (_read([1.4, 1.6, 1.5], [0.5, 0.5, 0.5]), True)):  # no rival, no question
        assert wheel_or_pair((wheel, "wheel model", "wheel"), [(ring, "ring run")], MODEL, read, None,
                             lambda r: (r, r), None, None, lambda m: 0.0, 1e3, 40.0, lambda r, s=significant: s) == (
            None, False, 0, "")
