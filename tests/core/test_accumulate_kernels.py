"""One cycle's normal-equation terms and their fold (core.monitor.identify.accumulate behind Accumulator.cycle_terms / fold)
against the numpy code they replace (kept here verbatim as ``_cycle_terms_reference`` / ``_fold_reference``).

Sizes: genset-v20 R=49 rows (2 x 24 harmonics + the mean balance) by P=47 parameters; k9k-4cyl 47 x 29,
deutz-1cyl 47 x 28. Tolerances: A^T y, y^T y, the sys_map, one reference row's outer product and the fold are
bit-identical (the same BLAS calls or the same single roundings); A^T A is a gemm where numpy uses syrk: 1e-15 of
the largest entry (a few roundings of a 49-term sum), and exactly symmetric.
"""

import numpy as np
import pytest
from frictionwatch.core.monitor.identify.accumulate import Accumulator, CycleTerms, cycle_terms_kernel
from numpy.testing import assert_allclose, assert_array_equal

SIZES = {"genset-v20": (49, 47), "k9k-4cyl": (47, 29), "deutz-1cyl": (47, 28)}


def _cycle_terms_reference(a, y, inv_sigma, reference_rows=0):
    ref = a[a.shape[0] - reference_rows:]
    return (a.T @ a, a.T @ y, float(y @ y), float(a.shape[0]), a.T * inv_sigma[None, :], ref.T @ ref)


def _fold_reference(acc, terms, lam):
    return (lam * acc.info + terms[0], lam * acc.rhs + terms[1], lam * acc.yty + terms[2], lam * acc.weight + 1.0,
            lam * acc.rows + terms[3], lam * acc.sys_map + terms[4], lam * acc.info_reference + terms[5])


