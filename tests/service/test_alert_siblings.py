"""The pressure statistics' reference (service.alert_interface.change_against_siblings): a change of one cylinder is
seen on that cylinder only, whichever cylinders the per-cycle sibling median was made of before and after."""

import numpy as np
from frictionwatch.service.alert_interface import change_against_siblings
from numpy.testing import assert_allclose


def _compared(levels: np.ndarray) -> np.ndarray:
    """The core's rows: each cylinder's indicator less the median of all cylinders (ring_pressure._sibling_median)."""
    return levels - np.median(levels, axis=1, keepdims=True)


def test_one_cylinder_back_to_its_siblings_moves_only_itself():
    # four cylinders with their own healthy levels (fuel spread); cylinder 3 leaked when the baseline was learnt
    healthy = np.array([[0.010, -0.004, 0.002, -0.012]] * 4)
    at_baseline = healthy.copy()
    at_baseline[:, 2] += 0.03
    change = _compared(healthy) - _compared(at_baseline)
    # against the median level the siblings moved (the median of four switched to other cylinders) ...
    assert np.max(np.abs(change[:, [0, 1, 3]])) > 0.002
    # ... against the median change they did not, and cylinder 3 carries the whole change
    rel = change_against_siblings(change)
    assert_allclose(rel[:, [0, 1, 3]], 0.0, atol=1e-15)
    assert_allclose(rel[:, 2], -0.03, rtol=1e-12)


def test_three_cylinders_and_a_common_change():
    levels = np.array([[0.004, -0.006, 0.001]] * 4)
    later = levels + 0.002  # a common change (load, temperature): no cylinder changed against its siblings
    later[:, 0] += 0.02  # and cylinder 1 leaks
    rel = change_against_siblings(_compared(later) - _compared(levels))
    assert_allclose(rel[:, 0], 0.02, rtol=1e-12)
    assert_allclose(rel[:, 1:], 0.0, atol=1e-15)


def test_two_cylinders_kept_as_they_are():
    change = np.array([[0.01, -0.01]] * 4)
    assert change_against_siblings(change) is change
