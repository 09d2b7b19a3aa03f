"""The fused excitation kernel and the row interpolation against plain numpy references.

References: gas and reciprocating torques from core.model.torques (physics.md §2, §3), the six Rezeka-Henein basis terms
from frictionwatch.core.model.friction (paper 000 Eq. 4), the node sums of physics.md §12.3 item 2 written out with numpy, work means as
np.mean(T * omega_q / Omega); np.interp for the interpolation. Tolerance: the kernel uses the angle-sum rule for the
local sin/cos and vectorised sums, so it agrees to rounding (rtol 1e-12 of each row's scale).
"""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.excitation import CRANKCASE_PA, excitation_plan
from frictionwatch.core.monitor.excitation_kernels import OMEGA_SLOT, interp_rows_periodic
from frictionwatch.core.model.friction import friction_basis
from frictionwatch.core.model.torques import gas_torque, reciprocating_torque
from tests.core.excitation_reference import _excitation_rows


def reference_rows(spec, motion, theta_fly, p_abs, recip_inertia_mean, variable_inertia, omega_mean):
    """Plain numpy: known node torques (N, n), basis (z, 6, n), gas (z, n), basis means (z, 6), indicated (z,)."""
    n_nodes, n = motion.shape[1:]
    z = spec.n_cyl
    kin, fric = spec.kinematics_params(), spec.friction_params()
    node = spec.cylinder_node
    gas = np.empty((z, n))
    known = np.zeros((n_nodes, n))
    for q in np.unique(node):
        cyl = np.flatnonzero(node == q)
        ph = spec.firing_angles[cyl]
        gas[cyl] = gas_torque(motion[0, q], p_abs[cyl], ph, kin, spec.piston_area, CRANKCASE_PA)
        known[q] = gas[cyl].sum(axis=0)
        if variable_inertia:
            t_a = reciprocating_torque(motion[0, q], motion[1, q], motion[2, q], ph, kin, spec.reciprocating_mass)
            known[q] += recip_inertia_mean * cyl.size * motion[2, q] - t_a.sum(axis=0)
    basis = np.stack([friction_basis(motion[0, node[k]] - spec.firing_angles[k], motion[1, node[k]],
                                     p_abs[k] - CRANKCASE_PA, fric) for k in range(z)])
    w_over = motion[1, node] / omega_mean
    return known, basis, gas, np.mean(basis * w_over[:, None, :], axis=-1), np.mean(gas * w_over, axis=-1)


@pytest.mark.parametrize("name", ["genset-v20", "k9k-4cyl", "deutz-1cyl"])
@pytest.mark.parametrize("variable_inertia", [True, False])
@pytest.mark.parametrize("seed", [0, 1])
def test_excitation_rows_match_numpy_reference(name, variable_inertia, seed):
    spec = load_engine(name)
    rng = np.random.default_rng(seed)
    n, n_nodes, z = 256, spec.n_nodes, spec.n_cyl
    omega_mean = 150.0
    tau = np.arange(n) * (4 * np.pi / omega_mean / n)
    theta_fly = rng.uniform(-1, 1) + omega_mean * tau + 0.01 * np.sin(2 * np.pi * np.arange(n) / n * 3)
    motion = np.empty((3, n_nodes, n))
    # node twists: small (series branch) and one large enough to take the direct sin/cos branch
    twist = rng.normal(0, 2e-3, (n_nodes, 1)) + 1e-3 * np.sin(2 * np.pi * np.arange(n) / n * 5 + rng.uniform(0, 6))
    if n_nodes > 2:
        twist[1] += 0.2
    twist[spec.flywheel_node] = 0.0
    motion[0] = theta_fly + twist
    motion[1] = omega_mean * (1 + 0.02 * rng.standard_normal((n_nodes, n)))
    motion[2] = 500.0 * rng.standard_normal((n_nodes, n))
    p_abs = 1e5 + 5e6 * rng.random((z, n)) - 2e4  # some samples below the crankcase pressure
    j_rec = 0.01
    plan = excitation_plan(spec, j_rec, variable_inertia)
    consts = plan.consts.copy()
    consts[OMEGA_SLOT] = omega_mean
    rows = np.empty((n_nodes + 7 * z, n))
    means = np.empty((z, 7))
    _excitation_rows(motion, np.ascontiguousarray(theta_fly), p_abs, plan.cyl_node, consts, rows, means)
    known, basis, gas, b_mean, i_mean = reference_rows(spec, motion, theta_fly, p_abs, j_rec, variable_inertia,
                                                       omega_mean)
    assert_allclose(rows[:n_nodes], known, rtol=0, atol=1e-12 * np.abs(known).max())
    got_basis = rows[n_nodes: n_nodes + 6 * z].reshape(z, 6, n)
    for term in range(6):
        scale = max(np.abs(basis[:, term]).max(), 1e-300)
        assert_allclose(got_basis[:, term], basis[:, term], rtol=0, atol=1e-12 * scale)
        assert_allclose(means[:, term], b_mean[:, term], rtol=0, atol=1e-12 * scale)
    assert_allclose(rows[n_nodes + 6 * z:], gas, rtol=0, atol=1e-12 * np.abs(gas).max())
    assert_allclose(means[:, 6], i_mean, rtol=0, atol=1e-12 * np.abs(gas).max())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_interp_rows_periodic_is_np_interp(seed):
    rng = np.random.default_rng(seed)
    n = 97
    xp = np.concatenate([[0.0], np.cumsum(rng.uniform(0.5, 1.5, n))])
    fp = rng.standard_normal((4, n))
    xq = np.concatenate([rng.uniform(-1, xp[-1] + 1, 300), xp[:5], [xp[-1]]])  # outside, on knots, unsorted
    got = interp_rows_periodic(xq, xp, fp)
    for k in range(4):
        np.testing.assert_array_equal(got[k], np.interp(xq, xp, np.append(fp[k], fp[k, 0])))


def test_interp_rows_periodic_rejects_bad_knots():
    with pytest.raises(ValueError, match="one point more"):
        interp_rows_periodic(np.zeros(3), np.arange(4.0), np.zeros((1, 4)))
    with pytest.raises(ValueError, match="increasing"):
        interp_rows_periodic(np.zeros(3), np.array([0.0, 2.0, 1.0]), np.zeros((1, 2)))
