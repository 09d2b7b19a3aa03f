"""The monitor's harmonic balance (core.monitor.balance.harmonic_balance: pass_samples -> the term library's kernels ->
pass_rows) against a plain-numpy reference written from the physics, not from the kernels:

- motion: the flywheel fit and the node-minus-flywheel harmonics as series by np.fft.irfft (design.md §4 convention);
- torques: np.interp of the pressure at the flywheel angle, gas and reciprocating torques from core.model.torques
  (physics.md §2, §3), the known node sums of physics.md §12.3 item 2, the loss terms from each library term's numpy
  reference on core.model.kinematics samples (core.model.terms), work means as np.mean(T omega_q / Omega);
- chain: harmonics by np.fft.rfft, np.add.at / einsum for the node torques and Z_m^-1, core.model.dynamics.static_twist,
  identify.friction_design and ParameterLayout.cylinder_rows for the rows, dynamics.dissipated_power.

Tolerance: the kernels rotate sin/cos of the throw angle from the flywheel's (addition theorem), multiply where the
reference divides and form the parameter-weighted friction sums before the FFT (linearity), so they agree to
rounding: 1e-9 of each quantity's scale (measured ~1e-13).

Also: a library with a new loss term gives the balance's design a new column without any solver edit.
"""

import numpy as np
import pytest
from frictionwatch.core.model.dynamics import dissipated_power, static_twist
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.terms import cylinder_samples_reference, rezeka_henein
from frictionwatch.core.model.torques import gas_torque, reciprocating_torque
from frictionwatch.core.monitor.balance.excitation import CRANKCASE_PA, Excitation
from frictionwatch.core.monitor.balance.harmonic_balance import harmonic_balance, operating_point
from frictionwatch.core.monitor.identify.parameters import friction_design, parameter_layout
from frictionwatch.core.monitor.monitor import default_max_order
from frictionwatch.core.monitor.teeth.flywheel import FlywheelMotion, harmonic_series, harmonics_of
from numpy.testing import assert_allclose

from tests.core.test_terms import AUX_QUADRATIC

RTOL = 1e-9


