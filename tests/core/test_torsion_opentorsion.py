"""Torsional natural frequencies of each preset's shaft line against openTorsion (Aalto Univ., an independent
assembly of the same lumped chain) and against engines.md §2's CHK table where the preset layout is the one CHK used."""

import numpy as np
import pytest
from frictionwatch.core.model.dynamics import natural_frequencies, shaft_model
from frictionwatch.core.model.engine import available_presets, load_engine
from numpy.testing import assert_allclose

ot = pytest.importorskip("opentorsion")


def opentorsion_frequencies(spec, mass):
    shafts = [ot.Shaft(i, i + 1, k=float(k), c=float(c)) for i, (k, c) in enumerate(zip(spec.stiffness, spec.damping))]
    ground = spec.load.grid_stiffness_nm_per_rad if spec.load.kind == "grid" else 0.0
    disks = [ot.Disk(i, I=float(mass[i]), k=ground if i == spec.load_node else 0.0) for i in range(spec.n_nodes)]
    lam, _ = ot.Assembly(shafts, disk_elements=disks).undamped_modal_analysis()
    return np.sort(np.sqrt(np.clip(np.real(lam), 0, None))) / (2 * np.pi)


@pytest.mark.parametrize("name", [n for n in available_presets() if load_engine(n).n_nodes > 1])
def test_frequencies_agree_with_opentorsion(name):
    spec = load_engine(name)
    shaft = shaft_model(spec, load_torque=0.0, omega_mean=spec.rated_speed_rpm * np.pi / 30)
    ours = natural_frequencies(shaft)
    theirs = opentorsion_frequencies(spec, shaft.mass)
    assert_allclose(ours, theirs, rtol=1e-6, atol=1e-3)  # the free-free rigid mode is 0 Hz up to round-off


@pytest.mark.parametrize("name,chk", [
    ("genset-v20", [2.45, 19.8, 97.8, 282, 473, 661]),  # engines.md §2 (CHK, openTorsion)
    ("k9k-4cyl", [61.5, 137, 524, 1432]),
])
def test_frequencies_match_engines_md(name, chk):
    spec = load_engine(name)
    f = natural_frequencies(shaft_model(spec, omega_mean=spec.rated_speed_rpm * np.pi / 30))
    f = f[f > 1.0]
    assert_allclose(f[: len(chk)], chk, rtol=0.01)
