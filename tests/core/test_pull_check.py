"""The pull check (core.monitor.identify.pull_check, design note 42): its distance's null variance, when it fires and
when it must not, and what it does to a reported estimate."""

from __future__ import annotations

import copy
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine, spec_from_toml_text
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from frictionwatch.core.monitor.identify.posterior import Posterior
from frictionwatch.core.monitor.identify.pull_check import (
    DataPull,
    PullCheck,
    data_only_pull,
    pull_sigma,
    pull_sigma_kernel,
    pull_sigma_of_info_kernel,
    pull_sigma_reference,
    with_pull,
)
from frictionwatch.core.monitor.identify.spd import spd_inverse_lower
from frictionwatch.core.monitor.pipeline import CyclePipeline
from frictionwatch.core.monitor.report.results import FrictionEstimate
from frictionwatch.drivers.logs.mcap_log import LogReader
from frictionwatch.service.pipeline import assembled_cycles
from numpy.testing import assert_allclose

LOGS = Path(__file__).resolve().parents[2] / "replay_logs"


def _system(rng, p=4, n=40):
    a = rng.standard_normal((n, p))
    n_pr = np.diag(np.full(p, 2.0))  # a prior of sigma 0.7 per parameter
    return a, n_pr


def _posterior(acc: Accumulator, n_pr, r_pr) -> Posterior:
    cov = np.linalg.inv(acc.info + n_pr)
    return Posterior(params=cov @ (acc.rhs + r_pr), covariance=cov, cov_statistical=cov, chi2_reduced=1.0,
                     weight=acc.weight, cov_reference=np.linalg.inv(n_pr))


def _acc(a, y) -> Accumulator:
    p = a.shape[1]
    return Accumulator(info=a.T @ a, rhs=a.T @ y, yty=float(y @ y), weight=float(a.shape[0]), rows=float(a.shape[0]),
                       sys_map=a.T.copy(), info_reference=np.zeros((p, p)))


def test_distance_variance_is_data_only_less_posterior():
    """Where the equations and the prior hold, d / sqrt(v) has unit variance: v = c (N^-1 - (N + N_pr)^-1) c^T is
    the variance of the data-only point's distance from the posterior (2,000 draws: the sample mean of d^2 / v
    within 0.1 of 1, its standard error ~0.03)."""
    rng = np.random.default_rng(5)
    a, n_pr = _system(rng)
    rows = rng.standard_normal((3, a.shape[1]))
    ratios = []
    for _ in range(2000):
        truth = rng.standard_normal(a.shape[1]) / np.sqrt(2.0)  # drawn from the prior (mean 0, precision n_pr)
        acc = _acc(a, a @ truth + rng.standard_normal(a.shape[0]))
        post = _posterior(acc, n_pr, np.zeros(a.shape[1]))
        pull = data_only_pull(acc, post, rows, share=np.zeros(3))
        ratios.append(pull.d ** 2 / pull.v)
    assert_allclose(np.mean(ratios, axis=0), np.ones(3), atol=0.1)


def test_fires_on_a_drawn_figure_and_not_within_kappa():
    """Note 41's cylinder 13 at 2,500 cycles of the base-load log, in % of the truth: the data-only point +150 on
    sigma 21 (the posterior's statistical sigma 4.7), the figure +13.4 from its share. At kappa 2 the pull is
    13.4 x sqrt(136.6^2 - 4 v) / 136.6 (12.78 %); a cylinder whose data-only point lies 1.9 of its scatter away gets
    none."""
    v = 21.0 ** 2 - 4.7 ** 2
    pull = DataPull(d=np.array([150.0 - 13.4, 1.9 * np.sqrt(v)]), v=np.array([v, v]), shift=np.array([13.4, 5.0]))
    sig = pull_sigma(pull, kappa=2.0)
    assert_allclose(sig[0], 13.4 * np.sqrt(136.6 ** 2 - 4.0 * v) / 136.6, rtol=1e-12)
    assert_allclose(sig[0], 12.78, atol=0.01)
    assert sig[1] == 0.0
    # a larger kappa asks more before it fires; the pull never exceeds the figure's own move from its share
    assert pull_sigma(pull, kappa=7.0)[0] == 0.0
    assert_allclose(pull_sigma(DataPull(np.array([1e6]), np.array([1.0]), np.array([3.0])), 2.0), [3.0], rtol=1e-5)


