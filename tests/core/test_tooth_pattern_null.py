"""The in-band tooth pattern's remaining uncertainty in the discrepancy workflow's null (design note 118): the spread
the nuisances' posterior puts into each residual speed harmonic (core.monitor.teeth.pattern_spread), carried per
cycle by the discrepancy's runs (MonitorConfig.nuisance_spread, Residuals.pattern_sigma) and added to each engine
order's sigma (core.discrepancy.features.order_table)."""

from __future__ import annotations

import dataclasses

import numpy as np
from frictionwatch.core.discrepancy.features import RPM_PER_RAD_S, SIGNIFICANT, order_table
from frictionwatch.core.discrepancy.residuals import ANGLE_POINTS, Residuals, pinned_config, run_model
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.view import reference
from frictionwatch.core.monitor.teeth.pattern_spread import pattern_spread
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles
from numpy.testing import assert_allclose


def test_the_spread_is_that_of_the_residual_an_estimate_drawn_from_the_posterior_leaves():
    """E ~ N(0, C) real, r = -D E complex: per order Var(Re r) + Var(Im r) over 40,000 draws against D C D^H (the
    draws' own sampling error at this size is ~1 %)."""
    rng = np.random.default_rng(4)
    m, n = 7, 6
    d = rng.standard_normal((m, n)) + 1j * rng.standard_normal((m, n))
    a = rng.standard_normal((n, n))
    cov = a @ a.T / n + 0.1 * np.eye(n)
    e = rng.multivariate_normal(np.zeros(n), cov, size=40_000)
    r = -(e @ d.T)
    assert_allclose(pattern_spread(d, cov), np.sqrt(r.real.var(axis=0) + r.imag.var(axis=0)), rtol=0.03)
    assert pattern_spread(d[:, :0], cov[:0, :0]).tolist() == [0.0] * m  # no nuisances: nothing


def _coherent_order(n: int, m: int, order_index: int, amplitude: float, noise: float, seed: int) -> Residuals:
    rng = np.random.default_rng(seed)
    harm = noise * (rng.standard_normal((n, m)) + 1j * rng.standard_normal((n, m))) / np.sqrt(2.0)
    harm[:, order_index] += amplitude * np.exp(0.7j)
    return Residuals(index=np.arange(n), omega=np.full(n, 150.0), load=np.full(n, 900.0), harmonics=harm,
                     balance=np.zeros(n), speed=np.zeros((n, ANGLE_POINTS)),
                     angles=np.linspace(0.0, 4.0 * np.pi, ANGLE_POINTS, endpoint=False))


def test_an_order_an_unconverged_tooth_pattern_can_explain_is_not_significant():
    """Order 11 of a 60-cycle residual at ~6.6 noise sigmas (note 117's healthy genset-v20 figure): significant with
    no tooth-pattern uncertainty, and with a converged one (a spread of a tenth of its amplitude); not significant
    where the nuisances' posterior still spreads the residual there by half its amplitude, whose sigma the table
    adds in quadrature (and never to another order)."""
    n, m, k = 60, 24, 21  # engine order 11 is harmonic 22
    amplitude, noise = 2.2e-3, 2.6e-3  # rad/s: noise / sqrt(60) per cycle mean, ~6.6 sigmas
    res = _coherent_order(n, m, k, amplitude, noise, seed=3)
    bare = order_table(res)
    assert [o["order"] for o in bare if o["significant"]] == [11.0]
    assert bare[k]["pattern_sigma_rpm"] == 0.0
    assert_allclose(bare[k]["sigma_rpm"], bare[k]["noise_sigma_rpm"], rtol=1e-12)
    z_noise = bare[k]["amplitude_rpm"] / bare[k]["noise_sigma_rpm"]
    assert 5.0 < z_noise < 9.0

    def with_spread(share: float, k_spread: int) -> list[dict]:
        spread = np.zeros((n, m))
        # the spread shrinks along the log as the estimate converges: its mean over the cycles is ``share`` x amp
        spread[:, k_spread] = share * amplitude * np.linspace(1.5, 0.5, n)
        return order_table(dataclasses.replace(res, pattern_sigma=spread))

    unconverged = with_spread(0.5, k)
    o = unconverged[k]
    assert_allclose(o["pattern_sigma_rpm"], 0.5 * amplitude * RPM_PER_RAD_S, rtol=1e-12)
    assert_allclose(o["sigma_rpm"], np.hypot(o["noise_sigma_rpm"], o["pattern_sigma_rpm"]), rtol=1e-12)
    assert o["amplitude_rpm"] < SIGNIFICANT * o["sigma_rpm"]
    assert [x["order"] for x in unconverged if x["significant"]] == []
    assert [x["order"] for x in with_spread(0.1, k) if x["significant"]] == [11.0]
    assert [x["order"] for x in with_spread(0.5, k - 2) if x["significant"]] == [11.0]  # order 10's spread: not 11's


