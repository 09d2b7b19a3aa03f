"""The thermal_shock effect (core.model.effects.catalog.ThermalShock, core.model.thermal_shock): a sensor-side error,
the plant unchanged; the monitor adds it back where its model holds it.

A shocked and a healthy run of one engine and seed (k9k-4cyl 2000 rpm / 0.8, seed 3, 4 cycles), sensor noise and
tooth errors off: the plant is the same to the bit, so a reading's difference is the error alone, through the ADC
(two readings rounded to its step each: one step, 305 Pa). Where it should be is read from the tooth edges, not from
the 1-deg grid the sensor model interpolates on: each sample's flywheel angle interpolated between the two edges
around it (6 deg apart; the speed's change within one is < 0.1 deg of angle; the whole revolutions from output cycle
0's start, at theta_F = 0), less the cylinder's firing angle.
"""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.core.model.effects import SensorSetup, ThermalShock, parse_effect
from frictionwatch.core.model.effects.base import ViewSetup
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.thermal_shock import shock_shape
from frictionwatch.core.model.view import monitor_view, viewed_cycle
from frictionwatch.core.plant.simulate import simulate, start_simulation
from frictionwatch.core.types import PressureFrame
from frictionwatch.service.pipeline import assembled_cycles

SPEC = load_engine("k9k-4cyl")
RPM, LOAD, CYCLES = 2000.0, 0.8, 4
QUIET = ("sensor_noise", "tooth_spacing_error")


def _run(*effects: str):
    return simulate(SPEC, RPM, LOAD, CYCLES, 3, effects=[parse_effect(e) for e in effects], without=QUIET)


def _pressure(sim) -> np.ndarray:
    return np.concatenate([r.values for r in sim.records if isinstance(r, PressureFrame)], axis=1)


@pytest.fixture(scope="module")
def runs():
    return _run(), _run("thermal_shock:cylinder=2,pa=40000,tau_ms=3,idle_frac=0.25")


def _local_angles(sim, n: int) -> np.ndarray:
    """(n, z) each sample's angle from each cylinder's firing TDC [rad], from the tooth edges."""
    se = SPEC.sensors
    e = sim.diagnostics["edge_index"]
    rev = np.concatenate([[0], np.cumsum(np.diff(e) < 0)])  # the index is the tooth's within its revolution
    theta_edge = np.radians(se.first_tooth_deg + e * 360.0 / se.wheel_teeth) + 2.0 * np.pi * rev
    t = np.arange(n) / se.pressure_rate_hz
    # the edges' index fixes the angle up to whole revolutions: output cycle 0 starts at theta_F = 0
    start = np.interp(sim.diagnostics["cycle_t_start_s"][0], sim.diagnostics["edge_times_s"], theta_edge)
    theta_edge = theta_edge - 2.0 * np.pi * np.round(start / (2.0 * np.pi))
    theta = np.interp(t, sim.diagnostics["edge_times_s"], theta_edge)
    # from output cycle 0 on: in the revolution before it the sensor model has no grid yet and interpolates the
    # angle over the whole revolution (up to ~1 deg off there: core.plant.sim_records)
    inside = (t >= sim.diagnostics["cycle_t_start_s"][0]) & (t <= sim.diagnostics["edge_times_s"][-1])
    return theta[inside, None] - SPEC.firing_angles[None, :], inside


def test_the_reading_is_low_by_the_shape_at_its_angle_in_its_cylinder_only(runs):
    healthy, shocked = runs
    p0, p1 = _pressure(healthy), _pressure(shocked)
    np.testing.assert_array_equal(healthy.diagnostics["pressure_true_pa"], shocked.diagnostics["pressure_true_pa"])
    lsb = SPEC.sensors.pressure_range_pa / 2**SPEC.sensors.pressure_adc_bits
    diff = p1 - p0
    np.testing.assert_array_equal(diff[[0, 2, 3]], 0.0)  # the other cylinders' readings unchanged
    local, inside = _local_angles(healthy, p0.shape[1])
    tau_deg = np.degrees(3e-3 * RPM * np.pi / 30.0)
    grid, shape = shock_shape(SPEC.combustion.start_deg, tau_deg)
    size = 4e4 * (0.25 + 0.75 * LOAD)
    expected = -size * np.interp(np.mod(local[:, 1], 4.0 * np.pi), grid, shape)
    np.testing.assert_allclose(diff[1, inside], expected, atol=1.01 * lsb)
    assert diff[1].min() < -0.97 * size  # it reaches its peak once a cycle at least