def _rows(rng, r, p):
    """Whitened rows like the monitor's: badly scaled columns, the last row (mean balance) without nuisances."""
    a = rng.normal(size=(r, p)) * np.logspace(-4, 2, p)
    a[-1, p // 2:] = 0.0
    return a, rng.normal(size=r) * 10.0, 1.0 / (0.5 + rng.random(r))


def _running(rng, r, p, cycles=5, lam=0.97):
    acc = Accumulator.empty(p, r)
    for _ in range(cycles):
        acc = acc.update(*_rows(rng, r, p), lam, reference_rows=1)
    return acc


@pytest.mark.parametrize("engine", list(SIZES))
@pytest.mark.parametrize("reference_rows", [0, 1, 3])
def test_cycle_terms_match_numpy(engine, reference_rows):
    r, p = SIZES[engine]
    rng = np.random.default_rng(r * p + reference_rows)
    a, y, inv_sigma = _rows(rng, r, p)
    got = Accumulator.empty(p, r).cycle_terms(a, y, inv_sigma, reference_rows)
    want = _cycle_terms_reference(a, y, inv_sigma, reference_rows)
    assert isinstance(got, CycleTerms)
    assert_allclose(got.info, want[0], rtol=0, atol=1e-15 * np.abs(want[0]).max())
    assert_array_equal(got.info, got.info.T)
    assert_array_equal(got.rhs, want[1])
    assert got.yty == want[2] and got.rows == want[3]
    assert_array_equal(got.sys_map, want[4])
    assert got.sys_map.flags.c_contiguous
    if reference_rows <= 1:
        assert_array_equal(got.info_reference, want[5])
    else:
        assert_allclose(got.info_reference, want[5], rtol=0, atol=1e-15 * np.abs(want[5]).max())


@pytest.mark.parametrize("engine", list(SIZES))
@pytest.mark.parametrize("lam", [0.0, 0.9975, 1.0])
def test_fold_matches_numpy_bit_for_bit(engine, lam):
    r, p = SIZES[engine]
    rng = np.random.default_rng(p + int(1000 * lam))
    acc = _running(rng, r, p)
    before = [x.copy() for x in (acc.info, acc.rhs, acc.sys_map, acc.info_reference)]
    terms = acc.cycle_terms(*_rows(rng, r, p), 1)
    got = acc.fold(terms, lam)
    want = _fold_reference(acc, terms, lam)
    for name, w in zip(("info", "rhs", "yty", "weight", "rows", "sys_map", "info_reference"), want):
        assert_array_equal(getattr(got, name), w, err_msg=name)
    # the input accumulator is unchanged and the result shares no array with it or with the terms
    for x, b in zip((acc.info, acc.rhs, acc.sys_map, acc.info_reference), before):
        assert_array_equal(x, b)
    for x in (got.info, got.rhs, got.sys_map, got.info_reference):
        for y in (acc.info, acc.rhs, acc.sys_map, acc.info_reference, *terms[:2], *terms[4:]):
            assert not np.shares_memory(x, y)


def test_update_over_cycles_matches_numpy():
    r, p = SIZES["genset-v20"]
    rng = np.random.default_rng(5)
    acc = Accumulator.empty(p, r)
    ref = [np.zeros((p, p)), np.zeros(p), 0.0, 0.0, 0.0, np.zeros((p, r)), np.zeros((p, p))]
    for _ in range(30):
        a, y, s = _rows(rng, r, p)
        acc = acc.update(a, y, s, 0.9975, reference_rows=1)
        ref = list(_fold_reference(Accumulator(*[ref[i] for i in (0, 1, 2, 3, 4, 5, 6)]),
                                   _cycle_terms_reference(a, y, s, 1), 0.9975))
    assert_allclose(acc.info, ref[0], rtol=0, atol=1e-15 * np.abs(ref[0]).max())
    for i, name in ((1, "rhs"), (2, "yty"), (3, "weight"), (4, "rows"), (5, "sys_map"), (6, "info_reference")):
        assert_array_equal(getattr(acc, name), ref[i], err_msg=name)


def test_other_layouts_and_dtypes_are_converted():
    r, p = SIZES["deutz-1cyl"]
    rng = np.random.default_rng(9)
    a, y, s = _rows(rng, r, p)
    s32 = s.astype(np.float32)
    want = Accumulator.empty(p, r).cycle_terms(a, y, s32.astype(np.float64), 1)
    got = Accumulator.empty(p, r).cycle_terms(np.asfortranarray(a), y.tolist(), s32, np.int32(1))
    for x, w in zip(got, want):
        assert_array_equal(x, w)
    # an accumulator built from Fortran-ordered arrays (a.T * inv_sigma is one) folds like a C-ordered one
    acc = _running(rng, r, p)
    f_acc = Accumulator(acc.info, acc.rhs, acc.yty, acc.weight, acc.rows, np.asfortranarray(acc.sys_map),
                        acc.info_reference)
    for name in ("info", "rhs", "yty", "weight", "rows", "sys_map", "info_reference"):
        assert_array_equal(getattr(f_acc.fold(want, 0.99), name), getattr(acc.fold(want, 0.99), name))


def test_bad_shapes_raise():
    r, p = SIZES["deutz-1cyl"]
    rng = np.random.default_rng(1)
    a, y, s = _rows(rng, r, p)
    acc = Accumulator.empty(p, r)
    with pytest.raises(ValueError, match="rows must have shape"):
        acc.cycle_terms(a[:-1], y[:-1], s[:-1])
    with pytest.raises(ValueError, match="one value per row"):
        acc.cycle_terms(a, y[:-1], s)
    with pytest.raises(ValueError, match="one value per row"):
        acc.cycle_terms(a, y, s[:-1])
    with pytest.raises(ValueError, match="reference_rows"):
        acc.cycle_terms(a, y, s, r + 1)
    assert not cycle_terms_kernel(a, y, s, -1)[0]
    with pytest.raises(ValueError, match="shapes"):
        Accumulator.empty(p + 1, r).fold(acc.cycle_terms(a, y, s), 0.9)
    with pytest.raises(ValueError, match="forgetting"):
        acc.fold(acc.cycle_terms(a, y, s), 1.5)


@pytest.mark.parametrize("engine", sorted(SIZES))
def test_fold_with_raw_rows_matches_numpy_bit_for_bit(engine):
    """The fold with raw rows kept: numpy's raw sums lam * old + new, the same for Fortran-ordered raw rows, over
    cycles; bad raw shapes raise. (The monitor's every cycle folds in accumulate.cycle_step_kernel:
    tests/core/test_identify_fused.py.)"""
    r, p = SIZES[engine]
    rng = np.random.default_rng(r + p)
    acc = Accumulator.empty(p, r)
    for _ in range(6):
        a, y, inv_sigma = _rows(rng, r, p)
        terms = acc.cycle_terms(a, y, inv_sigma, 1)
        raw = (a * rng.uniform(0.5, 2.0, r)[:, None], y * rng.uniform(0.5, 2.0, r))
        lam = 0.9975
        new = acc.fold(terms, lam, raw)
        general = acc.fold(terms, lam, (np.asfortranarray(raw[0]), raw[1]))
        if acc.raw_rows is not None:
            assert_array_equal(new.raw_rows, lam * acc.raw_rows + raw[0])
            assert_array_equal(new.raw_target, lam * acc.raw_target + raw[1])
        for name in ("info", "rhs", "yty", "weight", "rows", "sys_map", "info_reference", "raw_rows", "raw_target",
                     "raw_weight"):
            assert_array_equal(getattr(new, name), getattr(general, name), err_msg=name)
        acc = new
    with pytest.raises(ValueError):
        acc.fold(terms, 0.99, (raw[0][:-1], raw[1][:-1]))
