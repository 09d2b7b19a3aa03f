"""Harmonic balance, rigid balance and the flywheel fit against independent time-domain references.

Expected numbers come from physics.md: §3 (variable inertia), §4 (rigid round trip: Newton form within a few % of the
friction ripple, constant J off by more than the ripple itself), §12.1 (harmonic balance = periodic steady state of
the linear chain), §12.4 (mean dissipation = <omega^T C_rel omega>).
"""

from dataclasses import replace

import numpy as np
import pytest
import scipy.linalg
from frictionwatch.core.model.dynamics import (
    dissipated_power,
    first_flexible_mode_hz,
    mean_reciprocating_inertia,
    natural_frequencies,
    node_speed_harmonics,
    receptance,
    rigid_friction_torque,
    shaft_model,
)
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.kinematics import kinematics, variable_inertia
from frictionwatch.core.model.terms import cylinder_samples, rezeka_henein
from frictionwatch.core.model.torques import gas_torque
from frictionwatch.core.monitor.teeth.flywheel import fit_flywheel, harmonic_series, harmonics_of
from numpy.testing import assert_allclose


def friction_basis(theta, omega, p_gauge, consts):
    """The six Rezeka-Henein terms (L, n) of one cylinder through the term library (core.model.terms)."""
    return rezeka_henein().evaluate(cylinder_samples(theta, omega, p_gauge, consts), consts)


def periodic_time_response(shaft, omega_mean, torque_fn, n=4096):
    """Periodic steady state of M phi'' + C phi' + K phi = T(t) by exact (matrix-exponential) stepping with the
    input held at each step's midpoint, then a periodicity solve: an independent time-domain route."""
    nn = shaft.n_nodes
    m_inv = np.diag(1.0 / shaft.mass)
    a = np.block([[np.zeros((nn, nn)), np.eye(nn)], [-m_inv @ shaft.stiffness, -m_inv @ shaft.damping]])
    b = np.vstack([np.zeros((nn, nn)), m_inv])
    period = 4 * np.pi / omega_mean
    h = period / n
    big = scipy.linalg.expm(np.block([[a, b], [np.zeros((nn, 3 * nn))]]) * h)
    ad, bd = big[: 2 * nn, : 2 * nn], big[: 2 * nn, 2 * nn :]
    u = torque_fn((np.arange(n) + 0.5) * h)  # (N, n)
    s = np.zeros(2 * nn)
    for k in range(n):
        s = ad @ s + bd @ u[:, k]
    # a viscous damper ring (K_D = 0) leaves its angle offset free: least squares picks one periodic solution
    x0 = np.linalg.lstsq(np.eye(2 * nn) - np.linalg.matrix_power(ad, n), s, rcond=1e-12)[0]
    xs = np.empty((2 * nn, n))
    x = x0
    for k in range(n):
        xs[:, k] = x
        x = ad @ x + bd @ u[:, k]
    return xs[nn:], period  # node speeds (N, n) at t_k = k h


def _with_ground_spring(shaft, k_ground):
    stiff = shaft.stiffness.copy()
    stiff[-1, -1] += k_ground
    return replace(shaft, stiffness=stiff)


@pytest.mark.parametrize("name", ["k9k-4cyl", "genset-v20"])
def test_harmonic_balance_equals_time_domain_steady_state(name):
    spec = load_engine(name)
    omega = spec.rated_speed_rpm * np.pi / 30 * (0.45 if name == "k9k-4cyl" else 1.0)
    shaft = shaft_model(spec, spec.rated_torque_nm * 0.7, omega)
    if spec.load.kind != "grid":  # a free-free chain has no periodic angle solution; pin it softly to ground
        shaft = _with_ground_spring(shaft, 50.0)
    m = 24
    rec = receptance(shaft, omega, m)
    rng = np.random.default_rng(7)
    amp = np.zeros((shaft.n_nodes, m), complex)
    for q in spec.cylinder_node[:4]:
        amp[q] = (rng.normal(size=m) + 1j * rng.normal(size=m)) * 100.0 / np.arange(1, m + 1)
    w = rec.freq

    def torque(t):
        return np.real(amp[:, :, None] * np.exp(1j * w[None, :, None] * t[None, None, :])).sum(axis=1)

    speed_t, _ = periodic_time_response(shaft, omega, torque)
    got = node_speed_harmonics(rec, amp)
    want = harmonics_of(speed_t, m)
    # midpoint-held input: O((w h)^2) phase-free error; 4096 steps per cycle => < 1e-3 of the largest harmonic
    assert_allclose(got, want, atol=1e-3 * np.abs(want).max())
    # flywheel transfer is the flywheel row of the same solve
    assert_allclose(np.einsum("mq,qm->m", rec.speed_transfer(shaft.flywheel), amp), got[shaft.flywheel], rtol=1e-12)
    # physics.md §12.4: mean dissipated power = <sum c_rel (d omega)^2> + <sum c_gnd omega^2>
    rel, gnd = dissipated_power(shaft, got)
    d = speed_t[shaft.edges[:, 0]] - speed_t[shaft.edges[:, 1]]
    want_rel = np.mean(np.sum(shaft.edge_damping[:, None] * d**2, axis=0))
    want_gnd = np.mean(np.sum(shaft.ground_damping[:, None] * (speed_t - speed_t.mean(axis=1, keepdims=True)) ** 2,
                              axis=0))
    assert_allclose(rel, want_rel, rtol=2e-3)
    assert_allclose(gnd, want_gnd, rtol=2e-3, atol=1e-9)


