"""Accuracy of the per-cycle monitor against the plant simulator's truth (issue 4; design.md §5).

The chain under test is the product's own: core.plant.simulate (time-domain RK4 plant with its default realistic effects:
sensor noise, combustion variability COV 2 %, cylinder-to-cylinder fuel spread, flexible crank, variable inertia,
tooth-spacing errors 0.03 deg rms) -> the one pipeline (service.pipeline.run: the cycle assembler, the monitor with its default config, the
running calibration watches).
Each log is simulated and monitored once per test session (session-scoped cache).

Targets (design.md §5): total FMEP within 2 %; per-cylinder mean friction within 5 % (maruti-3cyl, k9k-4cyl, 200
cycles); genset-v20 within 10 % for the cylinders the data resolve (the suite runs 1000 cycles at one load; the full
3 loads x 2000 cycles run is ``python -m bench.accuracy_v20``); deutz-1cyl instantaneous friction NRMSE <= 10 %
(rms error / rms of the true trace); honest uncertainty: truth within 2 sigma for >= 90 % of cylinders; ring wear in
one cylinder shows in that cylinder.
"""

from dataclasses import dataclass

import numpy as np
import pytest
from frictionwatch.core.model.engine import EngineSpec, load_engine
from frictionwatch.core.monitor.report.results import CycleResult, change_sigma
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.plant.simulate import simulate

from tests.sim_logs import pipeline_results

pytestmark = pytest.mark.slow
WARMUP = 50  # cycles before the smoothed estimate is judged (also skipped in the per-cycle NRMSE)


@dataclass
class Run:
    spec: EngineSpec
    truth: dict
    results: list[CycleResult]
    skipped: dict

    @property
    def last(self) -> CycleResult:
        return self.results[-1]

    def truth_cyl(self) -> np.ndarray:
        return np.array([c["friction_torque_mean_nm"] for c in self.truth["cylinders"]])


@pytest.fixture(scope="session")
def monitored():
    cache: dict = {}

    def get(name: str, rpm: float, load: float, cycles: int, effects: dict | None = None, seed: int = 1) -> Run:
        key = (name, rpm, load, cycles, repr(effects), seed)
        if key not in cache:
            spec = load_engine(name)
            sim = simulate(spec, rpm, load, cycles, seed=seed, effects=effects)
            results, skipped = pipeline_results(spec, sim)
            cache[key] = Run(spec, sim.truth, results, dict(skipped))
        return cache[key]

    return get


def _total_error(run: Run) -> tuple[float, float]:
    """Relative error and relative 1-sigma of the smoothed total FMEP."""
    est = run.last.smoothed
    truth = run.truth["fmep_bar"] * 1e5
    return est.total_fmep / truth - 1.0, est.total_fmep_sigma / truth


def _check_points(get, name: str, points: list[tuple[float, float]], cycles: int, per_cyl_tol: float):
    inside, count = 0, 0
    for rpm, load in points:
        run = get(name, rpm, load, cycles)
        assert not run.skipped, f"{name} {rpm} rpm: the pipeline lost cycles {run.skipped}"
        assert len(run.results) == cycles
        err, sig = _total_error(run)
        assert abs(err) <= 0.02, f"{name} {rpm}/{load}: total FMEP off by {err:+.2%}"
        est = run.last.smoothed
        truth = run.truth_cyl()
        assert est.resolved.all(), f"{name} {rpm}/{load}: unresolved cylinders {np.flatnonzero(~est.resolved) + 1}"
        rel = est.friction_torque_mean / truth - 1.0
        assert np.all(np.abs(rel) <= per_cyl_tol), f"{name} {rpm}/{load}: per-cylinder errors {np.round(rel * 100, 1)} %"
        inside += int(np.sum(np.abs(est.friction_torque_mean - truth) <= 2 * est.friction_torque_mean_sigma))
        inside += int(abs(err) <= 2 * sig)
        count += truth.size + 1
    assert inside >= 0.9 * count, f"{name}: only {inside} of {count} estimates within 2 sigma"


def test_k9k_total_and_per_cylinder_friction(monitored):
    # engines.md §3: the three Seddak points 1100 / 1400 / 1700 rpm (67.5, 121, 166 N m of 240 N m rated)
    _check_points(monitored, "k9k-4cyl", [(1100.0, 0.28), (1400.0, 0.5), (1700.0, 0.69)], 200, 0.05)


