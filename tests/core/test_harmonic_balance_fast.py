"""The fused harmonic-balance pass (core.monitor.harmonic_balance, core.monitor.harmonic_balance_kernels) against the implementation
it replaced, kept here as the plain reference: numpy grid motion (one irfft), np.interp-style pressure, the fused
excitation kernel _excitation_rows of tests/core/excitation_reference.py (itself tested against core.model.torques /
core.model.friction in test_excitation_kernels.py), one rfft of every row, np.add.at / einsum for the chain,
identify.friction_design and ParameterLayout.cylinder_rows for the rows.

Tolerance: the new code forms the parameter-weighted friction sums in the time domain before the FFT (linearity),
multiplies where the old kernel divided, and sums in another order, so it agrees to rounding: 1e-10 of each
quantity's scale (measured: ~1e-14).
"""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from frictionwatch.core.model.dynamics import static_twist
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.excitation import Excitation, excitation_plan
from frictionwatch.core.monitor.excitation_kernels import OMEGA_SLOT
from frictionwatch.core.monitor.flywheel import FlywheelMotion, harmonics_of
from frictionwatch.core.model.friction import N_TERMS
from frictionwatch.core.monitor.harmonic_balance import harmonic_balance, operating_point
from frictionwatch.core.monitor.identify import friction_design
from frictionwatch.core.monitor.monitor import initial_state
from tests.core.excitation_reference import _excitation_rows, cycle_excitation, grid_motion, periodic_interp

RTOL = 1e-10


