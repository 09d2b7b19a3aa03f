"""The periodic row interpolation (core.monitor.report.cycle_report.interp_rows_periodic) against np.interp."""

import numpy as np
import pytest
from frictionwatch.core.monitor.report.cycle_report import interp_rows_periodic


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_interp_rows_periodic_is_np_interp(seed):
    rng = np.random.default_rng(seed)
    n = 97
    xp = np.concatenate([[0.0], np.cumsum(rng.uniform(0.5, 1.5, n))])
    fp = rng.standard_normal((4, n))
    xq = np.concatenate([rng.uniform(-1, xp[-1] + 1, 300), xp[:5], [xp[-1]]])  # outside, on knots, unsorted
    got = interp_rows_periodic(xq, xp, fp)
    for k in range(4):
        np.testing.assert_array_equal(got[k], np.interp(xq, xp, np.append(fp[k], fp[k, 0])))


def test_interp_rows_periodic_rejects_bad_knots():
    with pytest.raises(ValueError, match="one point more"):
        interp_rows_periodic(np.zeros(3), np.arange(4.0), np.zeros((1, 4)))
    with pytest.raises(ValueError, match="increasing"):
        interp_rows_periodic(np.zeros(3), np.array([0.0, 2.0, 1.0]), np.zeros((1, 2)))