def test_shape_rises_after_combustion_and_dies_away_over_the_exhaust():
    for tau_deg, lo, hi in ((20.0, 25.0, 45.0), (36.0, 35.0, 55.0), (60.0, 45.0, 65.0)):
        grid, shape = shock_shape(-5.0, tau_deg)
        deg = np.degrees(grid)
        assert lo <= deg[np.argmax(shape)] <= hi  # the peak some 30-60 deg after TDC, later for a slower sensor
        assert np.interp(360.0, deg, shape) < 0.02  # gone by the gas-exchange TDC
        assert np.all(shape >= 0.0) and shape.max() == pytest.approx(1.0)
        # the periodic steady state of the lag: the ODE e' = (q - e) / tau integrated on a 0.05-deg step from the table's start
        # value over the cycle comes back to it (and tracks the table)
        fine = np.arange(0.0, 720.0, 0.05)
        x = np.mod(fine + 5.0, 720.0) / 20.0
        q = x * np.exp(1.0 - x)
        e = np.empty_like(fine)
        e[0] = shape[0] * _peak(-5.0, tau_deg)
        a = np.exp(-0.05 / tau_deg)
        for i in range(1, fine.size):
            e[i] = a * e[i - 1] + (1.0 - a) * q[i - 1]
        np.testing.assert_allclose(e / _peak(-5.0, tau_deg), np.interp(fine, deg, shape), atol=0.01)


def _peak(soc: float, tau_deg: float) -> float:
    """The lag's unscaled peak (the table is scaled to 1 by it), from the same recurrence on a 0.05-deg step."""
    fine = np.arange(0.0, 720.0, 0.05)
    x = np.mod(fine - soc, 720.0) / 20.0
    q = x * np.exp(1.0 - x)
    a = np.exp(-0.05 / tau_deg)
    e, best = 0.0, 0.0
    for _ in range(2):
        for qi in q:
            e = a * e + (1.0 - a) * qi
            best = max(best, e)
    return best


def test_every_cylinder_and_the_view_of_it():
    setup = ThermalShock(cylinder=0, pa=2e4).apply_sensors(SensorSetup.ideal(3))
    np.testing.assert_allclose(setup.thermal_shock_pa, [2e4, 2e4, 2e4])
    setup = ThermalShock(cylinder=3, tau_ms=6.0).apply_sensors(setup)
    np.testing.assert_allclose(setup.thermal_shock_tau_s, [4e-3, 4e-3, 6e-3])
    np.testing.assert_allclose(setup.thermal_shock_pa, [2e4, 2e4, 3e4])
    view = ViewSetup(SPEC, None, np.zeros((4, 1)), np.zeros(4), np.ones(4), np.zeros(4))
    view = ThermalShock(cylinder=3, tau_ms=6.0, idle_frac=0.5).apply_view(ThermalShock(cylinder=0, pa=2e4).apply_view(view))
    np.testing.assert_allclose(view.shock.size_pa, [2e4, 2e4, 3e4, 2e4])
    np.testing.assert_allclose(view.shock.tau_s, [4e-3, 4e-3, 6e-3, 4e-3])
    np.testing.assert_allclose(view.shock.idle, [0.3, 0.3, 0.5, 0.3])


def test_a_model_with_the_shock_reads_the_true_pressure(runs):
    """The monitor's side (core.model.view.viewed_cycle): a model holding the shock in every cylinder (idle_frac 1:
    its size whatever the load) adds it back, at each cycle's own speed, to within the ADC's step and the cycle's
    speed against the run's (the plant sizes the time constant at the requested speed): 3 steps (~0.9 kPa) of a
    40 kPa error."""
    healthy = _run()
    shocked = _run("thermal_shock:cylinder=0,pa=40000,tau_ms=3,idle_frac=1")
    lsb = SPEC.sensors.pressure_range_pa / 2**SPEC.sensors.pressure_adc_bits
    c0, _ = assembled_cycles(SPEC, healthy.info, healthy.records)
    c1, _ = assembled_cycles(SPEC, shocked.info, shocked.records)
    model = EngineModel.from_spec(SPEC).with_effect(parse_effect("thermal_shock:cylinder=0,pa=40000,tau_ms=3,idle_frac=1"))
    view = monitor_view(model, None)
    assert view.corrects_pressure and not monitor_view(EngineModel.from_spec(SPEC), None).corrects_pressure
    for a, b in zip(c0, c1, strict=True):
        assert np.abs(b.pressure - a.pressure).max() > 0.9 * 4e4  # the shock as read
        np.testing.assert_allclose(viewed_cycle(view, b).pressure, a.pressure, rtol=0, atol=3 * lsb)


def test_the_same_readings_whatever_the_chunking():
    """A sample past the grid's last row waits for the next stretch's grid (core.plant.sim_records): cut into
    one-cycle chunks, the run's readings are those of the run in one piece (the same interpolation: equal)."""
    effects = [parse_effect("thermal_shock:cylinder=0,pa=50000")]

    def readings(chunk_cycles: int) -> np.ndarray:
        sim = start_simulation(SPEC, RPM, LOAD, CYCLES, 3, effects=effects, without=QUIET)
        records = [r for c in sim.chunks(chunk_cycles=chunk_cycles) for r in c.records]
        return np.concatenate([r.values for r in records if isinstance(r, PressureFrame)], axis=1)

    np.testing.assert_array_equal(readings(1), readings(CYCLES))
