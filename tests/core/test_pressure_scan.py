"""checked_pressure's one-pass scan (core/monitor/monitor.py ``pressure_scan``) against its numpy reference, and
checked_pressure's outcome with it against the numpy path it short-cuts: finite traces, non-positive samples, NaN
and +-inf anywhere in a row (the scan's sums of v * 0 must see them: its fastmath flags allow reordering only)."""

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.monitor import (
    CycleRejected,
    checked_pressure,
    nonpositive_flags,
    pressure_scan,
    pressure_scan_reference,
)
from frictionwatch.core.types import Cycle
from numpy.testing import assert_array_equal


def _traces(z, n, rng):
    return rng.uniform(2e4, 8e6, (z, n))


@pytest.mark.parametrize("z", [1, 4, 20])
def test_the_scan_answers_as_its_reference(z):
    rng = np.random.default_rng(z)
    for _ in range(60):
        p = _traces(z, 720, rng)
        for _k in range(int(rng.integers(0, 3))):
            p[rng.integers(0, z), rng.integers(0, 720)] = rng.choice([0.0, -0.0, -1e3, np.nan, np.inf, -np.inf])
        finite, low = pressure_scan(p)
        finite_r, low_r = pressure_scan_reference(p)
        assert finite == finite_r
        if finite:
            assert_array_equal(low, low_r)
    big = _traces(z, 720, rng)
    big[0, :4] = 1.7e308  # finite, though their plain sum overflows
    assert pressure_scan(big)[0]


def _cycle(p, flags=()):
    n = p.shape[1]
    return Cycle(index=0, tick_hz=1e6, tooth_ticks=np.arange(3), tooth_angle=np.zeros(3), tooth_index=np.arange(3),
                 grid=np.arange(n) * (4 * np.pi / n), pressure=p, load_torque=np.nan, load_power=np.nan,
                 flags=tuple(flags))


def _checked_by_numpy(spec, cycle):
    """checked_pressure's numpy path for a finite pressure: no repair, nonpositive_flags added once."""
    p = np.asarray(cycle.pressure, dtype=np.float64)
    flags = list(cycle.flags)
    return p, flags + [f for f in nonpositive_flags(p) if f not in flags]


def test_checked_pressure_flags_and_repairs_as_before():
    spec = load_engine("k9k-4cyl")
    rng = np.random.default_rng(3)
    p = _traces(4, 720, rng)
    p[2, 100:110] = 0.0
    for flags in ((), ("sensor_pressure_nonpositive_cyl3",), ("other",)):
        got, got_flags = checked_pressure(spec, _cycle(p, flags))
        want, want_flags = _checked_by_numpy(spec, _cycle(p, flags))
        assert_array_equal(got, want)
        assert got_flags == want_flags
    q = p.copy()
    q[1, 50] = np.nan  # one invalid sample: repaired, flagged, then the non-positive channel
    got, got_flags = checked_pressure(spec, _cycle(q))
    assert np.isfinite(got).all() and got_flags == ["pressure_repaired_cyl2", "sensor_pressure_nonpositive_cyl3"]
    q[1, 50:60] = np.inf  # a gap of ten: refused
    with pytest.raises(CycleRejected):
        checked_pressure(spec, _cycle(q))
