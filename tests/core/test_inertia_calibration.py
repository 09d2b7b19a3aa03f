"""core.monitor.calibration.inertia: J from the coast-down ripple on a synthetic rigid engine (exact kinematics, a
tooth-spacing error), the pooling and the speed trend, and simulated TU/e coast-downs whose plant J differs from
the preset's (no effect changes the plant's J, so the plant gets a spec with another inertia; the estimate is
given the preset model and never reads J from it)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.monitor.calibration.inertia import (
    coastdown_record,
    commission_inertia,
    pool_random_effects,
    speed_trend,
)
from frictionwatch.core.monitor.calibration.ripple import CycleGeometry, fit_ripple_inertia, ripple_rows
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles
from numpy.testing import assert_allclose

SPEC = load_engine("tue-4gb10")
GEO0 = CycleGeometry(np.zeros(1), SPEC.kinematics_params(), float(SPEC.piston_area), 0.0)  # no reciprocating mass
PITCH = 2.0 * np.pi / 60.0


def synthetic_cycle(j, tau, omega0, rng, tooth_error=0.0):
    """A rigid engine of inertia j [kg m^2] under a gas torque with half- and whole-order content and a constant
    friction tau [N m]: J dE/dtheta = T(theta) - tau exactly, edges of a 60-2 wheel (tooth 0 at -4.5 deg) timed by
    integrating dt = dtheta / omega. Returns (edge angles, edge times, tooth index, grid, torque on the grid)."""
    fine = np.linspace(-0.2, 4.0 * np.pi + 0.2, 200_001)

    def torque(th):
        return -0.6 + 6.0 * np.sin(0.5 * th + 0.3) + 3.0 * np.sin(1.5 * th - 0.7) + 2.0 * np.sin(th) \
            + 1.2 * np.sin(2.5 * th + 1.1) + 1.5 * np.cos(2.0 * th)

    tf = torque(fine)
    work = np.concatenate([[0.0], np.cumsum(0.5 * (tf[1:] + tf[:-1]) * np.diff(fine))])
    energy = 0.5 * omega0**2 + (work - tau * (fine - fine[0])) / j
    w = np.sqrt(2.0 * energy)
    t = np.concatenate([[0.0], np.cumsum(0.5 * (1.0 / w[1:] + 1.0 / w[:-1]) * np.diff(fine))])
    slot = np.arange(-1, 121)  # wheel slots from -4.5 deg - one pitch
    nominal = np.radians(-4.5) + slot * PITCH
    idx = np.mod(slot, 60)
    present = idx < 58
    err = tooth_error * rng.standard_normal(60) * PITCH  # fixed per wheel position: repeats every revolution
    ang = nominal[present]
    actual = ang + err[idx[present]]
    times = np.interp(actual, fine, t) + rng.normal(0.0, 5e-8, ang.shape[0])  # 50 ns timing noise
    keep = (ang >= -PITCH) & (ang <= 4.0 * np.pi + 2 * PITCH)
    grid = np.arange(720) * (4.0 * np.pi / 720)
    return ang[keep], times[keep], idx[present][keep], grid, torque(grid)


@pytest.mark.parametrize("tooth_error", [0.0, 0.01])
def test_ripple_gives_the_inertia_of_a_rigid_engine(tooth_error):
    rng = np.random.default_rng(7)
    rows = []
    for omega0 in (150.0, 140.0, 130.0):
        ang, t, idx, grid, tq = synthetic_cycle(0.0206, 0.8, omega0, rng, tooth_error)
        keep = (np.diff(ang) < 1.5 * PITCH) & ~np.isin(idx[:-1], [0, 56, 57])
        rows.append(ripple_rows(ang, t, keep, grid, tq, np.ones_like(tq), GEO0))
    fit = fit_ripple_inertia(rows)
    # measured: 0.020600 without, 0.020602 with a 1 % tooth-spacing error; friction 0.798-0.800 N m
    assert_allclose(fit.inertia, 0.0206, rtol=2e-3)
    assert abs(fit.inertia - 0.0206) <= 3.0 * fit.inertia_std + 1e-5
    assert_allclose(fit.resisting, 0.8, atol=0.02)
    assert_allclose(fit.per_cycle, 0.0206, rtol=5e-3)


def test_pooling_and_speed_trend():
    j, s, between = pool_random_effects(np.array([0.021, 0.021, 0.021]), np.array([1e-4, 2e-4, 2e-4]))
    assert between == 0.0 and j == pytest.approx(0.021) and s == pytest.approx(1.0 / np.sqrt(1e8 + 2 * 2.5e7))
    j, s, between = pool_random_effects(np.array([0.0211, 0.0210, 0.0212, 0.0192]), np.full(4, 2e-4))
    # one record off by 10 sigma: measured between 0.00093, sigma 0.00048 against the fixed-effect 0.0001
    assert between > 5e-4 and s > 2.0 * 2e-4 / np.sqrt(4)
    w = np.linspace(120.0, 280.0, 9)
    assert speed_trend(0.02 - 1e-5 * (w - 120.0), w) == pytest.approx(0.5 * 1e-5 * 160.0)
    assert speed_trend(np.full(9, 0.02), w) == pytest.approx(0.0, abs=1e-15)
    with pytest.raises(ValueError):
        pool_random_effects(np.array([0.02]), np.array([0.0]))


@pytest.mark.parametrize(("engine", "rpm", "cut_s", "scale", "seed"), [("tue-4gb10", 3000.0, 0.4, 1.12, 3),
                                                                  ("tue-4gb10", 3000.0, 0.4, 0.9, 4),
                                                                  ("deutz-1cyl", 2400.0, 0.3, 1.1, 3)])
def test_simulated_coast_down_finds_the_plant_inertia(engine, rpm, cut_s, scale, seed):
    spec = load_engine(engine)
    plant = dataclasses.replace(spec, node_inertia=spec.node_inertia * scale)
    sim = simulate(plant, rpm, load=0.6, cycles=24 if engine == "tue-4gb10" else 30, seed=seed,
                   effects={"coast_down": {"time_s": cut_s}})
    cycles, _ = assembled_cycles(spec, sim.info, sim.records)
    record = coastdown_record("sim", cycles, EngineModel.from_spec(spec))
    assert record is not None and len(record.rows) >= 10  # the motored cycles after the cut
    cal = commission_inertia([record])
    truth = plant.total_inertia
    # measured: tue +0.27 % at 0.24 sigma (x1.12), +0.40 % at 0.46 sigma (x0.9); sigma 1.1 %, 0.9 %
    assert abs(cal.inertia - truth) <= 2.0 * cal.inertia_std
    assert cal.inertia_std < 0.03 * truth
    assert abs(cal.inertia - spec.total_inertia) > 3.0 * cal.inertia_std  # the preset's J is told apart
    # the friction law against the plant's own friction at the coast-down's speeds (truth per cycle)
    truth_cycles = {c["index"]: c for c in sim.truth["cycles"]}
    cut = [c for c in cycles if c.index in truth_cycles  # motored cycles, by the plant's own IMEP
           and all(cyl["imep_bar"] < 0 for cyl in truth_cycles[c.index]["cylinders"])]
    assert len(cut) >= 10
    rpm = np.array([truth_cycles[c.index]["rpm_mean"] for c in cut])
    fric = np.array([truth_cycles[c.index]["friction_torque_mean_nm"] for c in cut])
    f, s = cal.friction_at(rpm * np.pi / 30.0)
    assert np.all(np.abs(f - fric) <= 2.0 * s) and np.all(s < 0.05 * fric)  # measured: tue within 0.3 sigma, s 2.5 %


def test_refused_where_the_ripple_cannot_read_the_total_inertia():
    # a shaft line with a soft coupling: the ripple reads what moves with the wheel (simulated maruti-3cyl -68 %)
    with pytest.raises(ValueError, match="single-node"):
        coastdown_record("k9k", [], EngineModel.from_spec(load_engine("k9k-4cyl")))