def test_a_repeated_error_in_the_equations_fires_it():
    """A small system whose parameter 0 the data barely separate (its column x 0.03: data precision ~3.6 against
    the prior's 2, as a genset cylinder's at one load) with a constant error added to every row's target (a
    repeated model error, 5.0 along that column): the data-only point moves ~6 of its sigmas and the check adds
    sigma to the figure it moved; without the error the same draws give none at kappa 3."""
    rng = np.random.default_rng(11)
    a, n_pr = _system(rng, n=4000)
    a[:, 0] *= 0.03
    rows = np.eye(a.shape[1])[:2]
    truth = np.full(a.shape[1], 1.0)
    noise = rng.standard_normal(a.shape[0])
    r_pr = n_pr @ truth  # a prior centred on the truth (the Eq. 6 share right)
    clean = _acc(a, a @ truth + noise)
    biased = _acc(a, a @ truth + noise + 5.0 * a[:, 0])  # the error projects on parameter 0
    share = rows @ truth
    s_clean = pull_sigma(data_only_pull(clean, _posterior(clean, n_pr, r_pr), rows, share), 3.0)
    p_biased = data_only_pull(biased, _posterior(biased, n_pr, r_pr), rows, share)
    s_biased = pull_sigma(p_biased, 3.0)
    assert_allclose(s_clean, [0.0, 0.0], atol=1e-12)
    assert abs(p_biased.d[0]) > 4.0 * np.sqrt(p_biased.v[0])
    # the figure's error is its whole move (the prior is centred on the truth): the pull covers most of it
    err = p_biased.shift[0]
    assert 0.75 * abs(err) < s_biased[0] <= abs(err)


def _estimate(t, sig, share) -> FrictionEstimate:
    z = t.shape[0]
    return FrictionEstimate(
        friction_torque_mean=t.copy(), friction_torque_mean_sigma=sig.copy(), fmep=t * 1.0, fmep_sigma=sig * 1.0,
        coefficients=np.ones((z, 6)), coefficients_sigma=np.ones((z, 6)), coefficients_normalised=np.ones((z, 6)),
        coefficients_normalised_sigma=np.ones((z, 6)), resolved=np.ones(z, dtype=bool),
        coefficient_resolved=np.ones((z, 6), dtype=bool), total_friction_torque=float(t.sum()),
        total_friction_torque_sigma=1.0, total_fmep=1.0, total_fmep_sigma=1.0, prior_friction_torque_mean=share,
        weight=100.0, chi2_reduced=1.0, data_gain=np.full(z, 0.6), calibration_sigma=np.full(z, 0.5))


def test_with_pull_adds_in_quadrature_and_unmeasures():
    """Figures of 80 N m with sigma 5 N m (0.5 of it the calibration's): a pull of 8 N m takes cylinder 1 to
    sqrt(25 + 64) N m, above 10 % of its figure before the calibration's part: a share (NaN); cylinder 2 without
    pull is unchanged; a zero pull returns the estimate itself."""
    spec = load_engine("maruti-3cyl")
    t, sig = np.array([80.0, 80.0, 80.0]), np.array([5.0, 5.0, 5.0])
    est = _estimate(t, sig, np.full(3, 78.0))
    out = with_pull(est, np.array([8.0, 0.0, 2.0]), 0.10, spec)
    assert_allclose(out.friction_torque_mean_sigma, np.sqrt(sig ** 2 + np.array([64.0, 0.0, 4.0])), rtol=1e-12)
    assert list(out.resolved) == [False, True, True]
    assert np.isnan(out.friction_torque_mean[0]) and out.friction_torque_mean[1] == 80.0
    assert out.total_friction_torque == est.total_friction_torque
    assert with_pull(est, np.zeros(3), 0.10, spec) is est
    # the figure the check made a share says why, apart from a share the data never separated
    from frictionwatch.core.monitor.report.figure_status import friction_status

    assert list(out.pulled) == [True, False, False]
    status = friction_status(out, ())
    assert status.cylinders[0].status == "share" and "pull check" in status.cylinders[0].reason
    unseparated = friction_status(replace(est, resolved=np.array([False, True, True]),
                                                      friction_torque_mean=np.array([np.nan, 80.0, 80.0])), ())
    assert unseparated.cylinders[0].status == "share" and "pull check" not in unseparated.cylinders[0].reason


