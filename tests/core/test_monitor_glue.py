"""The glue of core.monitor.monitor.process_cycle between the harmonic balance and the posteriors (round 3: one kernel for
the Eq. 6 shares of both estimates, the noise-model inputs formed in the kernel, cheaper frozen constructors)
against the separate steps it replaces, which stay in the code as the general path. Seeded inputs of the real
sizes (genset-v20: P = 47 incl. 24 nuisances, M = 24, z = 20) and small ones (1 and 4 cylinders). Tolerance:
bit-identical (the same operations in the same order)."""

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from frictionwatch.core.monitor.accumulate import Accumulator, ResidualStats
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.frozen_init import fast_constructor
from frictionwatch.core.monitor.identify import parameter_layout
from frictionwatch.core.monitor.monitor import MonitorState, initial_state
from frictionwatch.core.monitor.monitor_glue import freq_times_1j, glue_plan, shares_pair
from frictionwatch.core.monitor.monitor_kernels import firing_into, noise_rows, noise_rows_cycle, share_normal_into
from frictionwatch.core.model.pairwise import pairwise_sum
from frictionwatch.core.monitor.results import CycleResult, FrictionEstimate
from frictionwatch.core.monitor.sharing import motored_friction_per_cylinder, share_mean_loss

SIZES = (("genset-v20", 24), ("k9k-4cyl", 16), ("deutz-1cyl", 12))


def shares_pair_reference(state, prior_normal, rows, t_i, pmax, g, total_s, total_c, rpm, spec, spread):
    """The steps of process_cycle before round 3 (commit b138ac8), copied."""
    z = spec.n_cyl
    ind_mean = t_i.copy() if state.cycles == 0 else state.indicated_mean + g * (t_i - state.indicated_mean)
    fire = np.empty(z, dtype=np.bool_)
    n_fire = firing_into(t_i, 0.15, fire)
    pmax_motored = 0.0
    if n_fire < z:
        pmax_motored = pairwise_sum(np.ascontiguousarray(pmax[~fire]), 0, z - n_fire) / (z - n_fire)
    motored = motored_friction_per_cylinder(spec, rpm, pmax_motored)
    out = []
    for total, t in ((total_s, ind_mean), (total_c, t_i)):
        share = share_mean_loss(total, t, motored, spread)
        _, n_base, r_base = prior_normal
        n_out, r_out = np.empty(n_base.shape), np.empty(r_base.shape)
        if not share_normal_into(n_base, r_base, rows, share.friction_mean, share.sigma, n_out, r_out):
            n_out, r_out = n_base, r_base
        out.append((share, n_out, r_out))
    (sh_s, n_s, r_s), (sh_c, n_c, r_c) = out
    assert_array_equal(sh_c.motored, ~fire)
    return ind_mean, sh_s.friction_mean, sh_c.friction_mean, fire, n_fire, n_s, r_s, n_c, r_c


def _spd(rng, p):
    a = rng.normal(size=(p, p))
    return a @ a.T + p * np.eye(p)


