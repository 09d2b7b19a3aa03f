"""The fused identification step (core.monitor.identify_step: one compiled call from the noise model to both estimates)
against the separate steps of core.monitor.monitor.process_cycle it replaces (copied below as the reference; they also stay
in process_cycle as its fallback). Seeded inputs of the real sizes (genset-v20: P = 47 incl. 24 nuisances, M = 24,
z = 20; k9k-4cyl; deutz-1cyl), built consistent with a positive parameter vector so that both posteriors are
interior (the kernel path); each fallback forced once; the whole monitor on a short simulated log with and without
the fused step. Tolerance: bit-identical (the same kernels with the same inputs)."""

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from numpy.testing import assert_array_equal

import frictionwatch.core.monitor.identify_step as identify_step_module
import frictionwatch.core.monitor.monitor as monitor
from frictionwatch.core.monitor.accumulate import Accumulator, ResidualStats, posterior_from_normal
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.estimate import friction_estimate_leading
from frictionwatch.core.monitor.identify import CycleRows
from frictionwatch.core.monitor.identify_step import identify_step
from frictionwatch.core.monitor.identify_step_kernels import FUSED_BAD_SHAPE, FUSED_OK, FUSED_POSTERIOR
from frictionwatch.core.monitor.monitor import MonitorConfig, initial_state, process_cycle
from frictionwatch.core.monitor.monitor_glue import glue_plan, noise_model_rows, shares_pair
from frictionwatch.core.monitor.posterior_kernels import FALLBACK, NEEDS_BOUND

ENGINES = ("genset-v20", "k9k-4cyl", "deutz-1cyl")


def identify_steps_reference(cfg, spec, state, fly, rows, indicated_mean, pmax, basis_mean, cyl_rows, balance, t_i,
                             drift_var, coupling_loss, lam, g, bal_mean, rpm, prior_normal, plan):
    """The separate steps of process_cycle (commit before session 5), copied; returns what identify_step returns."""
    stats, a, y, inv_sigma, sys_var, freq, drift_col = noise_model_rows(cfg, spec, state, fly, rows, balance, t_i,
                                                                        drift_var, coupling_loss)
    terms = state.accumulator.cycle_terms(a, y, inv_sigma, 1)
    acc = state.accumulator.fold(terms, lam) if state.cycles >= cfg.warmup_cycles else state.accumulator
    ind_mean, fric_s, fric_c, fire, n_fire, n_s, r_s, n_c, r_c = shares_pair(
        spec, state, prior_normal, rows.cylinder_rows, indicated_mean, pmax, g, bal_mean,
        balance if np.isfinite(balance) else bal_mean, rpm, plan[1], cfg.share_spread)
    lower = plan[2]
    post_s = posterior_from_normal(acc, n_s, r_s, sys_var, lower)
    one = Accumulator(info=terms.info, rhs=terms.rhs, yty=terms.yty, weight=1.0, rows=terms.rows,
                      sys_map=terms.sys_map, info_reference=terms.info_reference)
    post_c = posterior_from_normal(one, n_c, r_c, sys_var, lower)
    layout = state.layout
    est_s = friction_estimate_leading(spec, layout, post_s, basis_mean, fric_s, cfg.resolve_rel,
                                      cfg.coefficient_snr, cfg.min_data_gain, cyl_rows, plan[3])
    est_c = friction_estimate_leading(spec, layout, post_c, basis_mean, fric_c, cfg.resolve_rel,
                                      cfg.coefficient_snr, cfg.min_data_gain, cyl_rows, plan[3])
    return stats, acc, post_s, ind_mean, fire, n_fire, freq, drift_col, est_s, est_c