def test_k9k_does_not_need_the_true_coefficients_as_prior():
    """The baseline a0 only fixes the shape inside each group; with it off by -40..+50 % per term the per-cylinder
    means still meet the target (the simulator's truth is the preset's a0, so this guards against a prior that
    merely repeats the answer)."""
    spec = load_engine("k9k-4cyl")
    sim = simulate(spec, 1400.0, 0.5, 200, seed=1)
    cfg = MonitorConfig(prior_coefficients=spec.friction.coefficients * np.array([1.5, 0.7, 1.3, 0.8, 1.2, 0.6]))
    results, skipped = pipeline_results(spec, sim, cfg)
    assert not skipped
    est = results[-1].smoothed
    truth = np.array([c["friction_torque_mean_nm"] for c in sim.truth["cylinders"]])
    assert abs(est.total_fmep / (sim.truth["fmep_bar"] * 1e5) - 1.0) <= 0.02
    assert est.resolved.all()
    assert np.all(np.abs(est.friction_torque_mean / truth - 1.0) <= 0.05)
    assert np.all(np.abs(est.friction_torque_mean - truth) <= 2 * est.friction_torque_mean_sigma)


def test_maruti_total_and_per_cylinder_friction(monitored):
    _check_points(monitored, "maruti-3cyl", [(2000.0, 0.5), (3000.0, 0.8), (5400.0, 0.8)], 200, 0.05)


def test_deutz_instantaneous_friction(monitored):
    # engines.md §3: idle 1570 rpm (friction = indicated torque), 2600 rpm / 27 N m, and a middle point
    for rpm, load in [(1570.0, 0.0), (2000.0, 0.5), (2600.0, 0.8)]:
        run = monitored("deutz-1cyl", rpm, load, 150)
        err, sig = _total_error(run)
        assert abs(err) <= 0.02 and abs(err) <= 2 * sig + 0.002, f"deutz {rpm}: total {err:+.2%} (sigma {sig:.2%})"
        nrmse = []
        for res in run.results[WARMUP:]:
            true_trace = np.asarray(run.truth["cycles"][res.index]["friction_torque_grid_nm"])
            assert true_trace.shape == res.friction_torque.shape
            nrmse.append(np.sqrt(np.mean((res.friction_torque - true_trace) ** 2) / np.mean(true_trace**2)))
        assert np.mean(nrmse) <= 0.10 and np.max(nrmse) <= 0.15, f"deutz {rpm}: NRMSE {np.mean(nrmse):.1%}"
        # the direct rigid balance (paper 001 Eq. 26) is kept beside it for the discrepancy workflow
        assert run.last.friction_torque_balance is not None


def test_genset_v20_resolved_cylinders(monitored):
    run = monitored("genset-v20", 1500.0, 1.0, 1000)
    err, sig = _total_error(run)
    assert abs(err) <= 0.02, f"V20 total FMEP off by {err:+.2%}"
    assert abs(err) <= 2 * sig
    est = run.last.smoothed
    truth = run.truth_cyl()
    # unresolved cylinders carry no number, resolved ones meet the 10 % target and their sigma is honest
    assert np.all(np.isnan(est.friction_torque_mean[~est.resolved]))
    assert est.resolved.sum() >= 3, f"only {est.resolved.sum()} of 20 cylinders resolved after 1000 cycles"
    got = est.friction_torque_mean[est.resolved]
    rel = got / truth[est.resolved] - 1.0
    assert np.all(np.abs(rel) <= 0.10), np.round(rel * 100, 1)
    inside = np.abs(got - truth[est.resolved]) <= 2 * est.friction_torque_mean_sigma[est.resolved]
    assert inside.mean() >= 0.9
    # an unresolved cylinder is one the speed signal cannot separate from its siblings yet
    assert np.all(est.data_gain[~est.resolved] < 0.5)


@pytest.mark.parametrize("name, rpm, load, worn", [("k9k-4cyl", 1400.0, 0.5, 2), ("maruti-3cyl", 3000.0, 0.8, 3)])
def test_ring_wear_shows_in_that_cylinder(monitored, name, rpm, load, worn):
    nominal = monitored(name, rpm, load, 200)
    wear = monitored(name, rpm, load, 200, effects={"ring_wear": {"cylinder": worn}})
    k = worn - 1
    est = wear.last.smoothed
    others = np.delete(np.arange(wear.spec.n_cyl), k)
    assert est.resolved.all()
    # the worn cylinder has the highest friction of all
    assert int(np.argmax(est.friction_torque_mean)) == k
    # ... and rose against its own baseline (same engine and wheel without the fault) more than any sibling, by
    # more than the noise of a difference of two estimates
    base = nominal.last.smoothed
    rise = est.friction_torque_mean - base.friction_torque_mean
    assert int(np.argmax(rise)) == k
    # (the calibration's part of the sigmas is the same in both runs and cancels in the rise: change_sigma)
    assert rise[k] - np.max(rise[others]) > 2 * np.hypot(change_sigma(est)[k], change_sigma(base)[k]) / 2
    # the nominal engine has no cylinder standing out like that
    assert np.max(base.friction_torque_mean) - np.median(base.friction_torque_mean) < 0.5 * rise[k]
    # the pressure side agrees: blow-by lowers the worn cylinder's peak pressure
    assert wear.last.pmax[k] < np.median(wear.last.pmax[others])
