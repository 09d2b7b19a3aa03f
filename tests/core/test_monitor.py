"""Contract of the per-cycle monitor: explicit state in and out, typed result, JSON with the truth file's keys, bad
input as a typed rejection with a reason, the Eq. 6 path for a misfiring cylinder. A short simulated K9K log
(simulator -> CycleAssembler) is the input; accuracy lives in test_monitor_accuracy.py."""

import dataclasses
import json

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.monitor import CycleRejected, MonitorConfig, initial_state, process_cycle
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.drivers.assembly.cycles import CycleAssembler
from numpy.testing import assert_allclose

SPEC = load_engine("k9k-4cyl")


def _log(cycles, effects=None):
    sim = simulate(SPEC, 1400.0, 0.5, cycles, seed=3, effects=effects)
    asm = CycleAssembler(sim.info, SPEC.n_cyl, SPEC.firing_angles, grid_points=720,
                         speed_range_rpm=SPEC.speed_range_rpm)
    return sim.truth, [c for r in sim.records for c in asm.feed(r)] + asm.flush()


@pytest.fixture(scope="module")
def log():
    return _log(30)


def _run(cycles, cfg=None):
    state = initial_state(SPEC, cfg)
    out = []
    for c in cycles:
        state, res = process_cycle(SPEC, state, c, cfg)
        out.append(res)
    return state, out


def test_state_in_and_out_is_explicit_and_pure(log):
    _, cycles = log
    s0 = initial_state(SPEC)
    info0 = s0.accumulator.info.copy()
    s1, r1 = process_cycle(SPEC, s0, cycles[0])
    assert s1 is not s0 and s1.cycles == 1 and s0.cycles == 0
    assert_allclose(s0.accumulator.info, info0)  # the input state is never modified
    # same state + same cycle -> same result (no hidden module state)
    s1b, r1b = process_cycle(SPEC, s0, cycles[0])
    assert_allclose(r1b.friction_torque, r1.friction_torque)
    assert_allclose(s1b.params, s1.params)


def test_result_fields_shapes_and_physics(log):
    truth, cycles = log
    _, out = _run(cycles)
    res = out[-1]
    z, n = SPEC.n_cyl, cycles[-1].grid.shape[0]
    assert res.imep.shape == res.pmax.shape == res.pmax_angle.shape == (z,)
    assert res.smoothed.coefficients.shape == res.cycle.coefficients_sigma.shape == (z, 6)
    assert res.friction_torque.shape == (n,) and res.friction_torque_cyl.shape == (z, n)
    assert_allclose(res.friction_torque, res.friction_torque_cyl.sum(axis=0))
    assert res.speed_measured.shape == res.speed_model.shape == (n,)
    assert res.residual_harmonics.ndim == 1 and np.iscomplexobj(res.residual_harmonics)
    # IMEP against the truth (issue 4 asks 1 % on real data). The monitor's is over each cylinder's own firing cycle
    # (-360..+360 deg around its TDC: a compression with its own combustion; a cylinder firing more than 360 deg
    # into the cycle reports the cycle before's), the truth's over the assembled cycle (an expansion with the next
    # cycle's compression and early combustion): per cycle they differ by the combustion variability (measured up
    # to 0.9 %; over a steady run the two windows agree, tests/core/test_transient.py).
    tc = truth["cycles"][res.index]
    imep_truth = np.array([c["imep_bar"] for c in tc["cylinders"]]) * 1e5
    assert_allclose(res.imep, imep_truth, rtol=0.02)
    assert np.all(np.abs(np.degrees(res.pmax_angle)) < 40)  # peak after firing TDC (engines.md §3: ~14 deg ATDC)
    assert_allclose(res.rpm_mean, tc["rpm_mean"], rtol=1e-4)
    assert 0.95 < res.r_squared <= 1.0
    assert res.smoothed.weight > 0 and np.all(res.smoothed.friction_torque_mean_sigma > 0)


def test_slim_copy_drops_the_traces_and_keeps_every_value(log):
    _, cycles = log
    _, out = _run(cycles[:3])
    res = out[-1]
    per_cyl = res.friction_torque_cyl  # put on the grid when first asked for, then cached
    assert res.friction_torque_cyl is per_cyl and res.friction_torque_cyl_time.shape == (SPEC.n_cyl, MonitorConfig().time_samples)
    slim = res.slim()
    assert slim.slim() is slim and res.friction_torque_cyl is per_cyl  # the whole result is untouched
    for name in ("grid", "friction_torque", "friction_torque_cyl_time", "time_angles", "speed_measured",
                 "speed_model", "friction_torque_balance", "friction_torque_cyl"):
        assert getattr(slim, name) is None, name
    assert json.dumps(slim.to_json()) == json.dumps(res.to_json())
    for f in dataclasses.fields(res):
        if getattr(slim, f.name) is not None:
            assert getattr(slim, f.name) is getattr(res, f.name), f.name