def test_natural_frequencies_of_presets_match_engines_md():
    # engines.md §2 (CHK, openTorsion): K9K 61.5 / 137 / 524 Hz; genset-v20 island 19.7, 97.8 Hz (grid adds 2.45 Hz)
    k9k = natural_frequencies(shaft_model(load_engine("k9k-4cyl"), 0.0, 180.0))
    assert_allclose(k9k[1:4], [61.5, 137.0, 524.0], rtol=0.03)
    v20 = shaft_model(load_engine("genset-v20"), 0.0, 157.0)
    f = natural_frequencies(v20)
    f = f[f > 0.5]  # the viscous damper ring (K_D = 0) has a free 0 Hz mode
    assert_allclose(f[0], 2.45, rtol=0.05)
    assert_allclose(f[1:3], [19.8, 97.8], rtol=0.03)
    assert_allclose(first_flexible_mode_hz(v20), f[1])
    assert np.isinf(first_flexible_mode_hz(shaft_model(load_engine("deutz-1cyl"), 27.0, 272.0)))


def test_mean_reciprocating_inertia_series():
    spec = load_engine("k9k-4cyl")
    lam = spec.crank_radius / spec.conrod
    want = spec.reciprocating_mass * spec.crank_radius**2 * (0.5 + lam**2 / 8)  # physics.md §3, to O(lambda^4)
    assert_allclose(mean_reciprocating_inertia(spec), want, rtol=2e-3)


def _rigid_run(spec, rpm, cycles=1.5, steps_per_rev=1440):
    """Rigid single-cylinder engine integrated in time by RK4: J(theta) alpha = T_g - T_f - T_L - 1/2 J' omega^2,
    with a smooth synthetic pressure and the Rezeka-Henein friction at the preset's coefficients."""
    kin, fric = spec.kinematics_params(), spec.friction_params()
    a = spec.friction.coefficients
    vc, area = spec.clearance_volume, spec.piston_area

    def pressure(th):
        x, _, _ = kinematics(th, kin)
        motored = 1.0e5 * ((vc + area * spec.stroke) / (vc + area * x)) ** 1.35
        loc = (th + 2 * np.pi) % (4 * np.pi) - 2 * np.pi
        return motored + 45e5 * np.exp(-0.5 * ((loc - 0.2) / 0.18) ** 2)

    omega0 = rpm * np.pi / 30

    def rhs(th, om):
        p = pressure(np.array([th]))
        tg = gas_torque(np.array([th]), p[None], spec.firing_angles, kin, area)[0, 0]
        tf = friction_basis(np.array([th]), om, p - 1e5, fric)[:, 0] @ a
        j, dj = variable_inertia(np.array([th]), spec.firing_angles, kin, spec.reciprocating_mass,
                                 spec.total_inertia)
        tl = 25.0 * om / omega0
        return (tg - tf - tl - 0.5 * dj[0] * om * om) / j[0], tg, tf, tl

    h = 2 * np.pi / steps_per_rev / omega0
    n = int(cycles * 2 * steps_per_rev)
    th, om = 0.0, omega0
    out = np.empty((n, 6))
    for i in range(n):
        acc, tg, tf, tl = rhs(th, om)
        out[i] = th, om, acc, tg, tf, tl
        k1 = (om, acc)
        k2 = (om + 0.5 * h * k1[1], rhs(th + 0.5 * h * k1[0], om + 0.5 * h * k1[1])[0])
        k3 = (om + 0.5 * h * k2[1], rhs(th + 0.5 * h * k2[0], om + 0.5 * h * k2[1])[0])
        k4 = (om + h * k3[1], rhs(th + h * k3[0], om + h * k3[1])[0])
        th += h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        om += h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    return out, h


