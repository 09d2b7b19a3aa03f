"""The pressure-based ring indicators (core/monitor/checks/ring_pressure.py) on constructed polytropic traces: what a gain
error, a pegging offset, a common load change and a leak do to each; and the ramp of a change mid-run
(core.model.effects ramp_cycles, core.plant.simulate.stage_onsets)."""

import numpy as np
import pytest
from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.kinematics import kinematics
from frictionwatch.core.monitor.checks.ring_pressure import ring_indicators, ring_windows
from frictionwatch.core.plant.simulate import MAX_RAMP_STEPS, cylinders_at, stage_onsets
from numpy.testing import assert_allclose

K9K = load_engine("k9k-4cyl")
GRID = np.linspace(0.0, 4 * np.pi, 1440, endpoint=False)


def _traces(spec, n_comp=1.37, n_exp=1.33, scale=1.0, leak=None):
    """Motored-like traces: p = p0 (V_ref / V)^n, compression exponent before TDC, expansion after, each cylinder
    on cylinder 1's grid; ``leak`` = (k, dn): cylinder k compresses with n - dn and expands with n + dn."""
    p = np.empty((spec.n_cyl, GRID.shape[0]))
    for k in range(spec.n_cyl):
        local = np.mod(GRID - spec.firing_angles[k] + 2 * np.pi, 4 * np.pi) - 2 * np.pi
        x, _, _ = kinematics(local, np.asarray(spec.kinematics_params()))
        vol = spec.clearance_volume + spec.piston_area * x
        dn = leak[1] if leak is not None and leak[0] == k else 0.0
        n = np.where(local < 0, n_comp - dn, n_exp + dn)
        p[k] = 1e5 * scale * (vol.max() / vol) ** n
    return p


def test_exponents_read_back_and_siblings_agree():
    ind = ring_indicators(K9K, GRID, _traces(K9K))
    assert_allclose(ind.n_compression, 1.37, atol=2e-4)
    assert_allclose(ind.n_expansion, 1.33, atol=2e-4)
    assert_allclose(np.vstack([ind.compression_ratio, ind.n_compression_dev, ind.n_expansion_dev,
                               ind.expansion_deficit]), 0.0, atol=1e-6)


def test_a_gain_error_moves_only_the_compression_ratio_and_a_common_change_nothing():
    p = _traces(K9K)
    base = ring_indicators(K9K, GRID, p)
    gained = p.copy()
    gained[1] *= 1.03
    ind = ring_indicators(K9K, GRID, gained)
    assert_allclose(ind.compression_ratio[1], np.log(1.03), atol=1e-9)  # not separable from a leak by the ratio
    assert_allclose(ind.n_compression, base.n_compression, atol=1e-9)  # the exponents are gain-invariant
    assert_allclose(ind.n_expansion, base.n_expansion, atol=1e-9)
    assert_allclose(ind.expansion_deficit, base.expansion_deficit, atol=1e-9)
    common = ring_indicators(K9K, GRID, 1.2 * p)  # a load change or a gain drift common to every sensor
    assert_allclose(common.compression_ratio, base.compression_ratio, atol=1e-9)


def test_a_leak_bends_both_polytropes_and_a_pegging_offset_bends_both_down():
    leak = ring_indicators(K9K, GRID, _traces(K9K, leak=(2, 0.01)))
    assert_allclose(leak.n_compression_dev[2], -0.01, atol=5e-4)
    assert_allclose(leak.n_expansion_dev[2], 0.01, atol=5e-4)
    assert leak.expansion_deficit[2] < -0.004 and leak.compression_ratio[2] < -0.01
    assert_allclose(np.delete(leak.n_compression_dev, 2), 0.0, atol=1e-6)
    p = _traces(K9K)
    p[2] += 0.3e5  # a pegging offset: the exponents both fall (the leak moves them apart)
    off = ring_indicators(K9K, GRID, p)
    assert off.n_compression_dev[2] < -0.01 and off.n_expansion_dev[2] < -0.005


