"""Plant kernel (core/plant.py) against a plain numpy reference built from the tested torque/friction/inertia
kernels, the plant's linearisation against scipy's generalised eigenvalues and engines.md's CHK frequencies, and the
integrator's step convergence."""

import math

import frictionwatch.core.plant.simulate as simulate_mod
import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.kinematics import variable_inertia
from frictionwatch.core.model.terms import cylinder_samples_reference, rezeka_henein
from frictionwatch.core.model.thermo import cylinder_model
from frictionwatch.core.model.torques import gas_torque
from frictionwatch.core.plant.plant import (
    NQ_GLOBAL,
    PlantArrays,
    PressureTraces,
    _load_torque,
    plant_rhs,
    work_arrays,
)
from frictionwatch.core.plant.plant_advance import crossing, herm
from frictionwatch.core.plant.plant_setup import build_plant, chain_matrices, linearised_stiffness, scalars
from frictionwatch.core.plant.simulate import simulate
from numpy.testing import assert_allclose, assert_array_equal
from scipy.linalg import eigh

from tests.core.test_terms import AUX_QUADRATIC


def make(spec, rng, variable=True, library=None):
    lib = rezeka_henein(spec.friction.coefficients) if library is None else library
    z = spec.n_cyl
    coef = np.append(spec.friction.coefficients, 1e-5 * np.ones(len(lib) - 6)) * rng.uniform(0.5, 1.5, (z, len(lib)))
    extra = np.column_stack([rng.uniform(0, 1, z), rng.uniform(0, 1, z), np.full(z, 2.0), rng.uniform(0, 6, z)])
    plant = build_plant(spec, flexible=True, variable=variable, coef=coef, phase=spec.firing_angles, extra=extra,
                        library=lib)
    return plant


@pytest.mark.parametrize("name,variable,new_term", [("k9k-4cyl", True, False), ("genset-v20", True, False),
                                                    ("k9k-4cyl", False, False), ("k9k-4cyl", True, True)])
def test_rhs_matches_numpy_reference(name, variable, new_term):
    """The plant's right-hand side against numpy; with ``new_term`` the library carries a seventh loss term
    (tests/core/test_terms.AUX_QUADRATIC) that the plant integrates without any edit of its kernel."""
    spec = load_engine(name)
    rng = np.random.default_rng(7)
    lib = rezeka_henein(spec.friction.coefficients)
    if new_term:
        lib = lib + AUX_QUADRATIC
    plant = make(spec, rng, variable, lib)
    n_terms = len(lib)
    q = plant.nq_cyl
    tm = cylinder_model(spec)
    n, z = plant.n, spec.n_cyl
    th = rng.uniform(0.3, 0.5) + rng.normal(0, 0.01, n)
    om = 150.0 + rng.normal(0, 3, n)
    traces = rng.uniform(0.5e5, 150e5, (z, 3, tm.theta.shape[0]))
    slots = np.zeros((z, 3), dtype=np.int64)
    for k in range(z):  # cycle c of cylinder k lives in slot c % 3
        for c in (-1, 0, 1):
            slots[k, c % 3] = c
    lp = np.array([1.0, 0, 0, 1, 1000.0, 7e4, 2e3, 0.2, 150.0, 50.0, 1.5, 0.3])
    sc = scalars(spec, plant)
    acc, pw = np.zeros(n), np.zeros(z * q + NQ_GLOBAL)
    w = work_arrays(z, n_terms)
    nd = (plant.inertia, plant.stiff, plant.damp, np.zeros(n), np.zeros(n), np.zeros(n))
    t = 0.01
    model = PlantArrays(nd, plant.cylinders, sc, spec.friction_params(), lp, PressureTraces(traces, slots, tm.step))
    plant_rhs(t, th, om, model, w, acc, pw)

    # reference: per cylinder at its own node angle
    k_mat, c_mat = chain_matrices(plant)[1], chain_matrices(plant, 0.0)[2]
    torque = -(k_mat @ th) - (c_mat @ om)
    jv, hdj = plant.inertia.copy(), np.zeros(n)
    for k in range(z):
        j = plant.cyl_node[k]
        loc = th[j] - plant.phase[k]
        cyc = int(np.floor((loc + 2 * np.pi) / (4 * np.pi)))
        p = np.interp(loc - 4 * np.pi * cyc, tm.theta, traces[k, cyc % 3])
        tg = gas_torque(np.array([th[j]]), np.array([[p]]), plant.phase[k:k + 1], spec.kinematics_params(),
                        spec.piston_area, 1e5)[0, 0]
        consts = spec.friction_params()
        f = lib.evaluate_reference(cylinder_samples_reference(np.array([loc]), om[j], p - 1e5, consts), consts)[:, 0]
        tf = plant.coef[k] @ f + plant.extra[k, 0] + plant.extra[k, 1] * np.cos(2.0 * loc + plant.extra[k, 3])
        torque[j] += tg - tf
        if variable:
            jj, dj = variable_inertia(np.array([th[j]]), plant.phase[k:k + 1], spec.kinematics_params(),
                                      spec.reciprocating_mass, 0.0)
            jv[j] += jj[0]
            hdj[j] += 0.5 * dj[0]
        # same formulas, other association (kernels vs numpy): 1e-9
        assert_allclose(pw[k * q], tg * om[j], rtol=1e-9)
        assert_allclose(pw[k * q + 1:k * q + 1 + n_terms], f * om[j], rtol=1e-9, atol=1e-12)
    ln = plant.load
    tl = 1000.0 + 7e4 * (th[ln] - 150.0 * t - 0.2) + 2e3 * (om[ln] - 150.0) + 50.0 * np.sin(1.5 * th[ln] + 0.3)
    torque[ln] -= tl
    assert_allclose(acc, (torque - hdj * om**2) / jv, rtol=1e-9, atol=1e-9 * np.abs(acc).max())
    g = z * q
    assert_allclose(pw[g:g + 3], [tl * om[ln], om @ c_mat @ om, tl], rtol=1e-9)