def grid_motion_reference(fly, n, theta_start, n_nodes, rel, static):
    m = fly.n_harmonics
    w = fly.freq
    n_rel = 0 if rel is None else n_nodes
    spec_rows = np.zeros((3 + 3 * n_rel, n // 2 + 1), dtype=np.complex128)
    spec_rows[0, 1: m + 1] = fly.harmonics * (0.5 * n)
    spec_rows[1, 1: m + 1] = 1j * w * fly.harmonics * (0.5 * n)
    spec_rows[2, 1: m + 1] = -(w**2) * fly.harmonics * (0.5 * n)
    if n_rel:
        spec_rows[3: 3 + n_rel, 1: m + 1] = rel * (0.5 * n)
        spec_rows[3 + n_rel: 3 + 2 * n_rel, 1: m + 1] = 1j * w * rel * (0.5 * n)
        spec_rows[3 + 2 * n_rel:, 1: m + 1] = -(w**2) * rel * (0.5 * n)
    series = np.fft.irfft(spec_rows, n=n, axis=-1)
    tau = np.arange(n) * (fly.period / n)
    u = tau / fly.period
    theta_f = theta_start + fly.omega_mean * tau + fly.offset + fly.drift * u * (u - 1.0) + series[0]
    omega_f = fly.omega_mean + fly.drift * (2.0 * u - 1.0) / fly.period + series[1]
    alpha_f = 2.0 * fly.drift / fly.period**2 + series[2]
    motion = np.empty((3, n_nodes, n))
    motion[0] = theta_f + (series[3: 3 + n_rel] if n_rel else 0.0)
    motion[1] = omega_f + (series[3 + n_rel: 3 + 2 * n_rel] if n_rel else 0.0)
    motion[2] = alpha_f + (series[3 + 2 * n_rel:] if n_rel else 0.0)
    if static is not None:
        motion[0] += static[:, None]
    return tau, theta_f, omega_f, alpha_f, motion


def torques_reference(spec, library, motion, theta_f, grid, pressure, j_rec, var_inertia, omega_mean):
    """Known node torques (N, n), basis (z, L, n), gas (z, n), basis work means (z, L), indicated (z,)."""
    n_nodes, n = motion.shape[1:]
    z = spec.n_cyl
    kin, fric = spec.kinematics_params(), spec.friction_params()
    node = spec.cylinder_node
    x = np.mod(theta_f - grid[0], 4 * np.pi)
    p_abs = np.stack([np.interp(x, np.append(grid - grid[0], 4 * np.pi), np.append(pk, pk[0])) for pk in pressure])
    gas = np.empty((z, n))
    known = np.zeros((n_nodes, n))
    for q in np.unique(node):
        cyl = np.flatnonzero(node == q)
        ph = spec.firing_angles[cyl]
        gas[cyl] = gas_torque(motion[0, q], p_abs[cyl], ph, kin, spec.piston_area, CRANKCASE_PA)
        known[q] = gas[cyl].sum(axis=0)
        if var_inertia:
            t_a = reciprocating_torque(motion[0, q], motion[1, q], motion[2, q], ph, kin, spec.reciprocating_mass)
            known[q] += j_rec * cyl.size * motion[2, q] - t_a.sum(axis=0)
    basis = np.stack([library.evaluate_reference(cylinder_samples_reference(
        motion[0, node[k]] - spec.firing_angles[k], motion[1, node[k]], p_abs[k] - CRANKCASE_PA, fric), fric)
        for k in range(z)])
    w_over = motion[1, node] / omega_mean
    return known, basis, gas, np.mean(basis * w_over[:, None, :], axis=-1), np.mean(gas * w_over, axis=-1)


def harmonic_balance_reference(spec, layout, op, theta, n_nuisance, rel, static, grid, pressure, fly, theta_start,
                               passes, n_time):
    n_nodes = spec.n_nodes
    coef = layout.coefficients(theta[: layout.n_params])
    m = fly.n_harmonics
    n_pass = max(1, passes - 1) if rel is not None and static is not None else max(1, passes)
    for _ in range(n_pass):
        tau, theta_f, omega_f, alpha_f, motion = grid_motion_reference(
            fly, n_time, theta_start, n_nodes, rel if n_nodes > 1 else None, static if n_nodes > 1 else None)
        known, basis, gas, basis_mean, ind_mean = torques_reference(
            spec, layout.library, motion, theta_f, grid, pressure, op.shaft.recip_inertia_mean, op.variable_inertia,
            fly.omega_mean)
        known_harm, basis_harm = harmonics_of(known, m), harmonics_of(basis, m)
        mean_torque = np.zeros(n_nodes)
        np.add.at(mean_torque, spec.cylinder_node, ind_mean - (coef * basis_mean).sum(axis=1))
        static = static_twist(op.shaft, mean_torque)
        torque = known_harm.copy()
        np.add.at(torque, spec.cylinder_node, -np.einsum("kl,klm->km", coef, basis_harm))
        phi = np.einsum("mij,jm->im", op.receptance.inverse, torque)
        rel = phi - phi[op.shaft.flywheel]
    node_speed = 1j * op.receptance.freq[None, :] * phi
    design = friction_design(layout, op.transfer, basis_harm, spec.cylinder_node)
    if n_nuisance:
        design = np.hstack([design, 1j * fly.freq[:, None] * fly.pattern_harmonics[:, :n_nuisance]])
    cyl_rows = layout.cylinder_rows(basis_mean)
    exc = dict(tau=tau, theta_fly=theta_f, omega_node=motion[1], gas=gas, known_harm=known_harm, basis=basis,
               basis_mean=basis_mean, indicated_mean=ind_mean, omega_fly=omega_f, alpha_fly=alpha_f)
    rows = dict(design=design, target=fly.speed_harmonics - np.einsum("mq,qm->m", op.transfer, known_harm),
                mean_row=np.concatenate([cyl_rows.sum(axis=0), np.zeros(n_nuisance)]), cylinder_rows=cyl_rows)
    return exc, rows, node_speed, rel, static


def cycle_inputs(name, seed, library=None, var_inertia=True, n_grid=720):
    """Seeded inputs of one cycle at the engine's real sizes (Wiebe-like pressure bumps at each firing angle)."""
    spec = load_engine(name)
    rng = np.random.default_rng(seed)
    layout = parameter_layout(spec, library=library)
    m = round(2 * default_max_order(spec))
    n_nuis = 2 * (m // 2)
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
    op = operating_point(spec, None, omega, rng.uniform(100.0, 1000.0), m, 0.005, var_inertia, layout)
    n = spec.n_nodes
    rel = (rng.normal(0, 3e-3, (n, m)) + 1j * rng.normal(0, 3e-3, (n, m))) / np.arange(1, m + 1)
    rel[spec.flywheel_node] = 0.0
    static = rng.normal(0, 5e-3, n)
    static[spec.flywheel_node] = 0.0
    theta = np.concatenate([rng.uniform(0.5, 1.5, layout.n_params), rng.normal(0, 1e-3, n_nuis)])
    return spec, layout, op, theta, n_nuis, rel, static, grid, pressure, fly, rng.uniform(-1.0, 1.0)


def close(got, ref, what):
    got, ref = np.asarray(got), np.asarray(ref)
    assert got.shape == ref.shape, what
    assert_allclose(got, ref, rtol=0, atol=RTOL * max(float(np.abs(ref).max()), 1e-300), err_msg=what)


@pytest.mark.parametrize("name", ["genset-v20", "k9k-4cyl", "deutz-1cyl"])
@pytest.mark.parametrize("seed,warm,time_samples,var_inertia", [(0, True, 256, True), (1, False, 192, True),
                                                                (2, True, 512, False)])
def test_harmonic_balance_matches_numpy_reference(name, seed, warm, time_samples, var_inertia):
    spec, layout, op, theta, n_nuis, rel, static, grid, pressure, fly, theta_start = cycle_inputs(
        name, seed, var_inertia=var_inertia)
    if not warm:
        rel, static = None, None
    got = harmonic_balance(op, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, 2, time_samples)
    r_exc, r_rows, r_speed, r_rel, r_static = harmonic_balance_reference(
        spec, layout, op, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, 2, time_samples)
    assert isinstance(got.excitation, Excitation)
    for field, ref in r_exc.items():
        value = getattr(got.excitation, field)
        if field in ("basis", "basis_mean"):
            for term in range(len(layout.library)):  # each friction term on its own scale
                close(value[:, term], ref[:, term], f"{field}[{term}]")
        else:
            close(value, ref, field)
    close(got.excitation.basis_harm, harmonics_of(r_exc["basis"], fly.n_harmonics), "basis_harm")
    for c in range(r_rows["design"].shape[1]):
        close(got.rows.design[:, c], r_rows["design"][:, c], f"design[:, {c}]")
    for field in ("target", "mean_row", "cylinder_rows"):
        close(getattr(got.rows, field), r_rows[field], field)
    assert np.isnan(got.rows.mean_target)
    close(got.node_speed, r_speed, "node_speed")
    close(got.relative_motion, r_rel, "relative_motion")
    close(got.static, r_static, "static")
    # the dissipation formed in the kernel is dissipated_power of the node speeds it returns (same sums)
    assert_allclose((got.power_relative, got.power_ground), dissipated_power(op.shaft, got.node_speed), rtol=1e-12)


@pytest.mark.parametrize("name", ["genset-v20", "deutz-1cyl"])
def test_a_new_loss_term_gains_its_design_column(name):
    """A seventh term (omega^2 auxiliaries, group "engine") added to the library: the layout gives it one engine-wide
    parameter, the balance's design one more column, equal to the reference's; the other columns do not change."""
    spec = load_engine(name)
    lib = rezeka_henein(spec.friction.coefficients) + AUX_QUADRATIC
    prior = np.append(spec.friction.coefficients, 2e-6)  # a commissioning value for the new term [N m s^2]
    base = cycle_inputs(name, 5)
    spec, layout, op, theta, n_nuis, rel, static, grid, pressure, fly, theta_start = cycle_inputs(name, 5, lib)
    layout = parameter_layout(spec, library=lib, prior=prior)
    op = operating_point(spec, None, op.omega_mean, op.load_torque, fly.n_harmonics, 0.005, True, layout)
    assert layout.n_params == base[1].n_params + (spec.n_cyl if spec.n_cyl == 1 else 1)
    assert layout.names[-1] == ("cyl1:F7" if spec.n_cyl == 1 else "all:F7")
    theta = np.concatenate([np.ones(layout.n_params), np.zeros(n_nuis)])
    got = harmonic_balance(op, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, 2, 256)
    _, r_rows, *_ = harmonic_balance_reference(spec, layout, op, theta, n_nuis, rel, static, grid, pressure, fly,
                                               theta_start, 2, 256)
    assert got.rows.design.shape[1] == layout.n_params + n_nuis
    new = layout.n_params - 1
    assert np.abs(got.rows.design[:, new]).max() > 0
    close(got.rows.design[:, new], r_rows["design"][:, new], "new term's column")
    # the new term's basis is omega^2 of each throw
    close(got.excitation.basis[:, -1], np.maximum(got.excitation.omega_node[spec.cylinder_node], 1e-3) ** 2,
          "omega^2 row")


def test_harmonic_balance_rejects_too_few_samples():
    spec, layout, op, theta, n_nuis, rel, static, grid, pressure, fly, theta_start = cycle_inputs("k9k-4cyl", 8)
    with pytest.raises(ValueError, match="harmonics need more"):
        harmonic_balance(op, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, 2, 2 * fly.n_harmonics)


def harmonic_series_reference(coeffs, n, mean=0.0):
    c = np.asarray(coeffs)
    spec = np.zeros(c.shape[:-1] + (n // 2 + 1,), dtype=np.complex128)
    spec[..., 1: c.shape[-1] + 1] = c * (0.5 * n)
    return np.fft.irfft(spec, n=n, axis=-1) + mean


@pytest.mark.parametrize("shape,n,mean", [((2, 24), 256, 0.0), ((3, 10), 65, 1.5), ((1, 5), 64, -2.0),
                                          ((24,), 256, 0.25), ((2, 3, 4), 32, 0.0)])
def test_harmonic_series_kernel_is_the_numpy_formula(shape, n, mean):
    rng = np.random.default_rng(n)
    c = rng.normal(size=shape) + 1j * rng.normal(size=shape)
    got = harmonic_series(c, n, mean)
    ref = harmonic_series_reference(c, n, mean)
    assert got.shape == ref.shape
    assert_allclose(got, ref, rtol=0, atol=1e-14 * np.abs(ref).max())
