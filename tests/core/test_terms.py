"""The loss-term library (core.model.terms): each kernel against its numpy reference, and against the friction
basis the simulator and monitor have used so far (core.model.friction), on seeded random cycles."""

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.terms import FIELDS, LossTerm, TermLibrary, cylinder_samples, rezeka_henein
from numpy.testing import assert_allclose

ENGINES = ["deutz-1cyl", "k9k-4cyl", "genset-v20"]


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
    lib = rezeka_henein(spec.friction.coefficients)
    # same formula, same operations up to association: a few ulps
    assert_allclose(lib.evaluate(samples, consts), lib.evaluate_reference(samples, consts), rtol=1e-12, atol=0)


@pytest.mark.parametrize("engine", ENGINES)
def test_library_reproduces_the_friction_basis(engine):
    from frictionwatch.core.model.friction import friction_basis

    spec = load_engine(engine)
    consts = spec.friction_params()
    angle, omega, p_gauge = random_cycle(spec, 3)
    basis = rezeka_henein().evaluate(cylinder_samples(angle, omega, p_gauge, consts), consts)
    # friction_basis takes sin of the wrapped angle, the samples of the unwrapped one; (1 - |sin|) near +-90 deg
    # cancels digits, so a few 1e-12 relative
    assert_allclose(basis, friction_basis(angle, omega, p_gauge, consts), rtol=1e-9, atol=1e-300)


def test_library_composes_and_refuses_repeats():
    lib = rezeka_henein()
    quad = LossTerm("aux_quadratic", "omega^2", "engine", "N m s^2", 0.0,
                    kernel=lambda s, c, out: np.multiply(s[FIELDS.index("omega")], s[FIELDS.index("omega")], out=out),
                    reference=lambda s, c: s[FIELDS.index("omega")] ** 2)
    bigger = lib + quad
    assert len(bigger) == 7 and bigger.index("aux_quadratic") == 6 and len(lib) == 6
    with pytest.raises(ValueError, match="repeated: ring_viscous"):
        TermLibrary(lib.terms + lib.terms[:1])
    with pytest.raises(KeyError, match="no loss term"):
        lib.index("ring_wear")
    assert "ring_mixed" in lib.equations(np.arange(6.0))