def test_the_discrepancys_runs_carry_the_spread_and_it_shrinks_as_the_pattern_is_learnt():
    """A short deutz-1cyl log through run_model with the pinned config: every cycle carries the nuisances' spread of
    each residual harmonic, non-zero at the integer orders the nuisances cover; it shrinks as their equations
    accumulate (the last four cycles' mean below 0.8 of the first four accumulated ones'); the product's default
    config (serving) carries none."""
    spec = load_engine("deutz-1cyl")
    sim = simulate(spec, 2000.0, 0.8, 18, 5)
    cycles = assembled_cycles(spec, sim.info, sim.records)[0]
    model = EngineModel.from_spec(spec)
    res = run_model(model, reference(cycles), pinned_config(), cycles)
    assert res.pattern_sigma is not None and res.pattern_sigma.shape == res.harmonics.shape
    integer = res.pattern_sigma[:, 1::2]  # harmonics 2, 4, ...: engine orders 1, 2, ...
    assert np.all(np.isfinite(res.pattern_sigma)) and np.all(integer[:, :4] > 0.0)
    early, late = integer[2:6].mean(axis=0), integer[-4:].mean(axis=0)
    assert np.all(late[:4] < 0.8 * early[:4])
    served = run_model(model, reference(cycles), dataclasses.replace(pinned_config(), nuisance_spread=False),
                       cycles[:4])
    assert served.pattern_sigma is None


def test_a_residual_within_the_tooth_patterns_uncertainty_is_said_not_named():
    """The order table of the test above (order 11 beyond its noise's sigmas and above the floor, inside the pattern's
    sigma) as a discover's final localisation: the outcome is 'nothing' and the verdict says the order lies within
    what the wheel's tooth pattern, still being learnt, can put there; without the pattern's sigma the same order is
    significant and unexplained."""
    from frictionwatch.core.discrepancy.discovery import Discovery

    model = EngineModel.from_spec(load_engine("genset-v20"))
    n, m, k = 60, 24, 21
    amplitude = 2.2e-3
    res = dataclasses.replace(_coherent_order(n, m, k, amplitude, 2.6e-3, seed=3),
                              measured=np.full((n, m), 0.01 * amplitude))  # a floor below the order's amplitude
    spread = np.zeros((n, m))
    spread[:, k] = 0.5 * amplitude

    def found(pattern_sigma) -> Discovery:
        orders = order_table(dataclasses.replace(res, pattern_sigma=pattern_sigma))
        final = {"significant_orders": [o["order"] for o in orders if o["significant"]], "orders": orders,
                 "balance": {"significant": False, "mean_nm": 0.0}, "angle": {"peak_deg": 0.0},
                 "cylinders": [{"cylinder": 1, "relative": 1.0}], "half_order_share": 0.0, "channels": {}}
        return Discovery(model, model, [], 0.7, 0.7, {"operating_points": 1}, final)

    learning = found(spread)
    assert learning.outcome == "nothing" and learning.within_pattern == [11.0]
    assert "at engine orders 11 a coherent residual lies within what the wheel's tooth pattern" in learning.verdict()
    bare = found(None)
    assert bare.outcome == "unexplained" and bare.within_pattern == []
    assert "engine orders 11" in bare.verdict() and "tooth pattern" not in bare.verdict()
