"""The pressure statistics' standard error (service.alert_interface.ewma_variance, sibling_reference_variance; design
note 54): the EWMA's variance through its running-mean start, and a three-cylinder engine's figure against the
median change, which is a difference of two cylinders where the third has moved."""

from types import SimpleNamespace

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.checks.ring_pressure import RingIndicators
from frictionwatch.service.alert_baseline import Band
from frictionwatch.service.alert_interface import (
    change_against_siblings,
    ewma_variance,
    leak_statistics,
    sibling_reference_variance,
)
from frictionwatch.service.alerts import AlertConfig, AlertEngine
from numpy.testing import assert_allclose

WINDOW = 50.0  # AlertConfig().window


def _schedule_variances(n: int) -> np.ndarray:
    """ewma_variance over the alerts' schedule g = max(1 / window, 1 / k), k = 1..n."""
    v, out = 0.0, []
    for k in range(1, n + 1):
        v = ewma_variance(v, max(1.0 / WINDOW, 1.0 / k))
        out.append(v)
    return np.array(out)


def test_ewma_variance_through_the_running_mean_start():
    rng = np.random.default_rng(5)
    x = rng.standard_normal((20000, 150))
    e = np.zeros(20000)
    seen = {}
    for k in range(1, 151):
        e += max(1.0 / WINDOW, 1.0 / k) * (x[:, k - 1] - e)
        if k in (10, 50, 150):
            seen[k] = e.var()
    v = _schedule_variances(150)
    for k, var in seen.items():  # 20,000 replicates: the sample variance within ~1 % (1 sigma)
        assert_allclose(var, v[k - 1], rtol=0.04)
    assert_allclose(v[9], 0.1, rtol=1e-12)  # a running mean of 10
    g = 1.0 / 10
    assert g / (2 - g) < 0.55 * v[9]  # the fixed-g formula said half of it there


def _band(sd: np.ndarray, z: int) -> Band:
    cov = np.zeros((z, 4, 4))
    for k in range(z):
        cov[k] = np.diag(sd**2)
    return Band(cycles=200, first_cycle=0, last_cycle=199, imep_pa=9e5, imep_lo_pa=8e5, imep_hi_pa=1e6,
                mean=np.zeros((4, z)), cov=cov)


def test_three_cylinders_beside_a_moved_one_read_a_difference_of_two():
    # maruti's case: cylinder 2 healthier than at its baseline (its leak gone: n_c up, n_e down, far beyond the
    # noise); cylinders 1 and 3 healthy, each EWMA with variance v per unit of the per-cycle spread
    sd = np.array([0.003, 0.003, 0.003, 0.0015])
    rng = np.random.default_rng(11)
    n, v = 4000, 1.0 / 30
    moved = np.array([0.0, 0.01, -0.01, 0.0])
    z_leak = np.empty((n, 2))
    band = _band(sd, 3)
    var = v * sibling_reference_variance(3)
    for i in range(n):
        e = rng.standard_normal((4, 3)) * sd[:, None] * np.sqrt(v)
        e[:, 1] += moved
        z_leak[i] = leak_statistics(change_against_siblings(e), band, var).z_leak[[0, 2]]
    # the median of each exponent's change is one of the two healthy cylinders: each reads the other, with the leak's
    # sign on one of them; scaled as a difference of two the tail is a standard normal's, P(z > 2) = 0.0228 (+-0.0017
    # at 4,000 x 2); scaled as one cylinder's it was P(N(0, 2) > 2) = 0.079
    tail = float(np.mean(z_leak > 2.0))
    assert 0.015 < tail < 0.032
    assert sibling_reference_variance(4) == 1.0 and sibling_reference_variance(2) == 1.0


def test_the_engine_scales_its_figures_by_both():
    # a three-cylinder engine whose indicators sit exactly on the baseline but for a fixed leak on cylinder 1: the
    # z it alerts with is the leak signature over sqrt(2 / n + 2 / 100) after n cycles (a running mean, a difference
    # of two; the band's mean over its 100 cycles, design note 71; within the long-run estimate's warm-up: factor 1)
    spec = load_engine("maruti-3cyl")
    eng = AlertEngine(spec, AlertConfig(baseline_cycles=100, skip_cycles=0))
    rng = np.random.default_rng(3)
    sd = np.array([0.0012, 0.0013, 0.0022, 0.0012])

    def cycle(i: int, x: np.ndarray):
        est = SimpleNamespace(resolved=np.zeros(3, bool), data_gain=np.zeros(3), friction_torque_mean=np.full(3, np.nan),
                              friction_torque_mean_sigma=np.full(3, np.nan), prior_friction_torque_mean=np.full(3, 5.0),
                              total_friction_torque=15.0, weight=10.0, source="data", chi2_reduced=1.0)
        ring = RingIndicators(compression_pa=np.full(3, 30e5), compression_ratio=x[0], n_compression=1.37 + x[1],
                              n_expansion=1.33 + x[2], n_compression_dev=x[1], n_expansion_dev=x[2],
                              expansion_deficit=x[3])
        return SimpleNamespace(index=i, t_start=0.07 * i, flags=(), ring=ring, cycle=est, smoothed=est,
                               imep=np.full(3, 9e5))

    for i in range(100):  # the baseline, learnt from noisy healthy cycles
        eng.update(cycle(i, rng.standard_normal((4, 3)) * sd[:, None]))
    band = eng.baseline.bands[0]
    shift = np.zeros((4, 3))
    shift[1, 0], shift[2, 0] = -0.004, 0.004
    n = 30
    for i in range(100, 100 + n):
        eng.update(cycle(i, band.mean + shift))
    leak = [a for a in eng.active() if a.kind == "blow_by"]
    assert [a.cylinder for a in leak] == [1]
    expected = leak_statistics(change_against_siblings(shift), band, 2.0 / n + 2.0 / 100).z_leak[0]
    assert_allclose(leak[0].evidence["z_leak"], expected, rtol=1e-9)
