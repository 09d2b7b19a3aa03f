"""The loss-term library (core.model.terms): each kernel against its numpy reference on seeded random cycles (one
cylinder and many at once), the sample rows against core.model.kinematics, composition, and a new term."""

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.terms import (
    OMEGA,
    LossTerm,
    TermLibrary,
    cylinder_samples,
    cylinder_samples_reference,
    loss_kernel,
    rezeka_henein,
)
from numpy.testing import assert_allclose

ENGINES = ["deutz-1cyl", "k9k-4cyl", "genset-v20"]


@loss_kernel
def aux_quadratic_kernel(s, c, out):
    for k in range(out.shape[0]):
        for i in range(out.shape[1]):
            out[k, i] = s[OMEGA, k, i] * s[OMEGA, k, i]


def aux_quadratic_reference(s, c):
    return s[OMEGA] ** 2


# a loss term the Rezeka-Henein set lacks: auxiliaries whose drag grows with omega^2 (fans, pumps), engine-wide
AUX_QUADRATIC = LossTerm("aux_quadratic", "omega^2", "engine", "N m s^2", 0.0, aux_quadratic_kernel,
                         aux_quadratic_reference)


def random_cycle(spec, seed):
    rng = np.random.default_rng(seed)
    angle = np.linspace(-np.pi, 3 * np.pi, 721)[:-1] + rng.normal(0, 0.01, 720)
    omega = 150.0 * (1 + 0.05 * np.sin(angle) + 0.01 * rng.normal(size=720))
    p_gauge = 5e6 * np.exp(-angle**2) - 2e4 + 1e4 * rng.normal(size=720)  # negative values are clipped
    return angle, omega, p_gauge


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("seed", [1, 2])
def test_kernels_match_their_references(engine, seed):
    spec = load_engine(engine)
    consts = spec.friction_params()
    samples = cylinder_samples(*random_cycle(spec, seed), consts)
    lib = rezeka_henein(spec.friction.coefficients) + AUX_QUADRATIC
    # same formula, same operations up to association: a few ulps
    assert_allclose(lib.evaluate(samples, consts), lib.evaluate_reference(samples, consts), rtol=1e-12, atol=0)


@pytest.mark.parametrize("engine", ENGINES)
def test_many_cylinders_at_once(engine):
    """(N_FIELDS, z, n) samples give (z, L, n), cylinder by cylinder the one-cylinder numbers (same kernel)."""
    spec = load_engine(engine)
    consts = spec.friction_params()
    lib = rezeka_henein(spec.friction.coefficients)
    one = [cylinder_samples(*random_cycle(spec, s), consts) for s in range(3)]
    stacked = np.stack(one, axis=1)
    got = lib.evaluate(stacked, consts)
    assert got.shape == (3, len(lib), 720)
    for k in range(3):
        assert_allclose(got[k], lib.evaluate(one[k], consts), rtol=0, atol=0)
    assert_allclose(got, lib.evaluate_reference(stacked, consts), rtol=1e-12, atol=0)


@pytest.mark.parametrize("engine", ENGINES)
def test_samples_match_the_kinematics(engine):
    spec = load_engine(engine)
    consts = spec.friction_params()
    cyc = random_cycle(spec, 3)
    # x', x'' with products for the divisions by L and cos(beta): ~1e-15 relative of their scale (R)
    assert_allclose(cylinder_samples(*cyc, consts), cylinder_samples_reference(*cyc, consts), rtol=1e-12,
                    atol=1e-14 * spec.kinematics_params()[0])


def test_library_composes_and_refuses_repeats():
    lib = rezeka_henein()
    bigger = lib + AUX_QUADRATIC
    assert len(bigger) == len(lib) + 1 and bigger.index("aux_quadratic") == len(lib)
    assert bigger.names[-1] == "aux_quadratic" and not bigger.per_cylinder[-1]
    with pytest.raises(ValueError, match="repeated: ring_viscous"):
        TermLibrary(lib.terms + lib.terms[:1])
    with pytest.raises(KeyError, match="no loss term"):
        lib.index("ring_wear")
    assert "ring_mixed" in lib.equations(np.arange(float(len(lib))))
    with pytest.raises(ValueError, match="KERNEL_SIGNATURE"):
        LossTerm("plain", "omega", "engine", "-", 0.0, lambda s, c, out: None, aux_quadratic_reference)


@pytest.mark.parametrize("engine", ["k9k-4cyl", "genset-v20"])
def test_vectorised_division_kernels_give_the_default_models_bits(engine):
    """valve_train and loaded_bearings divide only by sqrt(OMEGA) (floored) and are compiled with numba's numpy error
    model (design note 46): every sample the very bits of the same function compiled with the default model, on
    many cylinders at once and on a shaft at rest (OMEGA at its floor), and finite there."""
    import numba
    from frictionwatch.core.model import terms
    from frictionwatch.core.model.jit import BORROWING

    spec = load_engine(engine)
    consts = spec.friction_params()
    z = spec.n_cyl
    angle, omega, p_gauge = random_cycle(spec, 5)
    omega[::7] = 0.0  # stopped samples: floored to OMEGA_FLOOR by the sample rows
    one = cylinder_samples(angle, omega, p_gauge, consts)
    many = np.ascontiguousarray(np.repeat(one[:, None, :], z, axis=1))
    many[OMEGA] *= np.linspace(0.5, 1.5, z)[:, None]
    for name in ("valve_train_kernel", "loaded_bearings_kernel"):
        fast = getattr(terms, name)
        default = numba.njit(terms.KERNEL_SIGNATURE, **dict(BORROWING, cache=False))(fast.py_func)
        out_fast, out_default = np.empty(many.shape[1:]), np.empty(many.shape[1:])
        fast(many, consts, out_fast)
        default(many, consts, out_default)
        assert np.all(np.isfinite(out_fast))
        np.testing.assert_array_equal(out_fast.view(np.int64), out_default.view(np.int64), err_msg=name)