def test_to_json_uses_the_truth_file_keys(log):
    truth, cycles = log
    _, out = _run(cycles[:3])
    doc = json.loads(json.dumps(out[-1].to_json()))
    assert set(truth["cylinders"][0]) & set(doc["cylinders"][0]) >= {"cylinder", "friction_torque_mean_nm",
                                                                      "fmep_bar", "imep_bar", "coefficients",
                                                                      "coefficients_normalised"}
    assert "fmep_bar" in doc and len(doc["cylinders"]) == SPEC.n_cyl
    assert [c["cylinder"] for c in doc["cylinders"]] == [1, 2, 3, 4]
    assert all(len(c["coefficients"]) == 6 for c in doc["cylinders"])
    # after three cycles the split among cylinders is not resolved yet: reported as None, never as a number
    for k, c in enumerate(doc["cylinders"]):
        assert c["friction_torque_mean_nm"] is None and c["friction"]["status"] != "measured"
        assert not out[-1].smoothed.resolved[k]
    one = json.loads(json.dumps(out[-1].to_json(smoothed=False)))
    assert one["estimate"] == "cycle"


def test_bad_cycles_are_rejected_with_a_reason(log):
    _, cycles = log
    state = initial_state(SPEC)
    c = cycles[1]
    with pytest.raises(CycleRejected) as e:
        process_cycle(SPEC, state, dataclasses.replace(c, pressure=c.pressure[:3]))
    assert e.value.reason == "bad_pressure"
    p = c.pressure.copy()
    p[1, 100:140] = np.nan  # a 40-sample hole: not repairable honestly
    with pytest.raises(CycleRejected, match="cylinder 2"):
        process_cycle(SPEC, state, dataclasses.replace(c, pressure=p))
    with pytest.raises(CycleRejected) as e:
        process_cycle(SPEC, state, dataclasses.replace(c, tooth_ticks=c.tooth_ticks[:40],
                                                       tooth_angle=c.tooth_angle[:40],
                                                       tooth_index=c.tooth_index[:40]))
    assert e.value.reason == "bad_teeth"
    p = c.pressure.copy()
    p[2, 300] = np.nan  # one lost sample is repaired and flagged
    _, res = process_cycle(SPEC, state, dataclasses.replace(c, pressure=p))
    assert "pressure_repaired_cyl3" in res.flags
    assert not any(f.startswith("sensor_pressure_nonpositive") for f in res.flags)
    # a channel reading 0 Pa absolute (clipped at its converter's floor) or less (pegged wrong): flagged, and the
    # flag withholds that cylinder's figures
    p = c.pressure.copy()
    p[1, 100:140] = 0.0
    _, res = process_cycle(SPEC, state, dataclasses.replace(c, pressure=p))
    assert "sensor_pressure_nonpositive_cyl2" in res.flags
    assert [f for f in res.flags if f.startswith("sensor_pressure_nonpositive")] == ["sensor_pressure_nonpositive_cyl2"]
    from frictionwatch.core.monitor.report.figure_status import split_flag, withholds

    assert withholds(split_flag("sensor_pressure_nonpositive_cyl2")[0])
    # no load reading at all: the cycle is still analysed, the mean is not measured and it says so
    _, res = process_cycle(SPEC, state, dataclasses.replace(c, load_torque=float("nan"), load_power=float("nan")))
    assert "no_load_measurement" in res.flags and np.isnan(res.friction_balance)


def test_misfiring_cylinder_is_shared_as_motored():
    _, cycles = _log(12, effects={"misfire": {"cylinder": 2, "probability": 1.0}})
    _, out = _run(cycles, MonitorConfig(warmup_cycles=2))
    res = out[-1]
    assert "misfire_cyl2" in res.flags
    assert res.imep[1] < 0.15 * np.median(res.imep)
    # Eq. 6: the motored cylinder's prior is its motored friction, the firing ones share the rest
    prior = res.smoothed.prior_friction_torque_mean
    assert_allclose(prior.sum(), np.nanmean([r.friction_balance for r in out]), rtol=0.05)  # NaN: no cycle before
    assert 0 < prior[1] < 2.0 * np.median(prior)
