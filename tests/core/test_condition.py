"""Engine-condition flags and the change detector (core/monitor/checks/condition.py, core/monitor/checks/change.py).

Unit checks on constructed inputs first (sibling deviations, the compression rise under sensor errors, the CUSUM's
false-alarm rate and delay, the one-off forgetting step); then simulator logs the monitor is never told about: blow-by
and a worn ring in one cylinder flagged on that cylinder, healthy logs with combustion variability and a load step
(all default effects) free of condition flags in >= 99 % of cycles, and a ring wear starting mid-run flagged within
200 cycles and followed by the estimate (truth within 2 sigma again within 200 cycles).
"""

import numpy as np
import pytest
from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.kinematics import kinematics
from frictionwatch.core.monitor.checks.change import ChangeSettings, detect_change, detect_change_reference
from frictionwatch.core.monitor.checks.condition import DEFAULT_SETTINGS, compression_rise, sibling_deviation
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from frictionwatch.core.monitor.identify.posterior import Prior, solve_posterior
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import run
from numpy.testing import assert_allclose

MARUTI = load_engine("maruti-3cyl")
CONDITION_KINDS = ("blow_by", "ring_wear", "model_misfit", "condition_change")  # estimate_reset: an estimator event


def test_sibling_deviation_is_against_the_median():
    assert_allclose(sibling_deviation(np.array([1.0, 2.0, 4.0])), [-1.0, 0.0, 2.0])
    assert_allclose(sibling_deviation(np.array([1.0, 1.0, 0.5, 1.0])), [0.0, 0.0, -0.5, 0.0])
    assert_allclose(sibling_deviation(np.array([1.0, 2.0])), [-1.0, 1.0])
    assert_allclose(sibling_deviation(np.array([3.0])), [0.0])


def _compression_trace(spec, grid, mass=1.0, n=1.3):
    """Polytropic compression p = p_ivc (V_ivc / V)^n of each cylinder on cylinder 1's grid, trapped mass x mass."""
    p = np.empty((spec.n_cyl, grid.shape[0]))
    for k in range(spec.n_cyl):
        local = np.mod(grid - spec.firing_angles[k] + 2 * np.pi, 4 * np.pi) - 2 * np.pi
        x, _, _ = kinematics(local, np.asarray(spec.friction_params())[:3])
        vol = spec.clearance_volume + spec.piston_area * (x - x.min())
        p[k] = 1e5 * mass * (vol.max() / vol) ** n
    return p


def test_compression_rise_ignores_a_gain_error_and_sees_a_mass_loss():
    grid = np.linspace(0.0, 4 * np.pi, 720, endpoint=False)
    p = _compression_trace(MARUTI, grid)
    base = compression_rise(MARUTI, grid, p, DEFAULT_SETTINGS)
    assert np.ptp(base) < 1e-3 and np.all(base > 1.0)  # identical cylinders; a rise of e^1 at least
    gained = p.copy()
    gained[1] *= 1.05  # a 5 % gain error: the same ratio
    assert_allclose(compression_rise(MARUTI, grid, gained, DEFAULT_SETTINGS), base, atol=1e-12)
    leaking = p.copy()
    leaking[1] = _compression_trace(MARUTI, grid, n=1.2)[1]  # mass lost during compression: a lower exponent
    dev = sibling_deviation(compression_rise(MARUTI, grid, leaking, DEFAULT_SETTINGS))
    assert dev[1] < -0.05 and abs(dev[0]) < 1e-3


def _posterior(value: float, p: int = 2) -> object:
    """A posterior whose friction parameters are all ``value`` (rows of ones then give value * p)."""
    acc = Accumulator.empty(p, 1)
    prior = Prior(np.eye(p), np.full(p, value), np.full(p, 1e-6))
    return solve_posterior(acc, prior, np.zeros(1), lower=-np.inf)


def test_change_detector_rare_false_alarms_and_a_prompt_alarm_after_a_step():
    rng = np.random.default_rng(5)
    settings = ChangeSettings()
    rows = np.eye(2)
    smooth = _posterior(0.0)
    det, alarms, first = None, 0, None
    n, onset, step = 3000, 2000, 1.0  # a one-sigma step of cylinder 2's innovation
    for i in range(n):
        u = rng.standard_normal(2) + (np.array([0.0, step]) if i >= onset else 0.0)
        cycle = solve_posterior(Accumulator.empty(2, 1), Prior(np.eye(2), u, np.full(2, 1e-6)), np.zeros(1),
                                lower=-np.inf)
        det, alarm = detect_change(det, cycle, smooth, rows, settings)
        if i < onset:
            alarms += int(alarm.any())
        elif first is None and alarm.any():
            first = i - onset
            assert alarm[1] and not alarm[0]
    assert alarms <= 2  # h = 10 at k = 0.5: an in-control run length far beyond 2000 cycles
    assert first is not None and first < 60  # ~(h + 1.2) / (step - k) = 22 cycles expected


def _cycle_posterior(u: np.ndarray):
    return solve_posterior(Accumulator.empty(u.shape[0], 1), Prior(np.eye(u.shape[0]), u, np.full(u.shape[0], 1e-6)),
                           np.zeros(1), lower=-np.inf)


