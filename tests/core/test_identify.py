"""Identification building blocks against plain references: bounded LS vs scipy's lsq_linear, paper 000 Eq. 5 and
Eq. 6 by hand, accumulation with forgetting vs one weighted batch, posterior coverage by Monte Carlo, and the
linearity of the flywheel speed in the coefficients (physics.md §12.2)."""

import numpy as np
import pytest
import scipy.optimize
from frictionwatch.core.model.dynamics import receptance, shaft_model
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.terms import cylinder_samples, rezeka_henein
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from frictionwatch.core.monitor.identify.bounded_solve import bounded_solve, p_omega_fit
from frictionwatch.core.monitor.identify.noise_model import ResidualStats
from frictionwatch.core.monitor.identify.parameters import (
    firing_mask,
    friction_design,
    motored_friction_per_cylinder,
    parameter_layout,
    share_mean_loss,
)
from frictionwatch.core.monitor.identify.posterior import Prior, solve_posterior
from numpy.testing import assert_allclose


def friction_basis(theta, omega, p_gauge, consts):
    """The six Rezeka-Henein terms (L, n) of one cylinder through the term library (core.model.terms)."""
    return rezeka_henein().evaluate(cylinder_samples(theta, omega, p_gauge, consts), consts)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bounded_solve_matches_lsq_linear(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(40, 7)) * np.logspace(-3, 3, 7)  # badly scaled columns on purpose
    y = rng.normal(size=40)
    got = bounded_solve(a.T @ a, a.T @ y)
    want = scipy.optimize.lsq_linear(a, y, bounds=(0, np.inf), tol=1e-14, lsmr_tol="auto").x
    assert np.all(got >= 0)
    assert_allclose(a @ got, a @ want, atol=1e-7 * np.linalg.norm(y))


def test_p_omega_fit_recovers_coefficients_with_the_mean_as_equality():
    # paper 000 Eq. 5 on the Deutz basis at 2600 rpm with a smooth synthetic pressure
    spec = load_engine("deutz-1cyl")
    th = np.linspace(0, 4 * np.pi, 720, endpoint=False)
    loc = (th + 2 * np.pi) % (4 * np.pi) - 2 * np.pi
    p_gauge = 60e5 * np.exp(-0.5 * (loc / 0.35) ** 2) + 2e5 * (1 + np.cos(th))
    omega = 272.0 + 3.0 * np.sin(th)
    f = friction_basis(th, omega, p_gauge, spec.friction_params()).T  # (p, 6)
    a_true = spec.friction.coefficients
    t_f = f @ a_true + np.random.default_rng(5).normal(scale=0.02, size=th.size)
    mean_row = f.mean(axis=0)
    target = float(mean_row @ a_true)
    a = p_omega_fit(f, t_f, mean_row, target)
    assert np.all(a >= 0)
    assert_allclose(mean_row @ a, target, rtol=1e-8)  # the mean is met exactly
    # the instantaneous friction is what is identifiable (F3/F4 are nearly collinear): compare the trace
    assert np.sqrt(np.mean((f @ a - f @ a_true) ** 2)) < 0.01 * np.std(f @ a_true)


def test_share_mean_loss_eq6_with_a_motored_cylinder():
    # paper 000 Eq. 6: T'_iM = 30 + 28 = 58, T'_fM = 9 - 1.5 = 7.5 -> 7.5*30/58, 7.5*28/58, motored 1.5
    t_i = np.array([30.0, 28.0, -2.0])
    share = share_mean_loss(9.0, t_i, motored_friction=1.5, spread=0.1)
    assert_allclose(share.friction_mean, [7.5 * 30 / 58, 7.5 * 28 / 58, 1.5])
    assert share.motored.tolist() == [False, False, True]
    assert_allclose(share.friction_mean.sum(), 9.0)
    assert_allclose(share.sigma[:2], 0.1 * share.friction_mean[:2])
    assert firing_mask(np.array([10.0, 1.0, 9.0])).tolist() == [True, False, True]


def test_motored_friction_chen_flynn():
    # engines.md §4: K9K 1700 rpm, c = 4.56 m/s, pmax 101 bar -> 1.33 bar fired; motored at ~40 bar:
    spec = load_engine("k9k-4cyl")
    t = motored_friction_per_cylinder(spec, 1700.0, 40e5)
    fmep = spec.torque_to_mep(t, cylinders=1) / 1e5
    assert_allclose(fmep, 0.4 + 0.005 * 40 + 0.09 * 4.5617 + 0.0009 * 4.5617**2, rtol=1e-4)


def test_accumulation_with_forgetting_equals_weighted_batch():
    rng = np.random.default_rng(2)
    lam, p, r = 0.9, 4, 6
    acc = Accumulator.empty(p, r)
    batch_a, batch_y, weights = [], [], []
    for _ in range(12):
        a = rng.normal(size=(r, p))
        y = rng.normal(size=r)
        acc = acc.update(a, y, np.ones(r), lam)
        batch_a.append(a)
        batch_y.append(y)
    for c in range(12):
        weights.append(np.full(r, lam ** (11 - c)))
    a_all, y_all, w_all = np.vstack(batch_a), np.concatenate(batch_y), np.concatenate(weights)
    assert_allclose(acc.info, (a_all * w_all[:, None]).T @ a_all, rtol=1e-12)
    assert_allclose(acc.rhs, (a_all * w_all[:, None]).T @ y_all, rtol=1e-12)
    assert_allclose(acc.weight, sum(lam**k for k in range(12)))


