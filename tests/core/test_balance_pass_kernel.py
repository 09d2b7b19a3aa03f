"""The one-kernel harmonic-balance pass (core.monitor.balance_pass_kernel._balance_pass behind core.monitor.harmonic_balance.
harmonic_balance) against the step-by-step code it replaced (round 1 of the speed work, kept here as
``harmonic_balance_steps``: excitation_rows of tests/core/excitation_reference.py with numpy's FFTs, then
_mix_plan / _balance_rows).

The kernel runs the same helpers in the same order and rocket-fft runs numpy's pocketfft, so the numbers agree to
the last bits; the bar is 1e-13 of each quantity's scale (the plain-numpy reference of the physics is
tests/core/test_harmonic_balance_fast.py). Seeded inputs of the real sizes (genset-v20: 20 cylinders, 14 nodes,
M = 24, P = 23 + 24 nuisances, 256 samples) and small ones (k9k-4cyl, deutz-1cyl: one node)."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from frictionwatch.core.model.dynamics import dissipated_power
from frictionwatch.core.monitor.flywheel import harmonic_series
from frictionwatch.core.model.friction import N_TERMS
from frictionwatch.core.monitor.harmonic_balance import harmonic_balance
from frictionwatch.core.monitor.harmonic_balance_kernels import _balance_rows, _mix_plan
from tests.core.excitation_reference import excitation_rows
from tests.core.test_harmonic_balance_fast import cycle_inputs

RTOL = 1e-13


def harmonic_balance_steps(spec, layout, theta, n_nuisance, relative_motion, static, grid, pressure, fly, theta_start,
                           op, passes, time_samples, variable_inertia):
    """frictionwatch.core.monitor.harmonic_balance.harmonic_balance as it was before the fused kernel (commit 2dc5ffe)."""
    rel = relative_motion
    n_nodes = spec.n_nodes
    m = fly.n_harmonics
    if rel is not None and rel.shape != (n_nodes, m):
        rel = None
    static = static if static is not None and static.shape == (n_nodes,) else None
    n_pass = max(1, passes - 1) if rel is not None and static is not None else max(1, passes)
    z = spec.n_cyl
    n_par = layout.n_params
    cyl_node = op.plan.cyl_node
    group = np.ascontiguousarray(layout.group, dtype=np.int64)
    prior = np.ascontiguousarray(layout.prior, dtype=np.float64)
    mix_row = np.empty((z, N_TERMS), dtype=np.int64)
    mix_param = np.empty(z * N_TERMS, dtype=np.int64)
    mix_node = np.empty(z * N_TERMS, dtype=np.int64)
    n_mix = _mix_plan(group, prior, cyl_node, n_par, n_nodes, mix_row, mix_param, mix_node)
    th = np.ascontiguousarray(theta[:n_par], dtype=np.float64)
    pattern = np.ascontiguousarray(fly.pattern_harmonics) if n_nuisance else np.zeros((m, 0), dtype=np.complex128)
    known = np.empty((n_nodes, m), dtype=np.complex128)
    design = np.empty((m, n_par + n_nuisance), dtype=np.complex128)
    target = np.empty(m, dtype=np.complex128)
    cyl_rows = np.empty((z, n_par))
    mean_row = np.empty(n_par + n_nuisance)
    for _ in range(n_pass):
        exc, harm = excitation_rows(spec, grid, pressure, fly, theta_start, time_samples,
                                    op.shaft.recip_inertia_mean, rel if n_nodes > 1 else None,
                                    static if n_nodes > 1 else None, variable_inertia, op.plan,
                                    (mix_row, prior, n_mix))
        static = np.empty(n_nodes)
        phi = np.empty((n_nodes, m), dtype=np.complex128)
        rel = np.empty((n_nodes, m), dtype=np.complex128)
        node_speed = np.empty((n_nodes, m), dtype=np.complex128)
        means = np.ascontiguousarray(np.column_stack([exc.basis_mean, exc.indicated_mean]))
        _balance_rows(harm, 2.0 / time_samples, m, n_mix, mix_param, mix_node, th, group, prior, cyl_node, means,
                      op.shaft.compliance, op.shaft.flywheel, op.receptance.inverse, op.receptance.freq, op.transfer,
                      fly.freq, np.ascontiguousarray(fly.harmonics), pattern, n_nuisance, known, static, phi, rel,
                      node_speed, design, target, cyl_rows, mean_row)
    rows = dict(design=design, target=target, mean_row=mean_row, cylinder_rows=cyl_rows)
    return exc, rows, node_speed, rel, static


def close(got, ref, what):
    got, ref = np.asarray(got), np.asarray(ref)
    assert got.shape == ref.shape, what
    assert_allclose(got, ref, rtol=0, atol=RTOL * max(float(np.abs(ref).max()), 1e-300), err_msg=what)


@pytest.mark.parametrize("name", ["genset-v20", "k9k-4cyl", "deutz-1cyl"])
@pytest.mark.parametrize("warm", [True, False])
@pytest.mark.parametrize("variable_inertia", [True, False])
@pytest.mark.parametrize("nuisances", [True, False])
def test_fused_pass_matches_the_steps(name, warm, variable_inertia, nuisances):
    spec, layout, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, op = cycle_inputs(name, 7)
    if not warm:
        rel, static = None, None
    if not nuisances:
        n_nuis = 0
        theta = theta[:layout.n_params]
    args = (spec, layout, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, op, 2, 256, variable_inertia)
    exc, rows, node_speed, rel_new, static_new, power = harmonic_balance(*args)
    r_exc, r_rows, r_speed, r_rel, r_static = harmonic_balance_steps(*args)
    for field in ("tau", "theta_fly", "omega_node", "gas", "known_harm", "basis_mean", "indicated_mean", "omega_fly",
                  "alpha_fly"):
        close(getattr(exc, field), getattr(r_exc, field), field)
    for term in range(N_TERMS):
        close(exc.basis[:, term], r_exc.basis[:, term], f"basis[{term}]")
        close(exc.basis_harm[:, term], r_exc.basis_harm[:, term], f"basis_harm[{term}]")
    assert exc.basis_mean.flags.c_contiguous and exc.indicated_mean.flags.c_contiguous
    for c in range(r_rows["design"].shape[1]):
        close(rows.design[:, c], r_rows["design"][:, c], f"design[:, {c}]")
    for field in ("target", "mean_row", "cylinder_rows"):
        close(getattr(rows, field), r_rows[field], field)
    assert np.isnan(rows.mean_target)
    close(node_speed, r_speed, "node_speed")
    close(rel_new, r_rel, "relative_motion")
    close(static_new, r_static, "static")
    # the dissipation formed in the kernel is dissipated_power of the node speeds it returns, bit for bit
    assert power == dissipated_power(op.shaft, node_speed)


def test_harmonic_balance_rejects_too_few_samples():
    spec, layout, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, op = cycle_inputs("k9k-4cyl", 8)
    with pytest.raises(ValueError, match="harmonics need more"):
        harmonic_balance(spec, layout, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, op, 2,
                         2 * fly.n_harmonics, True)


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