def test_rigid_balance_counts_the_mass_torque_once():
    spec = load_engine("deutz-1cyl")
    run, h = _rigid_run(spec, 2600.0)
    th, om, _, tg, tf, tl = run.T
    alpha = np.gradient(om, h)  # what a measurement gives: finite differences of the speed
    got = rigid_friction_torque(th, om, alpha, tg, tl, spec)
    inner = slice(5, -5)
    ripple = np.std(tf[inner])
    err = np.sqrt(np.mean((got - tf)[inner] ** 2))
    assert err < 0.03 * ripple  # physics.md §4: Newton form 2.4 % of the friction ripple (finite differences)
    # constant mean J (variable inertia ignored) is wrong by more than the ripple itself (physics.md §4 table)
    j_mean = spec.total_inertia + mean_reciprocating_inertia(spec)
    const = tg - tl - j_mean * alpha
    assert np.sqrt(np.mean((const - tf)[inner] ** 2)) > 3 * ripple
    # energy form plus the mass torque subtracted again (double count) is as bad
    j, dj = variable_inertia(th, spec.firing_angles, spec.kinematics_params(), spec.reciprocating_mass,
                             spec.total_inertia)
    double = tg - tl - (j * alpha + 0.5 * dj * om**2) - 0.5 * dj * om**2
    assert np.sqrt(np.mean((double - tf)[inner] ** 2)) > 3 * ripple


def _teeth_for(phi_harm, drift, omega, n_teeth=60, missing=2, tick_hz=10e6, theta0=0.1):
    """Edge times of a wheel whose angle follows theta0 + omega tau + phi(tau), solved by Newton, then ticks."""
    period = 4 * np.pi / omega
    per_rev = np.array([i for i in range(n_teeth) if i < n_teeth - missing]) * 2 * np.pi / n_teeth
    ang = np.concatenate([per_rev, per_rev + 2 * np.pi, [4 * np.pi]])
    w = 0.5 * omega * np.arange(1, phi_harm.size + 1)

    def phi(t):
        u = t / period
        return drift * u * (u - 1) + np.real(phi_harm[None, :] * np.exp(1j * np.outer(t, w))).sum(axis=1)

    base = phi(np.array([0.0]))[0]
    t = ang / omega
    for _ in range(30):
        f = omega * t + phi(t) - base - ang
        dphi = np.real(1j * w[None, :] * phi_harm[None, :] * np.exp(1j * np.outer(t, w))).sum(axis=1)
        t -= f / (omega + dphi + drift * (2 * t / period - 1) / period)
    ticks = np.round(t * tick_hz).astype(np.int64) + 123_456
    return ticks, ang + theta0, period


def test_flywheel_fit_recovers_harmonics_and_drift_from_ticks():
    omega = 180.0
    m = 16
    rng = np.random.default_rng(3)
    harm = (rng.normal(size=m) + 1j * rng.normal(size=m)) * 2e-3 / np.arange(1, m + 1) ** 1.5
    drift = 4e-3
    # an (unrealistically) fine clock: the fit itself is exact
    ticks, ang, period = _teeth_for(harm, drift, omega, tick_hz=1e12)
    fly = fit_flywheel(ticks, 1e12, ang, m)
    assert_allclose(fly.harmonics, harm, atol=1e-8)
    assert_allclose(fly.drift, drift, rtol=1e-5)
    assert_allclose(fly.period, period, rtol=1e-9)
    # a 10 MHz clock: 1 tick = 1e-7 s -> omega * 1e-7 / sqrt(12) = 5e-6 rad per edge. A linear speed drift looks
    # much like order 0.5 over one cycle (u(u-1) vs cos 2 pi u), so harmonics 1-2 carry ~10x more noise than the rest
    ticks, ang, period = _teeth_for(harm, drift, omega)
    fly = fit_flywheel(ticks, 10e6, ang, m)
    assert_allclose(fly.harmonics[2:], harm[2:], atol=3e-6)
    assert_allclose(fly.harmonics[:2], harm[:2], atol=1e-4)
    assert 4e-6 < fly.residual_rms < 6e-6
    tau, _, om, al = fly.on_grid(512)
    assert_allclose(np.mean(om), omega, rtol=1e-4)
    # central differences err by (w h)^2/6 = 0.6 % at harmonic 16 of 512 samples
    assert_allclose(np.gradient(om, tau)[10:-10], al[10:-10], atol=1e-2 * np.abs(al).max())


def test_harmonic_series_round_trip_and_bad_input():
    rng = np.random.default_rng(0)
    c = rng.normal(size=(3, 10)) + 1j * rng.normal(size=(3, 10))
    assert_allclose(harmonics_of(harmonic_series(c, 64), 10), c, atol=1e-12)
    with pytest.raises(ValueError, match="harmonics need more"):
        harmonic_series(c, 20)
    with pytest.raises(ValueError, match="span one 720 deg cycle"):
        fit_flywheel(np.arange(200, dtype=np.int64) * 100, 1e6, np.linspace(0, 3 * np.pi, 200), 8)
    with pytest.raises(ValueError, match="cannot carry"):
        fit_flywheel(np.arange(20, dtype=np.int64) * 100, 1e6, np.linspace(0, 4 * np.pi, 20), 12)
