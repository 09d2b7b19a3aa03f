"""frictionwatch.core.model.dynamics.dissipated_power (numba kernel) against its plain-numpy reference, the pre-kernel implementation
copied here, on the presets' real chains (genset-v20: 14 nodes, 13 relative dampers; k9k-4cyl; deutz-1cyl rigid)
with seeded speed harmonics. The kernel sums in loop order, numpy pairwise: equal to ~1e-15 relative (1e-12 asserted)."""

import numpy as np
import pytest
from frictionwatch.core.model.dynamics import dissipated_power, shaft_model
from frictionwatch.core.model.engine import load_engine
from numpy.testing import assert_allclose


def dissipated_power_reference(shaft, speed):
    s = np.asarray(speed)
    rel = 0.0
    if shaft.edges.shape[0]:
        d = s[shaft.edges[:, 0], :] - s[shaft.edges[:, 1], :]
        rel = float(0.5 * np.sum(shaft.edge_damping[:, None] * np.abs(d) ** 2))
    gnd = float(0.5 * np.sum(shaft.ground_damping[:, None] * np.abs(s) ** 2))
    return rel, gnd


@pytest.mark.parametrize("name,m", (("genset-v20", 24), ("k9k-4cyl", 16), ("deutz-1cyl", 12)))
def test_dissipated_power_matches_reference(name, m):
    spec = load_engine(name)
    shaft = shaft_model(spec, load_torque=0.8 * spec.rated_torque_nm, omega_mean=150.0)
    rng = np.random.default_rng(4)
    speed = rng.normal(size=(spec.n_nodes, m)) + 1j * rng.normal(size=(spec.n_nodes, m))
    got = dissipated_power(shaft, speed)
    want = dissipated_power_reference(shaft, speed)
    assert_allclose(got, want, rtol=1e-12, atol=0.0)
    assert all(type(v) is float for v in got)
    # a non-contiguous view gives the same numbers
    wide = np.zeros((spec.n_nodes, 2 * m), dtype=complex)
    wide[:, ::2] = speed
    assert_allclose(dissipated_power(shaft, wide[:, ::2]), want, rtol=1e-12, atol=0.0)
    with pytest.raises(ValueError):
        dissipated_power(shaft, speed[:-1] if spec.n_nodes > 1 else np.zeros((2, m)))