@pytest.mark.parametrize("name,m", SIZES)
@pytest.mark.parametrize("case", ["steady", "first", "misfire", "none_fire", "no_total"])
def test_shares_pair_kernel_is_the_separate_steps(name, m, case):
    spec = load_engine(name)
    state = initial_state(spec)
    z = spec.n_cyl
    rng = np.random.default_rng(11)
    p = state.layout.n_params + state.n_nuisance
    cycles = 0 if case == "first" else 57
    state = dataclasses.replace(state, cycles=cycles, indicated_mean=rng.uniform(50.0, 150.0, z))
    n_base, r_base = _spd(rng, p), rng.normal(size=p)
    prior_normal = ((1.0, 0.05, 0.15), n_base, r_base)
    rows = state.layout.cylinder_rows(rng.uniform(0.1, 3.0, (z, 6)))
    t_i = rng.uniform(50.0, 150.0, z)
    if case == "misfire":
        t_i[z // 2] = rng.uniform(-5.0, 2.0)  # the middle cylinder does not fire
    if case == "none_fire":
        t_i[:] = -1.0
    pmax = rng.uniform(30e5, 150e5, z)
    totals = (float("nan"), 40.0) if case == "no_total" else (61.0, 58.5)
    plan = glue_plan(spec, state)
    assert plan[1][1] == spec.displacement_cyl
    args = (spec, state, prior_normal, rows, t_i, pmax, 0.01, *totals, 1512.0, plan[1], 0.3)
    got = shares_pair(*args)
    ref = shares_pair_reference(state, prior_normal, rows, t_i, pmax, 0.01, *totals, 1512.0, spec, 0.3)
    assert got[4] == ref[4]  # firing count
    for g, r, what in zip(got, ref, ("ind_mean", "share_s", "share_c", "fire", "n_fire", "N_s", "r_s", "N_c", "r_c")):
        assert_array_equal(g, r, err_msg=what)
    # the general path (non-contiguous rows: the separate steps, the prior rows through BLAS)
    wide = np.zeros((z, rows.shape[1] + 3))
    wide[:, :rows.shape[1]] = rows
    gen = shares_pair(spec, state, prior_normal, wide[:, :rows.shape[1]], *args[4:])
    for g, r, what in zip(gen, got, ("ind_mean", "share_s", "share_c", "fire", "n_fire", "N_s", "r_s", "N_c", "r_c")):
        assert_allclose(g, r, rtol=1e-12, atol=1e-12 * np.abs(r).max(), err_msg=what)
    if case == "misfire":
        assert not got[3][z // 2] and got[4] == z - 1 or z == 1
    # the kernel's motored friction is core.monitor.sharing's (a motored cylinder's share is it)
    if case == "misfire" and z > 1:
        pm = pmax[~got[3]].mean()
        assert got[2][z // 2] == motored_friction_per_cylinder(spec, 1512.0, pm)


@pytest.mark.parametrize("name,m", SIZES)
@pytest.mark.parametrize("case", ["steady", "first", "no_load", "no_drift"])
def test_noise_rows_cycle_is_noise_rows_with_numpy_inputs(name, m, case):
    spec = load_engine(name)
    rng = np.random.default_rng(5)
    layout = parameter_layout(spec)
    p = layout.n_params + 2 * (m // 2)
    design = rng.normal(size=(m, p)) + 1j * rng.normal(size=(m, p))
    target = rng.normal(size=m) + 1j * rng.normal(size=m)
    theta = rng.uniform(0.5, 1.5, p)
    omega = 157.3
    drift_harm = 1e-4 * (rng.normal(size=m) + 1j * rng.normal(size=m))
    harmonics = 1e-3 * (rng.normal(size=m) + 1j * rng.normal(size=m))
    count = 0 if case == "first" else 37
    st = ResidualStats(mean=0.01 * (rng.normal(size=m) + 1j * rng.normal(size=m)), var=rng.uniform(1e-4, 1e-3, m),
                       balance_mean=0.3, balance_var=2.0, count=count)
    balance = float("nan") if case == "no_load" else 55.0
    use_drift = case != "no_drift"
    rms, n_edges = 1.3e-5, 317
    mean_row = rng.normal(size=p)
    # reference: the numpy inputs of the code before (FlywheelMotion.freq, the floor, the drift column)
    freq = 0.5 * omega * np.arange(1, m + 1)
    floor = freq**2 * 2.0 * rms**2 / n_edges + 1e-12
    outs_ref = (np.empty(m, complex), np.empty(m), np.empty(3), np.empty((2 * m + 1, p)), np.empty(2 * m + 1),
                np.empty(2 * m + 1), np.empty(2 * m + 1))
    noise_rows(design, target, theta, freq, drift_harm, use_drift, st.mean, st.var,
               np.array([st.balance_mean, st.balance_var, st.count], float), 0.99, balance, mean_row, floor, 600.0,
               0.04, 0.08, harmonics, 0.003, 7.5, *outs_ref)
    outs = tuple(np.empty_like(o) for o in outs_ref)
    freq_out = np.empty(m)
    drift_col = np.empty(m, complex)
    noise_rows_cycle(design, target, theta, omega, drift_harm, use_drift, st.mean, st.var, st.balance_mean,
                     st.balance_var, float(st.count), 0.99, balance, mean_row, rms, float(n_edges), 600.0, 0.04, 0.08,
                     harmonics, 0.003, 7.5, freq_out, drift_col, *outs)
    assert_array_equal(freq_out, freq)
    assert_array_equal(drift_col, freq_times_1j(freq, drift_harm))
    for g, r in zip(outs, outs_ref):
        assert_array_equal(g, r)


@pytest.mark.parametrize("cls", [FrictionEstimate, CycleResult, MonitorState, ResidualStats, Accumulator])
def test_fast_constructor_is_the_dataclass(cls):
    make = fast_constructor(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    values = {n: np.arange(3.0) + i for i, n in enumerate(names)}
    a, b = make(**values), cls(**values)
    assert type(a) is cls and repr(a) == repr(b)
    for n in names:
        assert getattr(a, n) is values[n]
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(a, names[0], 1.0)
    with pytest.raises(TypeError):  # a forgotten field is an error, not a missing attribute
        make(**{n: values[n] for n in names[1:]})


def test_fast_constructor_refuses_post_init():
    @dataclasses.dataclass(frozen=True)
    class Checked:
        x: float

        def __post_init__(self):
            pass

    with pytest.raises(TypeError):
        fast_constructor(Checked)