def grid_motion_reference(fly, n, theta_start, n_nodes, rel, static):
    m = fly.n_harmonics
    w = fly.freq
    harm = fly.harmonics
    n_rel = 0 if rel is None else n_nodes
    spec_rows = np.zeros((3 + 3 * n_rel, n // 2 + 1), dtype=np.complex128)
    half = 0.5 * n
    spec_rows[0, 1: m + 1] = harm * half
    spec_rows[1, 1: m + 1] = (1j * w * harm) * half
    spec_rows[2, 1: m + 1] = (-(w**2) * harm) * half
    if n_rel:
        spec_rows[3: 3 + n_rel, 1: m + 1] = rel * half
        spec_rows[3 + n_rel: 3 + 2 * n_rel, 1: m + 1] = (1j * w * rel) * half
        spec_rows[3 + 2 * n_rel:, 1: m + 1] = (-(w**2) * rel) * half
    series = np.fft.irfft(spec_rows, n=n, axis=-1)
    period = fly.period
    tau = np.arange(n) * (period / n)
    u = tau / period
    phi = fly.offset + fly.drift * u * (u - 1.0) + series[0]
    omega_f = (fly.omega_mean + fly.drift * (2.0 * u - 1.0) / period) + series[1]
    alpha_f = 2.0 * fly.drift / period**2 + series[2]
    theta_f = theta_start + fly.omega_mean * tau + phi
    motion = np.empty((3, n_nodes, n))
    motion[0] = theta_f + (series[3: 3 + n_rel] if n_rel else 0.0)
    motion[1] = omega_f + (series[3 + n_rel: 3 + 2 * n_rel] if n_rel else 0.0)
    motion[2] = alpha_f + (series[3 + 2 * n_rel:] if n_rel else 0.0)
    if static is not None:
        motion[0] += static[:, None]
    return tau, theta_f, omega_f, alpha_f, motion


def cycle_excitation_reference(spec, grid, pressure, fly, theta_start, n_time, j_rec, rel, static, var_inertia):
    z, n_nodes, m = spec.n_cyl, spec.n_nodes, fly.n_harmonics
    plan = excitation_plan(spec, j_rec, var_inertia)
    tau, theta_f, omega_f, alpha_f, motion = grid_motion_reference(fly, n_time, theta_start, n_nodes, rel, static)
    p_t = periodic_interp(theta_f, grid, pressure)
    consts = plan.consts.copy()
    consts[OMEGA_SLOT] = fly.omega_mean
    rows = np.empty((n_nodes + 7 * z, n_time))
    means = np.empty((z, 7))
    _excitation_rows(motion, theta_f, p_t, plan.cyl_node, consts, rows, means)
    harm = harmonics_of(rows[: n_nodes + 6 * z], m)
    return dict(tau=tau, theta_fly=theta_f, omega_node=motion[1], gas=rows[n_nodes + 6 * z:],
                known_harm=harm[:n_nodes], basis=rows[n_nodes: n_nodes + 6 * z].reshape(z, N_TERMS, n_time),
                basis_harm=harm[n_nodes:].reshape(z, N_TERMS, m), basis_mean=means[:, :N_TERMS],
                indicated_mean=means[:, N_TERMS], omega_fly=omega_f, alpha_fly=alpha_f)


def harmonic_balance_reference(spec, layout, theta, n_nuisance, rel, static, grid, pressure, fly, theta_start, op,
                               passes, time_samples, var_inertia):
    n_nodes = spec.n_nodes
    coef = layout.coefficients(theta[: layout.n_params])
    n_pass = max(1, passes - 1) if rel is not None and static is not None else max(1, passes)
    for _ in range(n_pass):
        exc = cycle_excitation_reference(spec, grid, pressure, fly, theta_start, time_samples,
                                         op.shaft.recip_inertia_mean, rel if n_nodes > 1 else None,
                                         static if n_nodes > 1 else None, var_inertia)
        mean_torque = np.zeros(n_nodes)
        np.add.at(mean_torque, spec.cylinder_node, exc["indicated_mean"] - (coef * exc["basis_mean"]).sum(axis=1))
        static = static_twist(op.shaft, mean_torque)
        torque = exc["known_harm"].copy()
        np.add.at(torque, spec.cylinder_node, -np.einsum("kl,klm->km", coef, exc["basis_harm"]))
        phi = np.einsum("mij,jm->im", op.receptance.inverse, torque)
        rel = phi - phi[op.shaft.flywheel]
    node_speed = 1j * op.receptance.freq[None, :] * phi
    w0 = np.einsum("mq,qm->m", op.transfer, exc["known_harm"])
    design = friction_design(layout, op.transfer, exc["basis_harm"], spec.cylinder_node)
    if n_nuisance:
        design = np.hstack([design, 1j * fly.freq[:, None] * fly.pattern_harmonics[:, :n_nuisance]])
    cyl_rows = layout.cylinder_rows(exc["basis_mean"])
    rows = dict(design=design, target=fly.speed_harmonics - w0,
                mean_row=np.concatenate([cyl_rows.sum(axis=0), np.zeros(n_nuisance)]), cylinder_rows=cyl_rows)
    return exc, rows, node_speed, rel, static


def cycle_inputs(name, seed, n_grid=720):
    """Seeded inputs of one cycle at the engine's real sizes (Wiebe-like pressure bumps at each firing angle)."""
    spec = load_engine(name)
    rng = np.random.default_rng(seed)
    state = initial_state(spec)
    m, n_nuis, layout = state.n_harmonics, state.n_nuisance, state.layout
    omega = rng.uniform(100.0, 300.0)
    period = 4 * np.pi / omega
    harm = (rng.normal(0, 2e-3, m) + 1j * rng.normal(0, 2e-3, m)) / np.arange(1, m + 1)
    pattern = rng.normal(0, 1, (m, n_nuis + 1)) + 1j * rng.normal(0, 1, (m, n_nuis + 1))
    fly = FlywheelMotion(period, omega, harm, rng.normal(0, 1e-3), rng.normal(0, 1e-3), 1e-4, 300, np.zeros(301),
                         pattern)
    grid = np.linspace(0.0, 4 * np.pi, n_grid, endpoint=False) + rng.uniform(-0.5, 0.5)
    ang = (grid[None, :] - spec.firing_angles[:, None]) % (4 * np.pi)
    ang = np.minimum(ang, 4 * np.pi - ang)
    pressure = 1e5 + rng.uniform(2e6, 8e6, (spec.n_cyl, 1)) * np.exp(-(ang / 0.4) ** 2) + 2e4 * rng.random(
        (spec.n_cyl, n_grid))
    op = operating_point(spec, None, omega, rng.uniform(100.0, 1000.0), m, 0.005, True)
    n = spec.n_nodes
    rel = (rng.normal(0, 3e-3, (n, m)) + 1j * rng.normal(0, 3e-3, (n, m))) / np.arange(1, m + 1)
    rel[spec.flywheel_node] = 0.0
    static = rng.normal(0, 5e-3, n)
    static[spec.flywheel_node] = 0.0
    theta = np.concatenate([rng.uniform(0.5, 1.5, layout.n_params), rng.normal(0, 1e-3, n_nuis)])
    return spec, layout, theta, n_nuis, rel, static, grid, pressure, fly, rng.uniform(-1.0, 1.0), op


def close(got, ref, what):
    got, ref = np.asarray(got), np.asarray(ref)
    assert got.shape == ref.shape, what
    scale = max(float(np.abs(ref).max()), 1e-300)
    assert_allclose(got, ref, rtol=0, atol=RTOL * scale, err_msg=what)


@pytest.mark.parametrize("name", ["genset-v20", "k9k-4cyl", "deutz-1cyl"])
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("warm", [True, False])
@pytest.mark.parametrize("time_samples", [512, 256])
def test_harmonic_balance_matches_reference(name, seed, warm, time_samples):
    spec, layout, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, op = cycle_inputs(name, seed)
    if not warm:
        rel, static = None, None
    args = (spec, layout, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, op, 2, time_samples, True)
    exc, rows, node_speed, rel_new, static_new, power = harmonic_balance(*args)
    r_exc, r_rows, r_speed, r_rel, r_static = harmonic_balance_reference(*args)
    assert isinstance(exc, Excitation)
    for field, ref in r_exc.items():
        got = getattr(exc, field)
        if field in ("basis", "basis_harm", "basis_mean"):
            for term in range(N_TERMS):  # each friction term on its own scale
                close(got[:, term], ref[:, term], f"{field}[{term}]")
        else:
            close(got, ref, field)
    for c in range(r_rows["design"].shape[1]):
        close(rows.design[:, c], r_rows["design"][:, c], f"design[:, {c}]")
    close(rows.target, r_rows["target"], "target")
    close(rows.mean_row, r_rows["mean_row"], "mean_row")
    close(rows.cylinder_rows, r_rows["cylinder_rows"], "cylinder_rows")
    assert np.isnan(rows.mean_target)
    close(node_speed, r_speed, "node_speed")
    close(rel_new, r_rel, "relative_motion")
    close(static_new, r_static, "static")


@pytest.mark.parametrize("name", ["genset-v20", "deutz-1cyl"])
@pytest.mark.parametrize("variable_inertia", [True, False])
def test_cycle_excitation_matches_reference(name, variable_inertia):
    spec, layout, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, op = cycle_inputs(name, 3)
    rel_in = rel if spec.n_nodes > 1 else None
    static_in = static if spec.n_nodes > 1 else None
    exc = cycle_excitation(spec, grid, pressure, fly, theta_start, 512, op.shaft.recip_inertia_mean, rel_in,
                           static_in, variable_inertia)
    ref = cycle_excitation_reference(spec, grid, pressure, fly, theta_start, 512, op.shaft.recip_inertia_mean,
                                     rel_in, static_in, variable_inertia)
    for field, r in ref.items():
        close(getattr(exc, field), r, field)


def test_grid_motion_is_the_numpy_formula():
    spec, layout, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, op = cycle_inputs("genset-v20", 4)
    got = grid_motion(fly, 512, theta_start, spec.n_nodes, rel, static)
    ref = grid_motion_reference(fly, 512, theta_start, spec.n_nodes, rel, static)
    for g, r in zip(got, ref):
        assert_allclose(g, r, rtol=0, atol=1e-13 * np.abs(r).max())
    with pytest.raises(ValueError, match="static_twist"):
        grid_motion(fly, 512, theta_start, spec.n_nodes, rel, static[:3])
    with pytest.raises(ValueError, match="harmonics need more"):
        grid_motion(fly, 2 * fly.n_harmonics, theta_start, spec.n_nodes, rel, static)