def assert_identical(got, ref, path="out"):
    """Equal values, dtypes and shapes, bit for bit (NaN where NaN), through dataclasses and tuples."""
    if dataclasses.is_dataclass(ref):
        assert type(got) is type(ref), path
        for f in dataclasses.fields(ref):
            assert_identical(getattr(got, f.name), getattr(ref, f.name), f"{path}.{f.name}")
    elif isinstance(ref, tuple):
        assert isinstance(got, tuple) and len(got) == len(ref), path
        for i, (u, v) in enumerate(zip(got, ref)):
            assert_identical(u, v, f"{path}[{i}]")
    elif isinstance(ref, np.ndarray):
        assert isinstance(got, np.ndarray) and got.dtype == ref.dtype and got.shape == ref.shape, path
        assert_array_equal(got, ref, err_msg=path, strict=True)
    elif isinstance(ref, float):
        assert isinstance(got, float) and (got == ref or (np.isnan(got) and np.isnan(ref))), (path, got, ref)
    else:
        assert type(got) is type(ref) and got == ref, (path, got, ref)


def _spd(rng, p, scale=1.0):
    a = rng.normal(size=(p, p))
    return scale * (a @ a.T + p * np.eye(p))


def seeded_inputs(name, case="steady", seed=7):
    """identify_step's arguments for one engine, consistent with theta0 (friction scales 0.5..1.5 > 0): the
    accumulated equations, this cycle's rows and the prior all point at it, so both posteriors are interior."""
    rng = np.random.default_rng(seed)
    spec = load_engine(name)
    cfg = MonitorConfig(drift_nuisance=case != "no_drift")
    state = initial_state(spec, cfg)
    m, z = state.n_harmonics, spec.n_cyl
    p_f = state.layout.n_params
    p = p_f + state.n_nuisance
    r = 2 * m + 1
    theta0 = np.concatenate([rng.uniform(0.5, 1.5, p_f), rng.normal(0.0, 0.3, state.n_nuisance)])
    design = rng.normal(size=(m, p)) + 1j * rng.normal(size=(m, p))
    target = design @ theta0 + 1e-3 * (rng.normal(size=m) + 1j * rng.normal(size=m))
    mean_row = rng.uniform(5.0, 20.0, p_f)
    mean_row = np.concatenate([mean_row, np.zeros(state.n_nuisance)])
    basis_mean = rng.uniform(0.1, 3.0, (z, 6))
    cyl_rows = np.ascontiguousarray(state.layout.cylinder_rows(basis_mean)[:, :p_f])
    rows = CycleRows(design=design, target=target, mean_row=mean_row, mean_target=0.0, cylinder_rows=cyl_rows)
    a_hist = rng.normal(size=(6 * p, p)) * 30.0
    y_hist = a_hist @ theta0 + 0.1 * rng.normal(size=6 * p)
    ref_row = mean_row / 2.0
    cycles = {"first": 0, "warmup": 5}.get(case, 57)
    acc = Accumulator(info=a_hist.T @ a_hist, rhs=a_hist.T @ y_hist, yty=float(y_hist @ y_hist), weight=40.0,
                      rows=40.0 * r, sys_map=np.ascontiguousarray(rng.normal(size=(p, r)) * 3.0),
                      info_reference=40.0 * np.outer(ref_row, ref_row))
    if case == "first":
        acc = Accumulator.empty(p, r)
    stats = ResidualStats(mean=0.01 * (rng.normal(size=m) + 1j * rng.normal(size=m)), var=rng.uniform(1e-4, 1e-3, m),
                          balance_mean=0.3, balance_var=2.0, count=cycles)
    indicated = rng.uniform(50.0, 150.0, z)
    if case == "misfire" and z > 1:
        indicated[z // 2] = -3.0
    state = dataclasses.replace(state, accumulator=acc, stats=stats, theta=theta0 + 0.01 * rng.normal(size=p),
                                cycles=cycles, indicated_mean=np.full(z, np.nan) if case == "first"
                                else rng.uniform(50.0, 150.0, z))
    n_base = _spd(rng, p, 0.05)
    prior_normal = ((1.0, 0.05, 0.15), n_base, n_base @ theta0)
    plan = glue_plan(spec, state)
    fly = SimpleNamespace(harmonics=1e-3 * (rng.normal(size=m) + 1j * rng.normal(size=m)), omega_mean=157.3,
                          pattern_harmonics=1e-4 * (rng.normal(size=(m, 3)) + 1j * rng.normal(size=(m, 3))),
                          residual_rms=1.3e-5, n_edges=317, period=0.08)
    fly.freq = 0.5 * fly.omega_mean * np.arange(1, m + 1)
    balance = float("nan") if case == "no_load" else float(mean_row @ theta0)
    total = float(cyl_rows.sum(axis=0) @ theta0[:p_f])
    args = dict(cfg=cfg, spec=spec, state=state, fly=fly, rows=rows, indicated_mean=indicated,
                pmax=rng.uniform(30e5, 150e5, z), basis_mean=basis_mean, cyl_rows=cyl_rows, balance=balance,
                t_i=float(indicated.sum()), drift_var=0.0 if case == "no_drift_var" else 0.04, coupling_loss=1.7,
                lam=1.0 - 1.0 / 400.0, g=0.01, bal_mean=total, rpm=1512.0, prior_normal=prior_normal, plan=plan)
    return args


@pytest.fixture
def statuses(monkeypatch):
    """The kernel's status of every identify_step call."""
    seen = []
    kernel = identify_step_module.identify_step_kernel

    def recording(*a):
        out = kernel(*a)
        seen.append(out[0])
        return out

    monkeypatch.setattr(identify_step_module, "identify_step_kernel", recording)
    return seen


@pytest.mark.parametrize("name", ENGINES)
@pytest.mark.parametrize("case", ["steady", "warmup", "first", "no_load", "no_drift", "no_drift_var", "misfire"])
def test_fused_step_is_the_separate_steps(name, case, statuses):
    args = seeded_inputs(name, case)
    ref = identify_steps_reference(**args)
    got = identify_step(**args)
    assert statuses == [FUSED_OK]
    assert got is not None
    assert_identical(got, ref)
    # the inputs are not written (the state goes on unchanged when a later step rejects the cycle)
    again = seeded_inputs(name, case)
    assert_identical(args["state"], again["state"])
    assert_identical(args["prior_normal"], again["prior_normal"])


@pytest.mark.parametrize("name", ENGINES)
def test_fused_outputs_are_fresh_arrays(name):
    """Two calls on the same inputs share no output array (the results of consecutive cycles stay independent)."""
    args = seeded_inputs(name)
    one, two = identify_step(**args), identify_step(**args)
    assert_identical(one, two)
    assert not np.shares_memory(one[1].info, two[1].info)
    assert not np.shares_memory(one[8].coefficients, two[8].coefficients)
    assert not np.shares_memory(one[2].theta, args["state"].theta)


def test_active_bound_goes_the_separate_steps(statuses):
    """A friction scale pushed below 0 by the data: NNLS decides (NEEDS_BOUND), identify_step declines."""
    args = seeded_inputs("k9k-4cyl")
    acc = args["state"].accumulator
    p_f = args["state"].layout.n_params
    push = np.zeros(acc.rhs.shape)
    push[0] = -50.0 * acc.info[0, 0]
    args["state"] = dataclasses.replace(args["state"], accumulator=dataclasses.replace(acc, rhs=acc.rhs + push))
    assert identify_step(**args) is None
    assert statuses == [FUSED_POSTERIOR + NEEDS_BOUND]
    ref = identify_steps_reference(**args)
    assert ref[2].theta[0] == 0.0 and np.all(ref[2].theta[:p_f] >= 0.0)


def test_near_singular_prior_goes_the_separate_steps(statuses):
    """No accumulated equations (warm-up) and a prior that leaves a direction free: FALLBACK, the reference decides."""
    args = seeded_inputs("deutz-1cyl", "warmup")
    p = args["state"].accumulator.info.shape[0]
    args["state"] = dataclasses.replace(args["state"], accumulator=Accumulator.empty(p, args["state"].accumulator
                                                                                     .sys_map.shape[1]))
    _, n_base, r_base = args["prior_normal"]
    n_sing = n_base.copy()
    n_sing[-1, :] = 0.0
    n_sing[:, -1] = 0.0
    n_sing[-1, -1] = 1e-14 * n_base[-1, -1]
    args["prior_normal"] = (args["prior_normal"][0], n_sing, r_base)
    assert identify_step(**args) is None
    assert statuses == [FUSED_POSTERIOR + FALLBACK]


def test_other_harmonic_count_and_bad_inputs_go_the_separate_steps(statuses):
    # a tooth fit of another order: the general noise path, not even tried
    args = seeded_inputs("genset-v20")
    m = args["state"].n_harmonics
    fly = args["fly"]
    args["fly"] = SimpleNamespace(**{**vars(fly), "harmonics": np.resize(fly.harmonics, m + 2),
                                     "freq": 0.5 * fly.omega_mean * np.arange(1, m + 3)})
    assert identify_step(**args) is None and statuses == []
    # another layout (Fortran-ordered design): the separate steps convert
    args = seeded_inputs("genset-v20")
    args["rows"] = dataclasses.replace(args["rows"], design=np.asfortranarray(args["rows"].design))
    assert identify_step(**args) is None and statuses == []
    assert_identical(identify_steps_reference(**args), identify_step(**seeded_inputs("genset-v20")))
    statuses.clear()
    # rows that do not fit the accumulator: the separate steps raise their ValueError
    args = seeded_inputs("k9k-4cyl")
    rows = args["rows"]
    args["rows"] = dataclasses.replace(rows, design=np.ascontiguousarray(rows.design[:, :-1]),
                                       mean_row=np.ascontiguousarray(rows.mean_row[:-1]))
    args["state"] = dataclasses.replace(args["state"], theta=np.ascontiguousarray(args["state"].theta[:-1]))
    assert identify_step(**args) is None and statuses == [FUSED_BAD_SHAPE]
    with pytest.raises(ValueError, match="rows must have shape"):
        identify_steps_reference(**args)
    # a forgetting factor outside [0, 1]: fold's ValueError
    args = seeded_inputs("k9k-4cyl")
    args["lam"] = 1.5
    assert identify_step(**args) is None
    with pytest.raises(ValueError, match="forgetting factor"):
        identify_steps_reference(**args)


def _simulated_log(spec, n):
    from frictionwatch.core.plant.simulate import simulate
    from frictionwatch.drivers.assembly.cycles import CycleAssembler

    sim = simulate(spec, 1400.0, 0.5, n, seed=3)
    asm = CycleAssembler(sim.info, spec.n_cyl, spec.firing_angles, speed_range_rpm=spec.speed_range_rpm)
    return [c for r in sim.records for c in asm.feed(r)] + asm.flush()


def test_monitor_with_and_without_the_fused_step_is_the_same(monkeypatch):
    """process_cycle on a short simulated K9K log (warm-up 3 cycles, so the fold runs): every result and state
    field equal, and the fused step taken on nearly every cycle."""
    spec = load_engine("k9k-4cyl")
    cycles = _simulated_log(spec, 10)
    cfg = MonitorConfig(warmup_cycles=3)
    calls = []

    def counting(*a):
        out = identify_step(*a)
        calls.append(out is not None)
        return out

    runs = []
    for fused in (counting, lambda *a: None):
        monkeypatch.setattr(monitor, "identify_step", fused)
        state, results = initial_state(spec, cfg), []
        for c in cycles:
            state, res = process_cycle(spec, state, c, cfg)
            results.append(res)
        runs.append((state, results))
    # the fused step on all but the first cycle, whose own posterior has an active bound (NNLS: the separate steps)
    assert len(calls) == len(cycles) >= 8 and sum(calls) >= len(cycles) - 2
    assert_identical(runs[0][0], runs[1][0], "state")
    for k, (a, b) in enumerate(zip(runs[0][1], runs[1][1])):
        assert_identical(a, b, f"cycle {k}")
