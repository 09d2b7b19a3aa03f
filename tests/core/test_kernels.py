"""Kinematics, variable inertia, torques and friction basis against plain-numpy references (physics.md §1-3, §7)."""

import numpy as np
import pytest
from frictionwatch.core.model.engine import available_presets, load_engine
from frictionwatch.core.model.kinematics import kinematics, variable_inertia
from frictionwatch.core.model.terms import cylinder_samples, rezeka_henein
from frictionwatch.core.model.torques import gas_torque, mass_torque, reciprocating_torque
from numpy.testing import assert_allclose


def friction_basis(theta, omega, p_gauge, consts):
    """The six Rezeka-Henein terms (L, n) of one cylinder through the term library (core.model.terms)."""
    return rezeka_henein().evaluate(cylinder_samples(theta, omega, p_gauge, consts), consts)


def ref_kinematics(theta, r, rod):
    """physics.md §1 closed forms (no pin offset)."""
    lam = r / rod
    s, c = np.sin(theta), np.cos(theta)
    root = np.sqrt(1 - lam**2 * s**2)
    x = r * ((1 - c) + (1 - root) / lam)
    dx = r * (s + lam * s * c / root)
    ddx = r * (c + lam * (c**2 - s**2) / root + lam**3 * s**2 * c**2 / root**3)
    return x, dx, ddx


@pytest.mark.parametrize("name", ["k9k-4cyl", "genset-v20", "deutz-1cyl", "maruti-3cyl"])
def test_kinematics_matches_closed_form(name):
    spec = load_engine(name)
    th = np.random.default_rng(1).uniform(-4 * np.pi, 4 * np.pi, 500)
    got = kinematics(th, spec.kinematics_params())
    want = ref_kinematics(th, spec.crank_radius, spec.conrod)
    for g, w in zip(got, want):
        assert_allclose(g, w, atol=1e-12 * spec.stroke)


@pytest.mark.parametrize("offset", [0.0, 0.004])
def test_kinematics_derivatives_by_finite_difference(offset):
    prm = np.array([0.04, 0.13, offset])
    th = np.linspace(-7, 7, 301)
    h = 1e-5
    x, dx, ddx = kinematics(th, prm)
    xp, dxp, _ = kinematics(th + h, prm)
    xm, dxm, _ = kinematics(th - h, prm)
    assert_allclose(dx, (xp - xm) / (2 * h), atol=1e-7 * 0.04)  # physics.md §1: max error 1e-7 R
    assert_allclose(ddx, (dxp - dxm) / (2 * h), atol=1e-6 * 0.04)
    assert x.min() >= -1e-12  # x is measured from the top position


def test_variable_inertia_mean_and_derivative():
    r, rod, m = 0.04, 0.04 / 0.30, 2.0
    prm = np.array([r, rod, 0.0])
    th = np.linspace(0, 4 * np.pi, 20001)
    j, dj = variable_inertia(th, np.array([0.0]), prm, m, 0.5)
    # physics.md §3: cycle mean of the reciprocating part is m R^2 (1/2 + lambda^2/8 + ...) = 0.5119 m R^2 at 0.30
    assert_allclose((j[:-1].mean() - 0.5) / (m * r**2), 0.5119, atol=2e-4)
    assert_allclose(dj[1:-1], (j[2:] - j[:-2]) / (th[2] - th[0]), atol=1e-5 * np.abs(dj).max())
    _, dx, ddx = ref_kinematics(th, r, rod)
    assert_allclose(dj, 2 * m * dx * ddx, atol=1e-12)


def test_gas_and_mass_torque_against_numpy():
    spec = load_engine("k9k-4cyl")
    rng = np.random.default_rng(2)
    th = np.linspace(0, 4 * np.pi, 720, endpoint=False)
    p = rng.uniform(0.5e5, 100e5, (4, th.size))
    got = gas_torque(th, p, spec.firing_angles, spec.kinematics_params(), spec.piston_area, 1e5)
    for k in range(4):
        _, dx, ddx = ref_kinematics(th - spec.firing_angles[k], spec.crank_radius, spec.conrod)
        assert_allclose(got[k], (p[k] - 1e5) * spec.piston_area * dx, rtol=1e-12, atol=1e-9)
    w = 178 + rng.normal(0, 2, th.size)
    a = rng.normal(0, 500, th.size)
    ta = reciprocating_torque(th, w, a, spec.firing_angles, spec.kinematics_params(), spec.reciprocating_mass)
    tm = mass_torque(th, w, spec.firing_angles, spec.kinematics_params(), spec.reciprocating_mass)
    _, dj = variable_inertia(th, spec.firing_angles, spec.kinematics_params(), spec.reciprocating_mass, 0.0)
    assert_allclose(tm.sum(0), -0.5 * dj * w**2, rtol=1e-10, atol=1e-9)
    j, _ = variable_inertia(th, spec.firing_angles, spec.kinematics_params(), spec.reciprocating_mass, 0.0)
    assert_allclose(ta.sum(0), j * a + 0.5 * dj * w**2, rtol=1e-10, atol=1e-9)


def ref_friction(theta, omega, p, spec):
    f = spec.friction
    d = spec.bore
    _, dx, _ = ref_kinematics(theta, spec.crank_radius, spec.conrod)
    lever = np.abs(dx)
    c = omega * lever
    th = np.mod(theta, 4 * np.pi)
    window = (th <= np.pi / 2) | (th >= 4 * np.pi - np.pi / 2)
    p = np.maximum(p, 0)
    return np.array([
        np.sqrt(f.oil_viscosity_pa_s * c * (f.ring_tension_pa + p) * f.ring_thickness_m)
        * np.pi * d * (f.oil_rings + 0.4 * f.compression_rings) * lever,
        np.where(window, np.pi * d * f.compression_rings * (f.ring_tension_pa + p) * (1 - np.abs(np.sin(th))) * lever, 0),
        f.oil_viscosity_pa_s * c / f.skirt_film_m * np.pi * d * f.skirt_length_m * lever,
        f.valves * f.valve_spring_n_per_m * lever / np.sqrt(omega),
        f.oil_viscosity_pa_s * omega,
        np.pi / 4 * d**2 * f.bearing_radius_m * p * np.abs(np.cos(th)) / np.sqrt(omega),
    ])


@pytest.mark.parametrize("name", available_presets())
def test_friction_basis_against_numpy(name):
    spec = load_engine(name)
    rng = np.random.default_rng(3)
    th = rng.uniform(-2 * np.pi, 6 * np.pi, 400)
    w = rng.uniform(50, 500, 400)
    p = rng.uniform(-1e5, 150e5, 400)
    got = friction_basis(th, w, p, spec.friction_params())
    assert_allclose(got, ref_friction(th, w, p, spec), rtol=1e-12, atol=1e-12)
    assert (got >= 0).all()


def test_friction_split_matches_engines_md_for_k9k_motored_terms():
    """engines.md §4: K9K at 1700 rpm, a = [12.8, ..] gives a_tilde_5 = 1.16, a_tilde_4 = 0.47, a_tilde_3 = 0.84 N m
    (terms that do not depend on pressure, so they are checked without a pressure trace)."""
    spec = load_engine("k9k-4cyl")
    th = np.linspace(0, 4 * np.pi, 2880, endpoint=False)
    w = 1700 * np.pi / 30
    f = friction_basis(th, w, np.zeros_like(th), spec.friction_params())
    a_tilde = spec.friction.coefficients * f.mean(axis=1)
    assert_allclose(a_tilde[[2, 3, 4]], [0.84, 0.47, 1.16], rtol=0.03)
