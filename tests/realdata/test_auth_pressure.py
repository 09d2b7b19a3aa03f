"""AUTH 4-cyl SI, 1200 rpm / 87 N m: raw pressure volts + 360-ppr encoder + TDC marker (README: IMEP net 8.66 / 8.72
bar for the two cycles, BMEP 7.85 bar, FMEP ~0.85 bar)."""

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.indicated import net_imep, peak_pressure
from numpy.testing import assert_allclose

openpyxl = pytest.importorskip("openpyxl")


@pytest.fixture(scope="module")
def table(realdata):
    wb = openpyxl.load_workbook(realdata / "auth-si-4cyl-1200rpm-87Nm" / "1200rpm_87Nm.xlsx", read_only=True)
    rows = wb.active.iter_rows(min_row=2, values_only=True)
    return np.array([r[:4] for r in rows if r[0] is not None], dtype=float)


def rising_crossings(t, v, level):
    """Sub-sample times where v rises through level (linear interpolation)."""
    i = np.flatnonzero((v[1:] > level) & (v[:-1] <= level))
    return t[i] + (level - v[i]) / (v[i + 1] - v[i]) * (t[i + 1] - t[i])


def test_two_cycles_imep_and_fmep(table):
    spec = load_engine("auth-4cyl")
    t, volts, encoder, tdc = table.T
    edges = rising_crossings(t, encoder, 0.0)
    marks = rising_crossings(t, tdc, 3.5)
    assert edges.size == 1440  # README: 360 crossings per revolution, 4 revolutions
    assert_allclose(np.diff(marks), 0.05, rtol=2e-3)  # 1200 rpm
    p = np.interp(edges, t, volts) * 10.0 * 1e5  # README: p [bar] = 10 V, relative (offset irrelevant to IMEP)
    # firing TDC = the marker where pressure is high; angle of each edge relative to it, 1 deg per edge
    firing = max(marks, key=lambda m: np.interp(m, t, volts))
    i0 = int(np.searchsorted(edges, firing))
    angle = np.radians(np.arange(edges.size) - i0)
    imeps = []
    for c in range(2):
        sl = slice(720 * c, 720 * (c + 1))
        order = np.argsort(np.mod(angle[sl], 4 * np.pi))
        theta = np.mod(angle[sl], 4 * np.pi)[order]
        imeps.append(net_imep(theta, p[sl][order][None], np.zeros(1), spec.kinematics_params(), spec.piston_area,
                              spec.displacement_cyl)[0])
    assert_allclose(np.array(imeps) / 1e5, [8.66, 8.72], rtol=0.01)
    bmep = spec.torque_to_mep(87.0)
    assert_allclose(bmep / 1e5, 7.85, rtol=0.01)
    assert_allclose((np.mean(imeps) - bmep) / 1e5, 0.85, atol=0.05)
    pmax, ang = peak_pressure(theta, (p[sl][order] + 0.8e5)[None], np.zeros(1))
    assert 15.0 < np.degrees(ang[0]) < 25.0  # README: peak at ~20 deg ATDC