def test_posterior_sigma_is_honest_by_monte_carlo():
    """A linear Gaussian model with a repeated (systematic) error: the stated 2-sigma covers ~95 %."""
    rng = np.random.default_rng(11)
    p, r, cycles = 3, 10, 30
    a_fixed = rng.normal(size=(r, p))
    theta_true = np.array([1.2, 0.8, 1.0])
    sys_sd = 0.3
    inside = inside_stat = 0
    trials = 300
    for _ in range(trials):
        acc = Accumulator.empty(p, r)
        e_sys = rng.normal(scale=sys_sd, size=r)
        for _ in range(cycles):
            a = a_fixed + 0.1 * rng.normal(size=(r, p))
            y = a @ theta_true + e_sys + rng.normal(size=r)
            acc = acc.update(a, y, np.ones(r), 1.0)
        post = solve_posterior(acc, Prior(np.eye(p), np.ones(p), np.full(p, 100.0)), np.full(r, sys_sd**2))
        sd = np.sqrt(np.diag(post.covariance))
        inside += np.all(np.abs(post.params - theta_true) <= 2 * sd)
        inside_stat += np.all(np.abs(post.params - theta_true) <= 2 * np.sqrt(np.diag(post.cov_statistical)))
    # each of 3 parameters covered with ~95 %; all three together about 0.95^3 = 86 % (correlated: a bit more)
    assert 0.80 <= inside / trials <= 0.99
    # without the systematic term the statistical sigma alone would be badly optimistic
    assert inside_stat / trials < 0.6


def test_residual_stats_track_mean_and_variance():
    rng = np.random.default_rng(4)
    st = ResidualStats.empty(3)
    mean = np.array([1 + 1j, 0, -2j])
    for _ in range(3000):
        st = st.update(mean + rng.normal(size=3) + 1j * rng.normal(size=3), 0.5 + rng.normal(), 1 - 1 / 500)
    assert_allclose(st.mean, mean, atol=0.15)
    assert_allclose(st.var, 1.0, rtol=0.2)
    assert_allclose(st.balance_var, 1.0, rtol=0.2)


@pytest.mark.parametrize("scheme", ["pressure_group", "all", "piston_group", "scale"])
def test_flywheel_speed_is_affine_in_the_coefficients(scheme):
    """physics.md §12.2: with the basis frozen, the speed response to friction is linear; the design matrix built
    from parameter groups reproduces the receptance response of the coefficient map exactly."""
    spec = load_engine("k9k-4cyl")
    layout = parameter_layout(spec, scheme)
    omega = 178.0
    shaft = shaft_model(spec, 166.0, omega)
    m = 20
    rec = receptance(shaft, omega, m)
    rng = np.random.default_rng(9)
    basis_harm = rng.normal(size=(spec.n_cyl, 6, m)) + 1j * rng.normal(size=(spec.n_cyl, 6, m))
    theta = rng.uniform(0.5, 1.5, layout.n_params)
    coef = layout.coefficients(theta)
    torque = np.zeros((spec.n_nodes, m), complex)
    np.add.at(torque, spec.cylinder_node, -np.einsum("kl,klm->km", coef, basis_harm))
    h = rec.speed_transfer(shaft.flywheel)
    want = np.einsum("mq,qm->m", h, torque)
    got = friction_design(layout, h, basis_harm, spec.cylinder_node) @ theta
    assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    assert layout.coefficients(np.ones(layout.n_params)).shape == (spec.n_cyl, 6)
    assert_allclose(layout.coefficients(np.ones(layout.n_params)), np.broadcast_to(spec.friction.coefficients, (4, 6)))


def test_parameter_layout_rejects_bad_input():
    spec = load_engine("k9k-4cyl")
    with pytest.raises(ValueError, match="unknown parameter scheme"):
        parameter_layout(spec, "nonsense")
    with pytest.raises(ValueError, match=">= 0"):
        parameter_layout(spec, prior=-np.ones(6))
    assert parameter_layout(load_engine("deutz-1cyl")).n_params == 6
    assert parameter_layout(spec).n_params == 4 + 3


@pytest.mark.parametrize("active", [False, True])
def test_bounded_solve_with_free_nuisances_matches_lsq_linear(active):
    """Nuisances last and free (lower = -inf), coefficients >= 0: the unconstrained fast branch (no bound active)
    and the NNLS branch (two coefficients the data want negative) against scipy's lsq_linear."""
    rng = np.random.default_rng(21)
    n_coef, n_free = 9, 6
    a = rng.normal(size=(60, n_coef + n_free)) * np.logspace(-2, 2, n_coef + n_free)
    truth = np.concatenate([1.0 + rng.random(n_coef), rng.normal(size=n_free)])
    if active:
        truth[[2, 5]] = -1.0
    y = a @ truth + 0.01 * rng.normal(size=60)
    lower = np.concatenate([np.zeros(n_coef), np.full(n_free, -np.inf)])
    got = bounded_solve(a.T @ a, a.T @ y, lower)
    want = scipy.optimize.lsq_linear(a, y, bounds=(lower, np.inf), tol=1e-14, lsmr_tol="auto").x
    assert np.all(got[:n_coef] >= 0)
    assert (np.count_nonzero(got[:n_coef] == 0.0) >= 2) == active
    assert_allclose(a @ got, a @ want, atol=1e-7 * np.linalg.norm(y))
