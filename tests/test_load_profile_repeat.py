"""bench.accuracy_v20_long.load_profile ``repeat`` (issue 29's check, design note 159): the +-20 % set-points again
and again to the run's end, each step still 1 % of rated, one pass the same as without it."""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose

from bench.accuracy_v20_long import BASE_LOAD, load_profile

HOURS = 20000 / (1500.0 / 120.0) / 3600.0  # the check's 20,000 genset cycles


def test_repeated_profile_fills_the_run_in_small_steps():
    once = load_profile(HOURS, dwell_s=30.0, ramp_pct_per_min=60.0)
    again = load_profile(HOURS, dwell_s=30.0, ramp_pct_per_min=60.0, repeat=True)
    t, f = np.array(again).T
    assert once[-1][0] < 0.3 * 3600.0 * HOURS  # one pass ends early: the base load after it (design note 102)
    assert t[-1] > 0.9 * 3600.0 * HOURS and t[-1] < 3600.0 * HOURS
    assert_allclose(np.array(again[:len(once)]), np.array(once), rtol=0, atol=1e-12)  # its first pass is the pass
    assert np.all(np.diff(t) > 0)
    steps = np.abs(np.diff(np.concatenate([[BASE_LOAD], f])))
    assert_allclose(steps, 0.01, atol=1e-9)  # every step 1 % of rated, below the monitor's 2 % voiding step
    assert f.min() >= BASE_LOAD - 0.20 - 1e-9 and f.max() <= BASE_LOAD + 0.20 + 1e-9
    # the low and the high set-points are both visited in the last pass too
    last = f[t > 0.75 * 3600.0 * HOURS]
    assert last.min() < BASE_LOAD - 0.15 and last.max() > BASE_LOAD + 0.15