@pytest.mark.parametrize("detector", ["detect_change", "detect_change_reference"])
def test_change_detector_follows_the_smoothed_estimate_while_it_learns(detector):
    """The smoothed estimate drifts (here 0.005 sigma a cycle in cylinder 2, as a weakly identified genset-v20
    cylinder's does while it learns: design note 151) while the engine and each cycle's estimate stay put: the
    innovation trends, the EWMA mean lags it by ~1 sigma, and a detector that did not follow the smoothed estimate's
    motion alarmed at cycle 243 and every ~100 cycles after (seen failing so). Following it: no alarm in 1500 cycles, and a
    one-sigma step of the cycle estimate on top of the drift still alarmed on its cylinder within 60 cycles."""
    step_fn = {"detect_change": detect_change, "detect_change_reference": detect_change_reference}[detector]
    rng = np.random.default_rng(11)
    settings, rows = ChangeSettings(), np.eye(2)
    det, alarms, first = None, [], None
    onset = 1500
    for i in range(1800):
        smooth = _cycle_posterior(np.array([20.0, 20.0 + 0.005 * i]))
        u = 20.0 + rng.standard_normal(2) + (np.array([0.0, 1.0]) if i >= onset else 0.0)
        det, alarm = step_fn(det, _cycle_posterior(u), smooth, rows, settings)
        if alarm.any() and i < onset:
            alarms.append(i)
        elif alarm.any() and first is None:
            first = i - onset
            assert alarm[1] and not alarm[0]
    assert alarms == []
    assert first is not None and first < 60


def test_discounted_accumulator_keeps_the_systematic_covariance():
    rng = np.random.default_rng(2)
    acc = Accumulator.empty(2, 4)
    for _ in range(50):
        a = rng.standard_normal((4, 2))
        acc = acc.fold(acc.cycle_terms(a, a @ [1.0, 2.0] + 0.1 * rng.standard_normal(4), np.ones(4), 1), 0.99)
    low = acc.discounted(0.1)
    assert_allclose([low.weight, low.rows, low.yty], [0.1 * acc.weight, 0.1 * acc.rows, 0.1 * acc.yty])
    prior = Prior(np.eye(2), np.zeros(2), np.full(2, 1e3))
    sys_var = np.full(4, 0.01)
    full, part = solve_posterior(acc, prior, sys_var, -np.inf), solve_posterior(low, prior, sys_var, -np.inf)
    assert_allclose(part.params, full.params, rtol=1e-4)  # the same equations, less weight
    cov_sys_full = full.covariance - full.cov_statistical
    cov_sys_part = part.covariance - part.cov_statistical
    assert_allclose(cov_sys_part, cov_sys_full, rtol=1e-3, atol=1e-12)
    assert np.all(np.diag(part.cov_statistical) > 5 * np.diag(full.cov_statistical))
    with pytest.raises(ValueError):
        acc.discounted(0.0)


# ---- simulator logs --------------------------------------------------------------------------------------------

def _monitor(spec, rpm, load, cycles, effects=(), seed=1, **kw):
    sim = simulate(spec, rpm, load, cycles, seed=seed, effects=[parse_effect(e) for e in effects], **kw)
    out = []
    for outcome in run(spec, sim.info, sim.records):  # the one pipeline: assembler, monitor, calibration watches
        assert outcome.ok or outcome.stage == "assembly", outcome  # the monitor refuses no cycle
        if outcome.ok:
            out.append(outcome.result.slim())
    return sim.truth, out


def _condition_flags(res) -> list[str]:
    return [f for f in res.flags if f.startswith(CONDITION_KINDS)]


@pytest.mark.parametrize("effect", ["blow_by:cylinder=2", "ring_wear:cylinder=2"])
def test_blow_by_and_worn_ring_flag_their_cylinder(effect):
    _, out = _monitor(MARUTI, 3000.0, 0.8, 120, [effect])
    late = out[60:]
    on_cyl2 = np.mean([any(f.endswith("_cyl2") and not f.startswith("misfire") for f in r.flags) for r in late])
    others = np.mean([any(f.endswith(("_cyl1", "_cyl3")) for f in _condition_flags(r)) for r in late])
    assert on_cyl2 >= 0.9 and others == 0.0


@pytest.mark.slow
@pytest.mark.parametrize("engine, rpm, load", [("maruti-3cyl", 3000.0, 0.8), ("k9k-4cyl", 1700.0, 0.69)])
def test_healthy_logs_raise_no_condition_flag(engine, rpm, load):
    """3 % COV of IMEP, a load step mid-log, all default effects: condition flags in at most 1 % of the cycles."""
    spec = load_engine(engine)
    t_step = 150 * 120.0 / rpm  # about cycle 150
    _, out = _monitor(spec, rpm, load, 300, seed=4, cov_imep=0.03, load_steps=[(t_step, 0.6 * load)])
    flagged = [r.index for r in out if _condition_flags(r)]
    assert len(flagged) <= 0.01 * len(out), flagged


def _total_truth(truth) -> np.ndarray:
    return np.array([c["friction_torque_mean_nm"] for c in truth["cycles"]])


@pytest.mark.slow
@pytest.mark.parametrize("effect", ["ring_wear:cylinder=2,from_cycle=200", "misfire:cylinder=2,from_cycle=200"])
def test_a_change_mid_run_is_flagged_and_followed(effect):
    """Onset at cycle 200 of 600: a flag on the changed cylinder within 200 cycles, none before; from 200 cycles
    after the onset on, the smoothed total friction holds the new truth within 2 sigma (not the two states' mix)."""
    truth, out = _monitor(MARUTI, 3000.0, 0.8, 600, [effect])
    on_cyl2 = [r.index for r in out if any(f.endswith("_cyl2") for f in r.flags)]
    assert all(i >= 200 for i in on_cyl2) and on_cyl2 and on_cyl2[0] < 400, on_cyl2[:5]
    after = _total_truth(truth)[200:].mean()
    late = [r for r in out if r.index >= 400]
    err = np.array([(r.smoothed.total_friction_torque - after) / r.smoothed.total_friction_torque_sigma for r in late])
    assert np.mean(np.abs(err) <= 2.0) >= 0.95, err.round(1)