def test_by_direction_charges_only_the_inconsistent_direction():
    """Four cylinders whose distance covariance has the directions of a 4x4 Hadamard basis (the total, pinned by the
    balance, with no scatter; three others of variance 0.70, 0.80, 0.73): the data-only point 2.8 of its scatter
    off along the pairs' contrast (1+4 against 2+3) only, the posterior moved 0.74 N m on cylinder 2 alone (a worn
    ring the data see). Only the contrast is charged: sigma = |u.shift| e / |u.d| = 0.37 x sqrt(0.73 (2.8^2 -
    2.5^2)) / (2.8 sqrt(0.73)) in that direction, half of it on each cylinder (|u_k| = 1/2): 0.0834 N m each."""
    u = 0.5 * np.array([[1, 1, 1, 1], [1, -1, 1, -1], [1, 1, -1, -1], [1, -1, -1, 1]], dtype=float).T  # columns
    lam = np.array([0.0, 0.70, 0.80, 0.73])
    cov = (u * lam) @ u.T
    d = 2.8 * np.sqrt(0.73) * u[:, 3]
    shift = np.array([0.0, 0.74, 0.0, 0.0])
    sig = pull_sigma(DataPull(d, np.diag(cov), shift, cov), kappa=2.5)
    one = 0.37 * np.sqrt(0.73 * (2.8 ** 2 - 2.5 ** 2)) / (2.8 * np.sqrt(0.73))
    assert_allclose(sig, np.full(4, 0.5 * one), rtol=1e-9)
    assert_allclose(sig[1], 0.0834, atol=5e-4)
    # within kappa along every direction: nothing
    assert_allclose(pull_sigma(DataPull(0.8 * d / 1.4, np.diag(cov), shift, cov), kappa=2.5), np.zeros(4), atol=1e-12)


# --- the kernel (PullCheck.sigma: pull_sigma_kernel after LAPACK's inverse) against its numpy reference ---------------
# rtol 1e-10 of each figure, atol 1e-10 of the largest of the call's figures: a cylinder's pull that is a tiny part of
# the others' carries their rounding (genset-v20 below: 1.3e-12 of the largest at most, 6e-11 of each figure above
# 1e-3 of the largest; bench/bench_pull_check.py)
KAPPAS = (2.5, 1.0, 0.3)  # the tuned one, and smaller ones, so every direction's firing branch is exercised


def _assert_kernel_is_reference(acc, post, rows, share, kappa) -> bool:
    ref = pull_sigma_reference(acc, post, rows, share, kappa)
    got = PullCheck(kappa).sigma(acc, post, rows, share)
    assert got.shape == ref.shape
    # rtol 1e-8: d = c (N^-1 r - theta) carries the last digits of N^-1 (two exact routes to N^-1 move the sigmas by
    # up to 3e-8 of their largest, pull_sigma_kernel's docstring), and the reference's products run in numpy's
    # OpenBLAS, the kernel's in scipy's (numba's BLAS): each picks its kernels by CPU. Here within 1e-10; the
    # CI machine of stop 47 read 2.1e-10 on genset-v20. A share off by 1e-6 of itself fails it.
    assert_allclose(got, ref, rtol=1e-8, atol=1e-8 * float(np.max(ref, initial=0.0)))
    return bool(np.any(ref > 0.0))


@pytest.fixture(scope="module")
def captured():
    """Every PullCheck.sigma call's inputs over the first 40 cycles of the genset-v20 demo log and the k9k-4cyl
    replay log, through the one pipeline (CyclePipeline) with the identification step by its reference (the step's
    kernel makes the pull sigmas without calling PullCheck.sigma, core.monitor.identify.step)."""
    from frictionwatch.core.monitor.identify import identification, step

    original, out = PullCheck.sigma, {}
    fused, identification.identify_step = identification.identify_step, step.identify_step_reference
    try:
        for log_name in ("demo", "k9k-4cyl"):
            calls: list = []

            def recorded(self, acc, post, rows, share, _calls=calls):
                _calls.append(copy.deepcopy((acc, post, np.asarray(rows), np.asarray(share))))
                return original(self, acc, post, rows, share)

            PullCheck.sigma = recorded
            with LogReader(LOGS / f"{log_name}.mcap") as log:
                spec = spec_from_toml_text(log.engine_toml, origin=log_name)
                cycles, _ = assembled_cycles(spec, log.info, log.records())
            pipe = CyclePipeline(spec)
            for c in cycles[:40]:
                pipe.process(c)
            out[spec.name] = calls
    finally:
        PullCheck.sigma = original
        identification.identify_step = fused
    return out


def test_kernel_is_the_reference_on_monitor_inputs(captured):
    """genset-v20 (20 cylinders, 47 parameters) and k9k-4cyl (4, 29): every call with an accumulated weight, at the
    tuned kappa and smaller ones; the pull fires on most of them (counted, so the comparison is of figures, not of
    zeros)."""
    assert set(captured) == {"genset-v20", "k9k-4cyl"}
    for name, calls in captured.items():
        live = [c for c in calls if c[0].weight > 0.0]
        assert len(live) >= 10, name
        fired = sum(_assert_kernel_is_reference(*c, kappa) for c in live for kappa in KAPPAS)
        assert fired >= len(live), (name, fired)


