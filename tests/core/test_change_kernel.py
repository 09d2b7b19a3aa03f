"""The change detector's kernel (core/monitor/checks/change.py: detect_change, cusum_kernel) against its plain numpy
reference (detect_change_reference), cycle by cycle over seeded innovation streams of 1, 2, 4 and 20 cylinders that
go through the warm-up, a step in one cylinder (an alarm), the quiet cycles after it and a non-finite cycle, with
the innovation's floor off and on.

Tolerance: the kernel does the reference's arithmetic element by element (the torques are numpy's own matmul in
both), so the running means, variances and sums are compared to rtol 1e-12 (atol 1e-300); alarms exactly."""

import numpy as np
import pytest
from frictionwatch.core.monitor.checks.change import ChangeSettings, detect_change, detect_change_reference
from numpy.testing import assert_allclose, assert_array_equal


class _Post:
    """What the detector reads of a posterior: its params."""

    def __init__(self, params):
        self.params = params


@pytest.mark.parametrize("rel_floor", [0.0, 0.044])  # the scale its own spread; the floor above it (~10x here)
@pytest.mark.parametrize("z", [1, 2, 4, 20])
def test_kernel_matches_reference(z, rel_floor):
    rng = np.random.default_rng(100 + z)
    settings = ChangeSettings(warmup=40, quiet=15, rel_floor=rel_floor)
    p = z + 3
    rows = rng.uniform(0.5, 2.0, (z, p))
    smoothed = rng.uniform(0.8, 1.2, p + 2)
    kernel = reference = None
    alarms = quiet_seen = 0
    for i in range(260):
        params = smoothed + 0.01 * rng.standard_normal(p + 2)
        if i >= 120:
            params[0] += 0.2 if rel_floor == 0.0 else 2.0  # a step in the first parameter: an alarm after the warm-up
        if i == 90:
            params[1] = np.nan  # a non-finite innovation: the detector unchanged, no alarm
        cyc, smo = _Post(params), _Post(smoothed)
        kernel, a_k = detect_change(kernel, cyc, smo, rows, settings)
        reference, a_r = detect_change_reference(reference, cyc, smo, rows, settings)
        assert_array_equal(a_k, a_r)
        assert (kernel.count, kernel.quiet) == (reference.count, reference.quiet)
        for name in ("mean", "var", "sums"):
            assert_allclose(getattr(kernel, name), getattr(reference, name), rtol=1e-12, atol=1e-300, err_msg=name)
        alarms += int(a_k.any())
        quiet_seen += int(kernel.quiet > 0)
    assert alarms >= 1 and quiet_seen >= settings.quiet  # the stream went through an alarm and its quiet cycles
