"""identify_cycle's fused accumulation step against the chain it replaces (design note 63):
core.monitor.identify.identification.accumulate_cycle, one kernel (cycle terms, raw rows, fold, speed budget)
against accumulate_cycle_reference (Accumulator.cycle_terms, raw_rows, Accumulator.fold, speed_budget). The kernel
runs the same BLAS calls and single roundings, so it is held to rtol 1e-12 (what bench_monitor_against holds a whole
cycle's outcome to); the sizes are the monitor's (k9k-4cyl 47 rows x 29 parameters, genset-v20 49 x 47)."""

from types import SimpleNamespace

import numpy as np
import pytest
from frictionwatch.core.monitor.identify.accumulate import (
    Accumulator,
    accumulate_cycle,
    accumulate_cycle_reference,
    cycle_step_kernel,
)
from frictionwatch.core.monitor.identify.noise_model import ResidualStats
from numpy.testing import assert_allclose

SIZES = {"k9k-4cyl": (47, 29), "genset-v20": (49, 47)}
RTOL = 1e-12


def _white(rng, r, p, zero_weight=True):
    m = (r - 1) // 2
    a = rng.normal(size=(r, p)) * np.logspace(-4, 2, p)
    inv_sigma = 1.0 / (0.5 + rng.random(r))
    if zero_weight:
        inv_sigma[3] = 0.0  # a row that is not there: zeros in the raw rows
        a[3] = 0.0
    stats = ResidualStats(np.zeros(m, complex), rng.random(m) * 1e-2, 0.0, 0.0, 5)
    return SimpleNamespace(a=a, y=rng.normal(size=r) * 10.0, inv_sigma=inv_sigma, sys_var=rng.random(r),
                           freq=np.linspace(50.0, 900.0, m), stats=stats)


def _running(rng, r, p, cycles=5, lam=0.97):
    """An accumulator with its raw rows kept, as the monitor's after its warm-up."""
    acc = Accumulator.empty(p, r)
    for _ in range(cycles):
        acc = accumulate_cycle_reference(acc, _white(rng, r, p), lam, True, np.zeros(p), 0.003, np.ones(1))[1]
    return acc


def _assert_same(got, want, name):
    if want is None or isinstance(want, (bool, np.bool_)):
        assert got == want, name
    elif np.ndim(want) == 0:
        assert_allclose(got, want, rtol=RTOL, err_msg=name)
    else:
        assert np.shape(got) == np.shape(want), name
        w = np.abs(np.asarray(want))
        big = float(np.max(w[np.isfinite(w)], initial=0.0))
        assert_allclose(got, want, rtol=RTOL, atol=RTOL * max(big, 1e-300), err_msg=name)  # NaN where NaN


def _assert_same_accumulator(got, want):
    for f in ("info", "rhs", "yty", "weight", "rows", "sys_map", "info_reference", "raw_rows", "raw_target",
              "raw_weight"):
        _assert_same(getattr(got, f), getattr(want, f), f)


@pytest.mark.parametrize("engine", list(SIZES))
@pytest.mark.parametrize("fold", [True, False])
def test_accumulation_step_equals_its_chain(engine, fold):
    r, p = SIZES[engine]
    rng = np.random.default_rng(r + p + fold)
    acc = _running(rng, r, p)
    white = _white(rng, r, p)
    m = white.freq.shape[0]
    params = rng.uniform(0.5, 1.5, p)
    harmonics = rng.normal(size=m) + 1j * rng.normal(size=m)
    assert cycle_step_kernel(white.a, white.y, white.inv_sigma, 0.98, fold,
                             (acc.info, acc.rhs, acc.sys_map, acc.info_reference, acc.raw_rows, acc.raw_target),
                             acc.raw_weight, params, (white.sys_var, white.stats.var, white.freq, harmonics),
                             0.003)[0]  # the kernel's path is the one compared
    got = accumulate_cycle(acc, white, 0.98, fold, params, 0.003, harmonics)
    want = accumulate_cycle_reference(acc, white, 0.98, fold, params, 0.003, harmonics)
    for f in ("info", "rhs", "yty", "rows", "sys_map", "info_reference"):
        _assert_same(getattr(got[0], f), getattr(want[0], f), f)
    _assert_same_accumulator(got[1], want[1])
    if not fold:
        assert got[1] is acc
    _assert_same(got[2], want[2], "budget")
    # the budget is the persistent residual's for some speed rows and the model floor for others here
    assert np.any(got[2][:m] != white.sys_var[:m])


@pytest.mark.parametrize("fold", [True, False])
def test_accumulation_step_from_a_fresh_accumulator_is_the_chain(fold):
    """A fresh (or an old saved) accumulator keeps no raw rows: the warm-up's steps (no fold: the budget is the
    noise model's) and the first fold (raw rows started from that cycle's) take the kernel too, and so does the
    accumulator the kernel made."""
    r, p = SIZES["k9k-4cyl"]
    rng = np.random.default_rng(3)
    harmonics = np.ones((r - 1) // 2, complex)
    acc = Accumulator.empty(p, r)
    for _ in range(3):
        white = _white(rng, r, p)
        arrays = (acc.info, acc.rhs, acc.sys_map, acc.info_reference,
                  *((acc.raw_rows, acc.raw_target) if acc.raw_rows is not None else (np.empty((0, 0)), np.empty(0))))
        assert cycle_step_kernel(white.a, white.y, white.inv_sigma, 0.98, fold, arrays, 1.0, np.ones(p),
                                 (white.sys_var, white.stats.var, white.freq, harmonics), 0.003)[0]
        got = accumulate_cycle(acc, white, 0.98, fold, np.ones(p), 0.003, harmonics)
        want = accumulate_cycle_reference(acc, white, 0.98, fold, np.ones(p), 0.003, harmonics)
        _assert_same_accumulator(got[1], want[1])
        _assert_same(got[2], want[2], "budget")
        acc = got[1]
    assert (acc.raw_rows is not None) == fold


def test_accumulation_step_with_wrong_inputs_raises_as_the_chain():
    r, p = SIZES["k9k-4cyl"]
    rng = np.random.default_rng(3)
    white = _white(rng, r, p)
    harmonics = np.ones(white.freq.shape[0], complex)
    acc = _running(rng, r, p)
    with pytest.raises(ValueError, match="rows must have shape"):
        accumulate_cycle(acc, _white(rng, r, p + 1), 0.98, True, np.ones(p), 0.003, harmonics)
    with pytest.raises(ValueError, match="forgetting factor"):
        accumulate_cycle(acc, white, 1.5, True, np.ones(p), 0.003, harmonics)
