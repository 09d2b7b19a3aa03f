"""IMEP and peak pressure against a plain-numpy reference and a closed-form case."""

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.indicated import (
    net_imep,
    peak_pressure,
    piston_positions,
    window_starts,
    window_works,
    window_works_reference,
    works_at,
    works_with_alone,
)
from frictionwatch.core.model.kinematics import cylinder_volume
from numpy.testing import assert_allclose


def test_imep_matches_numpy_trapezoid_of_p_dv():
    spec = load_engine("k9k-4cyl")
    th = np.linspace(0, 4 * np.pi, 1440, endpoint=False)
    rng = np.random.default_rng(4)
    p = 1e5 + rng.uniform(0, 80e5, (4, th.size))
    got = net_imep(th, p, spec.firing_angles, spec.kinematics_params(), spec.piston_area, spec.displacement_cyl)
    for k in range(4):
        v = cylinder_volume(th - spec.firing_angles[k], spec.kinematics_params(), spec.piston_area,
                            spec.clearance_volume)
        vc, pc = np.append(v, v[0]), np.append(p[k], p[k][0])
        assert_allclose(got[k], np.trapezoid(pc, vc) / spec.displacement_cyl, rtol=1e-10)


def test_constant_pressure_and_isentropic_loop_have_zero_work():
    spec = load_engine("deutz-1cyl")
    th = np.linspace(0, 4 * np.pi, 2880, endpoint=False)
    v = cylinder_volume(th, spec.kinematics_params(), spec.piston_area, spec.clearance_volume)
    flat = net_imep(th, np.full((1, th.size), 3e5), spec.firing_angles, spec.kinematics_params(),
                    spec.piston_area, spec.displacement_cyl)
    loop = net_imep(th, (2e5 * (v.max() / v) ** 1.35)[None], spec.firing_angles, spec.kinematics_params(),
                    spec.piston_area, spec.displacement_cyl)
    assert abs(flat[0]) < 1e-6 and abs(loop[0]) < 1e-3 * 1e5


def test_peak_pressure_angle_is_refined_between_samples():
    th = np.linspace(0, 4 * np.pi, 720, endpoint=False)
    true_angle = np.radians(12.3)
    p = 100e5 - 1e9 * (th - true_angle) ** 2
    pmax, ang = peak_pressure(th, p[None], np.array([0.0]))
    assert_allclose(np.degrees(ang[0]), 12.3, atol=1e-6)
    assert_allclose(pmax[0], 100e5, rtol=1e-9)


def test_window_works_match_the_numpy_trapezoid_over_two_cycles():
    """Windows across the previous and the current cycle, at the grid's ends and between: the kernel sums in the
    same order as the trapezoid, numpy pairwise, so ~1e-14 of the work [J] (1e-12 relative stated)."""
    spec = load_engine("genset-v20")
    th = 0.003 + np.arange(720) * (4 * np.pi / 720)
    rng = np.random.default_rng(11)
    prev, cur = (1e5 + rng.uniform(0, 80e5, (spec.n_cyl, th.size)) for _ in range(2))
    x = piston_positions(th, spec.firing_angles, spec.kinematics_params())
    centres = np.stack([rng.uniform(-2 * np.pi, 2 * np.pi, spec.n_cyl), np.full(spec.n_cyl, -2 * np.pi),
                        np.full(spec.n_cyl, 2 * np.pi), np.zeros(spec.n_cyl)])
    got = window_works(th, x, prev, cur, centres, spec.piston_area)
    assert_allclose(got, window_works_reference(th, x, prev, cur, centres, spec.piston_area), rtol=1e-12)


def test_works_with_alone_are_the_two_windowed_calls():
    """The transient balance's one call (windows over [previous | current] and over [current | current]) against
    two ``works_at`` calls and the numpy trapezoid: the same terms summed in the same order, so equal to 1e-15
    relative (stated; they agree to the bit), and the reference to 1e-12."""
    spec = load_engine("k9k-4cyl")
    th = 0.01 + np.arange(720) * (4 * np.pi / 720)
    rng = np.random.default_rng(12)
    prev, cur = (1e5 + rng.uniform(0, 80e5, (spec.n_cyl, th.size)) for _ in range(2))
    x = piston_positions(th, spec.firing_angles, spec.kinematics_params())
    centres = np.stack([rng.uniform(-2 * np.pi, 2 * np.pi, spec.n_cyl), np.zeros(spec.n_cyl)])
    alone_centres = np.stack([np.zeros(spec.n_cyl), np.full(spec.n_cyl, 2 * np.pi)])
    starts, alone_starts = window_starts(th, centres), window_starts(th, alone_centres)
    own, alone = works_with_alone(x, prev, cur, starts, alone_starts, spec.piston_area)
    assert_allclose(own, works_at(x, prev, cur, starts, spec.piston_area), rtol=1e-15, atol=0)
    assert_allclose(alone, works_at(x, cur, cur, alone_starts, spec.piston_area), rtol=1e-15, atol=0)
    assert_allclose(alone, window_works_reference(th, x, cur, cur, alone_centres, spec.piston_area), rtol=1e-12)
    assert_allclose(own, window_works_reference(th, x, prev, cur, centres, spec.piston_area), rtol=1e-12)
