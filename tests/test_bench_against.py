"""The figures check of bench/bench_monitor_against.py (base and this checkout on the same records): ``plain`` turns
a result into builtins and arrays, ``differences`` finds every number beyond rtol 1e-12 and every other field that
differs, with where it is. Tried on a real cycle's result and on changes made to it, so a check that can no longer
fail shows."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import run

from bench.bench_monitor_against import RTOL, differences, plain


@pytest.fixture(scope="module")
def outcomes():
    spec = load_engine("deutz-1cyl")
    sim = simulate(spec, 3000.0, 1.0, 5, seed=3)
    out = list(run(spec, sim.info, sim.records))
    assert sum(o.ok for o in out) >= 3
    return out


def test_the_same_outcomes_show_no_difference(outcomes):
    diffs, n = differences(plain(outcomes), plain(outcomes))
    assert diffs == []
    assert n > 1000  # every estimate's arrays, nested ones included, are compared


def test_a_figure_beyond_the_tolerance_is_found_where_it_is(outcomes):
    k = max(i for i, o in enumerate(outcomes) if o.ok)
    res = outcomes[k].result
    chi2 = res.cycle.chi2_reduced  # a nested scalar; the residual harmonics a complex array
    assert np.isfinite(chi2) and np.all(np.isfinite(res.residual_harmonics))

    def changed(rel):
        harm = res.residual_harmonics.copy()
        harm[1] *= 1.0 + rel
        est = dataclasses.replace(res.cycle, chi2_reduced=chi2 * (1.0 + rel))
        new = dataclasses.replace(outcomes[k], result=dataclasses.replace(res, cycle=est, residual_harmonics=harm))
        return differences(plain(outcomes), plain([*outcomes[:k], new, *outcomes[k + 1:]]))[0]

    diffs = changed(10 * RTOL)
    assert len(diffs) == 2
    assert diffs[0].startswith(f"[{k}].result.cycle.chi2_reduced:")
    assert diffs[1].startswith(f"[{k}].result.residual_harmonics:")
    assert changed(0.1 * RTOL) == []


def test_flags_nan_and_a_skipped_cycle_are_compared_as_they_are(outcomes):
    k = max(i for i, o in enumerate(outcomes) if o.ok)  # the first has no cycle before: its balance is NaN
    res = outcomes[k].result
    assert np.isfinite(res.friction_balance)
    flagged = dataclasses.replace(outcomes[k], result=dataclasses.replace(res, flags=(*res.flags, "speed_fit_poor")))
    diffs, _ = differences(plain(outcomes[k]), plain(flagged))
    assert len(diffs) == 1 and ".result.flags" in diffs[0]
    nan = dataclasses.replace(outcomes[k], result=dataclasses.replace(res, friction_balance=float("nan")))
    assert differences(plain(nan), plain(nan))[0] == []  # NaN where NaN: the same
    assert differences(plain(outcomes[k]), plain(nan))[0] != []
    skipped = dataclasses.replace(outcomes[k], result=None, skipped="bad_teeth")
    assert differences(plain(outcomes[k]), plain(skipped))[0] != []
    zero = np.zeros(3)
    assert differences([zero], [zero + 1e-300])[0] != []  # atol 0: a zero stays a zero
