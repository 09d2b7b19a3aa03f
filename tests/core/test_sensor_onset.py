"""Sensor faults with an onset (``from_cycle`` of tdc_offset, pressure_gain, pressure_offset; core.plant.simulate,
core.plant.sim_stream, core.plant.sim_records): the records are the healthy run's, to the bit, before the switch, and
carry the fault from the start of output cycle ``from_cycle`` on.

One engine and seed faulted and healthy (k9k-4cyl 2000 rpm / 0.8, seed 3, 30 cycles, fault from cycle 12), sensor
noise and tooth errors off so that a reading is the true pressure or edge time through the ADC and the timer only.
Tolerances: a pressure reading is gain x true + offset rounded to the ADC step (half a step each); an edge tick is
floor(t x tick_hz) (one tick), and the healthy run's edge time at an angle between its edges comes from a cubic spline
through them (its error is below 1e-8 s here, a tenth of a tick); a shifted pressure trace's shift is fitted to 0.01 deg
(sample-to-sample interpolation of a 20 kHz trace) and judged against the siblings': a moved throw changes the work
and the speed a little, so the whole plant lags the healthy run by ~0.04 deg a few cycles on, on every channel alike
(within 0.02 deg of each other)."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.core.types import PressureFrame, ToothBatch
from scipy.interpolate import CubicSpline

ONSET, CYCLES, RPM = 12, 30, 2000.0
SPEC = load_engine("k9k-4cyl")
QUIET = ("sensor_noise", "tooth_spacing_error")


def _run(*effects: str):
    return simulate(SPEC, RPM, 0.8, CYCLES, 3, effects=[parse_effect(e) for e in effects], without=QUIET)


@pytest.fixture(scope="module")
def healthy():
    return _run()


def _pressure(sim) -> np.ndarray:
    return np.concatenate([r.values for r in sim.records if isinstance(r, PressureFrame)], axis=1)


def _ticks(sim) -> np.ndarray:
    return np.concatenate([r.ticks for r in sim.records if isinstance(r, ToothBatch)])


def _onset_time(sim) -> float:
    (change,) = sim.truth["wheel"]["changes"]
    assert change["cycle"] == ONSET
    # the switch is at the start of the onset cycle (the plant stops at the first step past it: 0.25 deg)
    start = sim.truth["cycles"][ONSET]["t_start_s"]
    assert 0.0 <= change["time_s"] - start <= np.radians(0.3) / (RPM * np.pi / 30.0)
    return change["time_s"]


def test_gain_and_pegging_from_their_onset(healthy):
    faulted = _run(f"pressure_gain:cylinder=2,gain=0.96,from_cycle={ONSET}",
                   f"pressure_offset:cylinder=3,pa=30000,from_cycle={ONSET}")
    t_switch = _onset_time(faulted)
    assert faulted.truth["wheel"]["changes"][0]["pressure_gain"] == [1.0, 0.96, 1.0, 1.0]
    assert faulted.truth["wheel"]["changes"][0]["pressure_offset_pa"] == [0.0, 0.0, 30000.0, 0.0]
    ph, pf = _pressure(healthy), _pressure(faulted)
    assert ph.shape == pf.shape
    t = np.arange(ph.shape[1]) / SPEC.sensors.pressure_rate_hz
    before, after = t < t_switch, t >= t_switch
    assert before.sum() > 1000 and after.sum() > 1000
    np.testing.assert_array_equal(pf[:, before], ph[:, before])  # the same run to the bit before the onset
    lsb = SPEC.sensors.pressure_range_pa / 2**SPEC.sensors.pressure_adc_bits
    np.testing.assert_allclose(pf[1, after], 0.96 * ph[1, after], rtol=0, atol=lsb)  # two roundings of half a step
    np.testing.assert_allclose(pf[2, after], ph[2, after] + 30000.0, rtol=0, atol=lsb)
    np.testing.assert_array_equal(pf[[0, 3]], ph[[0, 3]])  # the plant is unchanged: the other channels too


def _edge_angles(sim) -> np.ndarray:
    """Wheel angle [rad] of every recorded edge: the tooth index within its revolution, revolutions counted."""
    idx = sim.diagnostics["edge_index"]
    rev = np.concatenate([[0], np.cumsum(np.diff(idx) < 0)])
    se = SPEC.sensors
    return np.radians(se.first_tooth_deg + idx * 360.0 / se.wheel_teeth + 360.0 * rev)


def test_wheel_offset_from_its_onset_moves_every_later_edge(healthy):
    deg = 0.5
    faulted = _run(f"tdc_offset:deg={deg},cylinder=0,from_cycle={ONSET}")
    t_switch = _onset_time(faulted)
    assert faulted.truth["wheel"]["changes"][0]["wheel_offset_deg"] == deg
    th, tf = _ticks(healthy), _ticks(faulted)
    assert th.shape == tf.shape == healthy.diagnostics["edge_index"].shape
    f = SPEC.sensors.tick_hz
    before = th < t_switch * f
    np.testing.assert_array_equal(tf[before], th[before])
    # from the onset each edge comes when the flywheel is deg short of the edge's stated angle (theta_W = theta_F +
    # deg): the healthy run's time at that angle (the plant is the same; the wheel is only read differently)
    angle = _edge_angles(healthy)
    t_at = CubicSpline(angle, healthy.diagnostics["edge_times_s"])
    later = ~before
    later[np.flatnonzero(later)[:1]] = False  # the first edge after the switch may fire at the switch's step
    expected = np.floor(t_at(angle[later] - np.radians(deg)) * f)
    np.testing.assert_allclose(tf[later], expected, rtol=0, atol=1.0)
    shift_ticks = th[later] - tf[later]  # 0.5 deg at ~2000 rpm: ~420 ticks at 10 MHz
    assert shift_ticks.min() > 350


def _shift_deg(p_faulted: np.ndarray, p_healthy: np.ndarray, t: np.ndarray, omega: float) -> float:
    """The angle [deg] by which p_faulted lags p_healthy (least squares over a grid of time shifts)."""
    shifts = np.linspace(-100e-6, 100e-6, 2001)
    cost = [np.sum((p_faulted - np.interp(t - s, t, p_healthy)) ** 2) for s in shifts]
    return float(np.degrees(shifts[int(np.argmin(cost))] * omega))


def test_cylinder_tdc_from_its_onset_moves_that_cylinder(healthy):
    deg, k = 0.5, 3
    faulted = _run(f"tdc_offset:deg={deg},cylinder={k},from_cycle={ONSET}")
    t_switch = _onset_time(faulted)
    change = faulted.truth["wheel"]["changes"][0]
    np.testing.assert_allclose(change["firing_angles_deg"], np.degrees(SPEC.firing_angles) + deg * (np.arange(4) == k - 1),
                               rtol=0, atol=1e-9)
    assert change["wheel_offset_deg"] == 0.0
    ph, pf = _pressure(healthy), _pressure(faulted)
    m = min(ph.shape[1], pf.shape[1])  # the moved throw changes the plant: the run may end a sample later
    ph, pf = ph[:, :m], pf[:, :m]
    t = np.arange(m) / SPEC.sensors.pressure_rate_hz
    np.testing.assert_array_equal(pf[:, t < t_switch], ph[:, t < t_switch])
    th, tf = _ticks(healthy), _ticks(faulted)
    np.testing.assert_array_equal(tf[tf < t_switch * SPEC.sensors.tick_hz], th[th < t_switch * SPEC.sensors.tick_hz])
    # three cycles after the onset: the cylinder's pressure lags the healthy one by deg, the others do not move
    cyc = faulted.truth["cycles"]
    window = (t >= cyc[ONSET + 1]["t_start_s"]) & (t < cyc[ONSET + 4]["t_start_s"])
    omega = cyc[ONSET + 2]["rpm_mean"] * np.pi / 30.0
    shifts = [_shift_deg(pf[j, window], ph[j, window], t[window], omega) for j in range(4)]
    # the whole plant lags a little behind the healthy run (the moved throw changed the work and the speed: 0.04 deg
    # over these cycles), the same on every channel; against its siblings the cylinder lags by deg
    others = np.delete(shifts, k - 1)
    np.testing.assert_allclose(shifts[k - 1] - np.median(others), deg, rtol=0, atol=0.02)
    np.testing.assert_allclose(others - np.median(others), 0.0, rtol=0, atol=0.02)
    assert abs(np.median(others)) < 0.1


def test_onset_zero_is_the_fault_from_the_start():
    a = _run("pressure_gain:cylinder=2,gain=0.96")
    b = _run("pressure_gain:cylinder=2,gain=0.96,from_cycle=0")
    np.testing.assert_array_equal(_pressure(a), _pressure(b))
    assert "changes" not in a.truth["wheel"]