def test_load_law_short_cuts_are_the_general_law():
    """The dyno law with exponent 1 and no ripple skips pow and sin: the same numbers as the general formula (pow(x,
    1) is x; adding 0 sin(..) changes nothing), bit for bit, and a law with neither still takes them."""
    om = np.concatenate([[0.0, -5.0, 1e-300, 1e150], np.linspace(0.1, 900.0, 200)])
    th = np.linspace(-50.0, 5000.0, om.size)
    for c, k, s, ripple in ((0.0, 0.1036, 1.0, 0.0), (1.4e-14, 0.55, 1.0, 0.0), (3.0, 0.02, 1.7, 0.0),
                            (3.0, 0.5, 1.0, 12.0), (2.0, 0.01, 2.0, 5.0)):
        lp = np.array([0.0, c, k, s, 0, 0, 0, 0, 0, ripple, 1.5, 0.3])
        got = np.array([_load_torque(0.1, a, b, lp) for a, b in zip(th, om)])
        # the general formula with the C library's pow and sin (numba's too)
        want = [c + k * math.pow(max(b, 0.0), s) + ripple * math.sin(1.5 * a + 0.3) for a, b in zip(th, om)]
        assert_array_equal(got, want)


def test_hermite_crossing_inverts_a_cubic():
    h, y0, d0, y1, d1 = 1e-4, 1.0, 150.0, 1.0162, 170.0
    for target in np.linspace(y0, y1, 7):
        s = crossing(target, h, y0, d0, y1, d1)
        assert abs(herm(s, h, y0, d0, y1, d1) - target) < 1e-12


# engines.md §2 natural frequencies [Hz] (CHK, openTorsion); maruti's CHK set (39, 632, 1739) used another layout
CHK_HZ = {"genset-v20": [2.45, 19.8, 97.8, 282, 473, 661], "k9k-4cyl": [61.5, 137, 524, 1432]}


@pytest.mark.parametrize("name", ["genset-v20", "k9k-4cyl", "maruti-3cyl", "deutz-1cyl"])
def test_natural_frequencies_plant_vs_eigh_vs_engines_md(name):
    spec = load_engine(name)
    z = spec.n_cyl
    plant = build_plant(spec, flexible=True, variable=True, coef=np.zeros((z, 6)), phase=spec.firing_angles,
                        extra=np.zeros((z, 4)))
    grid_k = spec.load.grid_stiffness_nm_per_rad if spec.load.kind == "grid" else 0.0
    law = np.zeros(12)
    law[0], law[5], law[8] = (1.0 if grid_k else 0.0), grid_k, 157.0
    jac = linearised_stiffness(spec, plant, cylinder_model(spec), law)  # M^-1 K as the kernel integrates it
    f_plant = np.sqrt(np.clip(np.sort(np.linalg.eigvals(jac).real), 0, None)) / (2 * np.pi)
    # independent: K assembled here from the spec's section stiffness, M = rotating + mean reciprocating inertia
    k = np.zeros((spec.n_nodes, spec.n_nodes))
    for i, ki in enumerate(spec.stiffness):
        k[i:i + 2, i:i + 2] += ki * np.array([[1.0, -1.0], [-1.0, 1.0]])
    k[spec.load_node, spec.load_node] += grid_k
    m = spec.node_inertia.copy()
    grid = np.linspace(0, 4 * np.pi, 2880, endpoint=False)
    for node in set(spec.cylinder_node.tolist()):
        j, _ = variable_inertia(grid, spec.firing_angles[spec.cylinder_node == node], spec.kinematics_params(),
                                spec.reciprocating_mass, 0.0)
        m[node] += j.mean()
    f_eigh = np.sqrt(np.clip(eigh(k, np.diag(m), eigvals_only=True), 0, None)) / (2 * np.pi)
    assert_allclose(f_plant, f_eigh, rtol=1e-5, atol=1e-3)
    if name in CHK_HZ:
        nonzero = f_eigh[f_eigh > 0.5]
        assert_allclose(nonzero[:len(CHK_HZ[name])], CHK_HZ[name], rtol=0.01)


def test_integrator_step_convergence(monkeypatch):
    """Halving the RK4 step changes the flywheel speed trace by < 0.1 % of its ripple (K9K near its cardan mode)."""
    spec = load_engine("k9k-4cyl")
    kw = {"cov_imep": 0.0, "without": {"sensor_noise", "tooth_spacing_error"}}
    a = simulate(spec, 1700, 1.0, 2, 1, **kw).diagnostics["flywheel_speed_grid_rad_s"]
    monkeypatch.setattr(simulate_mod, "STEP_DEG", 0.125)
    b = simulate(spec, 1700, 1.0, 2, 1, **kw).diagnostics["flywheel_speed_grid_rad_s"]
    ripple = a.max() - a.min()
    assert np.max(np.abs((a - a.mean()) - (b - b.mean()))) < 1e-3 * ripple
