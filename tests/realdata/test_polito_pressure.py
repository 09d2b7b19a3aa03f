"""PoliTo 4-cyl diesel, 1600 rpm / 99.99 N m: IMEP from the measured cylinder-1 trace (README: 5.68 bar net) and
FMEP = IMEP - BMEP (README: BMEP 4.19 bar, FMEP ~1.5 bar)."""

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.indicated import net_imep, peak_pressure
from numpy.testing import assert_allclose

FOLDER = "polito-diesel-4cyl-1600rpm"


def load_trace(realdata):
    data = np.loadtxt(realdata / FOLDER / "pcyl1_1600rpm_100Nm.csv", delimiter=",", skiprows=1)
    angle_deg, p_bar = data[:, 0], data[:, 1]
    # README: -360..359.9 deg, 0 = firing TDC; our grid is 0..720 deg
    order = np.argsort(np.mod(angle_deg, 720.0))
    return np.radians(np.mod(angle_deg, 720.0)[order]), p_bar[order] * 1e5


def test_imep_and_fmep(realdata):
    spec = load_engine("polito-4cyl")
    theta, p = load_trace(realdata)
    assert theta.size == 7200
    imep = net_imep(theta, p[None], np.zeros(1), spec.kinematics_params(), spec.piston_area, spec.displacement_cyl)
    assert_allclose(imep[0] / 1e5, 5.68, rtol=0.01)
    torque = np.loadtxt(realdata / FOLDER / "steady_state_tests.csv", delimiter=",", skiprows=1)[2, 2]
    assert_allclose(torque, 99.99)
    bmep = spec.torque_to_mep(torque)
    assert_allclose(bmep / 1e5, 4.19, rtol=0.01)
    assert_allclose((imep[0] - bmep) / 1e5, 1.5, atol=0.05)


def test_peak_pressure(realdata):
    theta, p = load_trace(realdata)
    pmax, ang = peak_pressure(theta, p[None], np.zeros(1))
    assert_allclose(pmax[0] / 1e5, 69.6, atol=0.2)  # README: 69.6 bar at +5.8 deg ATDC
    assert_allclose(np.degrees(ang[0]), 5.8, atol=0.15)