@pytest.mark.parametrize("engine", ["k9k-4cyl", "maruti-3cyl", "deutz-1cyl", "genset-v20"])
def test_every_preset_has_windows_before_combustion_and_after_it(engine):
    spec = load_engine(engine)
    w = ring_windows(spec)
    cb = spec.combustion
    assert cb.ivc_deg < w.comp_start < w.comp_end <= cb.start_deg - 10.0
    assert w.exp_start >= 30.0 and w.exp_end <= cb.evo_deg - 10.0
    ind = ring_indicators(spec, GRID, _traces(spec))
    assert_allclose(ind.n_compression, 1.37, atol=5e-4)
    assert ind.compared().shape == (4, spec.n_cyl)


def test_a_ramp_grows_linearly_from_its_onset():
    wear = parse_effect("ring_wear:cylinder=2,gain=1.3,mass_loss=0.04,from_cycle=100,ramp_cycles=50")
    assert [wear.ramp_fraction(c) for c in (99, 100, 124, 149, 400)] == [0.0, 1 / 50, 25 / 50, 1.0, 1.0]
    assert stage_onsets([wear], 1000) == [0, *range(100, 150)]
    long = parse_effect("blow_by:cylinder=1,from_cycle=10,ramp_cycles=1000")
    onsets = stage_onsets([long], 5000)
    assert len(onsets) == MAX_RAMP_STEPS + 1 and onsets[1] == 10 and onsets[-1] < 1010
    coef = np.ones((K9K.n_cyl, 6))
    names = ("ring_viscous", "ring_mixed", "skirt_viscous", "loaded_bearings", "valve_train", "auxiliaries")
    half = cylinders_at(K9K, [wear], coef, names, 124)
    assert_allclose(half.coefficients[1, :3], 1.15)  # half way: gain 1 + 0.3 / 2
    assert_allclose(half.mass_loss, [0.0, 0.02, 0.0, 0.0])
    full = cylinders_at(K9K, [wear], coef, names, 149)
    assert_allclose(full.coefficients[1, :3], 1.3) and assert_allclose(full.mass_loss[1], 0.04)
    assert_allclose(cylinders_at(K9K, [wear], coef, names, 99).coefficients, coef)


def test_the_misfit_statistic_counts_only_the_parameters_the_data_determine():
    """10 rows, 8 parameters, 6 of them held by tight priors (a genset-v20 cycle: 49 rows, 47 parameters): the
    posterior's chi^2 / (rows - P) reads ~4 on a right model; over rows - tr(H) it reads ~1."""
    from frictionwatch.core.monitor.checks.condition import cycle_chi2_reduced
    from frictionwatch.core.monitor.identify.accumulate import Accumulator
    from frictionwatch.core.monitor.identify.posterior import Prior, solve_posterior

    rng = np.random.default_rng(8)
    rows, p = 10, 8
    truth = np.ones(p)
    sigma = np.r_[np.full(2, 1e3), np.full(6, 1e-4)]  # two free parameters, six held at their (true) prior
    new, old = [], []
    for _ in range(400):
        a = rng.standard_normal((rows, p))
        y = a @ truth + rng.standard_normal(rows)
        acc = Accumulator.empty(p, rows)
        acc = acc.fold(acc.cycle_terms(a, y, np.ones(rows), 1), 1.0)
        post = solve_posterior(acc, Prior(np.eye(p), truth, sigma), np.zeros(rows), lower=-np.inf)
        new.append(cycle_chi2_reduced(acc, post))
        old.append(post.chi2_reduced)
    assert_allclose(np.mean(new), 1.0, atol=0.1)  # chi^2 with 8 dof / 8: mean 1, sd of the mean 0.025
    assert np.mean(old) > 3.0  # the same residuals over rows - P = 2
    assert cycle_chi2_reduced(None, post) == post.chi2_reduced