def test_one_dispatch_is_the_two_step_path(captured):
    """PullCheck.sigma's one kernel (the inverse by the numba-bound LAPACK calls, design note 88) against what it
    replaced, scipy's potrf/potri (``spd_inverse_lower``) then ``pull_sigma_kernel``: the same library calls on the
    same matrix, so equal to the last bit but for zeros' signs (a + 0.0); held at rtol 1e-14."""
    for name, calls in captured.items():
        for acc, post, rows, share in [c for c in calls if c[0].weight > 0.0]:
            args = (np.ascontiguousarray(acc.rhs), post.params, float(post.chi2_reduced), post.cov_statistical,
                    np.ascontiguousarray(rows), share, 2.5)
            got = pull_sigma_of_info_kernel(acc.info, *args)
            want = pull_sigma_kernel(spd_inverse_lower(acc.info), *args)
            assert_allclose(got, want, rtol=1e-14, atol=1e-14 * float(np.max(want, initial=0.0)), err_msg=name)


def _random_case(rng, n=12, p=7, z=5, prior=2.0, bias=0.0, twin=False):
    a = rng.standard_normal((60, n)) * rng.uniform(0.05, 3.0, n)  # badly scaled columns, as the monitor's
    truth = rng.uniform(0.5, 2.0, n)
    y = a @ truth + rng.standard_normal(60) + bias * a[:, 0]
    acc = _acc(a, y)
    n_pr = np.diag(np.full(n, prior))
    post = _posterior(acc, n_pr, n_pr @ truth)
    post = replace(post, chi2_reduced=float(rng.uniform(0.5, 2.0)))  # both sides of max(1, chi2)
    rows = rng.standard_normal((z, p))
    if twin:  # two cylinders with one row: a direction of d without scatter (it carries nothing), their shares apart
        rows[1] = rows[0]
    return acc, post, rows, rows @ truth[:p] + rng.normal(0.0, 0.1, z)


def test_kernel_is_the_reference_on_random_cases():
    """200 random systems (12 parameters, 5 cylinders on the leading 7; half with a repeated error along the first
    parameter, so the pull fires; every third with two cylinders of one row, so V has a direction of no scatter
    whose shift is not zero), each at the three kappas."""
    rng = np.random.default_rng(2)
    fired = 0
    for i in range(200):
        case = _random_case(rng, bias=5.0 * (i % 2), twin=i % 3 == 0)
        fired += sum(_assert_kernel_is_reference(*case, kappa) for kappa in KAPPAS)
    assert fired >= 200


def test_kernel_none_paths_give_zeros_as_the_reference():
    """Where ``data_only_pull`` finds no data-only point both give zeros (z,): nothing accumulated (weight 0), N not
    positive definite (singular, indefinite), a non-finite right-hand side, N, share or posterior; shapes that do not
    fit are a one-line error."""
    rng = np.random.default_rng(3)
    acc, post, rows, share = _random_case(rng, bias=5.0)
    assert np.any(PullCheck(1.0).sigma(acc, post, rows, share) > 0.0)  # the case fires before it is broken
    singular = acc.info.copy()
    singular[:, 3] = singular[:, 2]
    singular[3, :] = singular[2, :]
    indefinite = acc.info - 2.0 * np.linalg.eigvalsh(acc.info).max() * np.eye(acc.info.shape[0])
    nan_info = acc.info.copy()
    nan_info[4, 4] = np.nan
    nan_rhs = acc.rhs.copy()
    nan_rhs[1] = np.inf
    nan_params = post.params.copy()
    nan_params[0] = np.nan
    nan_share = share.copy()
    nan_share[2] = np.nan
    nan_cov = post.cov_statistical.copy()
    nan_cov[1, 2] = np.nan
    cases = [(replace(acc, weight=0.0), post, share), (replace(acc, info=singular), post, share),
             (replace(acc, info=indefinite), post, share), (replace(acc, info=nan_info), post, share),
             (replace(acc, rhs=nan_rhs), post, share), (acc, replace(post, params=nan_params), share),
             (acc, post, nan_share), (acc, replace(post, cov_statistical=nan_cov), share)]
    for a, p, s in cases:
        assert data_only_pull(a, p, rows, s) is None
        assert_allclose(PullCheck(1.0).sigma(a, p, rows, s), np.zeros(rows.shape[0]), atol=0.0)
    with pytest.raises(ValueError, match="do not fit"):
        PullCheck(1.0).sigma(acc, post, rows, share[:3])
    with pytest.raises(ValueError, match="do not fit"):
        PullCheck(1.0).sigma(acc, post, np.ones((5, 13)), share)
