"""The alert engine's pressure statistics by core/monitor/checks/pressure_statistics.py's kernel are the numpy reference's
(``AlertEngine.statistics_reference``, the functions of service.alert_interface) to the last bit: every event and
every cycle's statistics of a run (a worn ring, a leak, a load step learnt as a new band) on a 20-, 4- and
3-cylinder engine, and the statistics alone on 1, 2 and 5 cylinders (1 and 2: no siblings' median, no long-run
factor). The demo log looped with faults: bench_service_cycle's events digest, base against this (design note 94)."""

import numpy as np
import pytest
from frictionwatch.service import alerts
from numpy.testing import assert_allclose

from bench.bench_alert_engine import fold, synthetic_run


def _fold_both(run: dict, monkeypatch) -> tuple[list, list, list, list]:
    _, events, stats = fold(alerts.AlertEngine, run, True)
    with monkeypatch.context() as m:
        m.setattr(alerts.AlertEngine, "statistics", alerts.AlertEngine.statistics_reference)
        _, events_ref, stats_ref = fold(alerts.AlertEngine, run, True)
    return events, events_ref, stats, stats_ref


@pytest.mark.parametrize("engine", ["genset-v20", "k9k-4cyl", "maruti-3cyl"])
def test_a_run_through_the_kernel_is_the_references(engine, monkeypatch):
    run = synthetic_run(engine, 1000, 94, friction=engine in ("genset-v20", "k9k-4cyl"))  # (a worn cylinder 4)
    events, events_ref, stats, stats_ref = _fold_both(run, monkeypatch)
    assert events == events_ref  # kind, ids, cycles, severity, the message and the evidence's JSON
    assert any(e[0] == "raised" and e[3] == "blow_by" for e in events)
    used = [x is not None for x in stats]
    assert used == [r is not None for r in stats_ref] and sum(used) > 500
    for x, r in zip(stats, stats_ref, strict=True):
        if x is not None:  # z_leak, effect, z_ratio, the EWMA's change, the variances and long-run factors...
            assert_allclose(x, r, rtol=0.0, atol=0.0, equal_nan=True)  # the same IEEE operations in order


@pytest.mark.parametrize("z", [1, 2, 5])
def test_the_statistics_alone_are_the_references(z):
    from frictionwatch.service.alert_baseline import BaselineLearner
    from frictionwatch.service.alert_interface import LeakWeights

    rng = np.random.default_rng(z)
    learner = BaselineLearner(z)
    for i in range(60):
        learner.add(rng.standard_normal((4, z)) * 1e-3, i, 9e5)
    band = learner.band(0.1)
    spec = type("Spec", (), {"n_cyl": z})()
    kernel, reference = alerts.AlertEngine(spec), alerts.AlertEngine(spec)
    for e in (kernel, reference):
        e._leak_weights = lw = LeakWeights.of(band)
        e._weights_rows = np.array((lw.w1, lw.w2, lw.s_sd, lw.sd_ratio))
    for n in range(1, 300):
        x = band.mean + rng.standard_normal((4, z)) * 1e-3 + (2e-3 if n > 150 else 0.0)
        g, var, band_var = max(1 / 30, 1 / n), 0.02 + 1e-4 * n, 1 / 60
        a, b = kernel.statistics(x, band, g, var, band_var), reference.statistics_reference(x, band, g, var, band_var)
        for u, v in ((a[0], b[0]), (a[1].z_leak, b[1].z_leak), (a[1].effect, b[1].effect),
                     (a[1].z_ratio, b[1].z_ratio), (a[2], b[2]), (kernel._ewma, reference._ewma),
                     (kernel.long_run_variance.state, reference.long_run_variance.state)):
            assert_allclose(u, v, rtol=0.0, atol=0.0)
        assert kernel.long_run_variance.n == reference.long_run_variance.n == n
    assert (z < 3) == (a[2] == (1.0, 1.0))  # no siblings' median: no long-run factor


def test_load_kernels_is_the_signature_a_run_uses_and_changes_nothing(monkeypatch):
    """``load_kernels`` (serve's start, design note 100) compiles the one signature the statistics call with: a
    run with a band in use after it adds none; and it leaves the engine as it was (the run's events and
    statistics equal a run without the call)."""
    from frictionwatch.core.monitor.checks.pressure_statistics import pressure_statistics_kernel

    run = synthetic_run("genset-v20", 400, 100)
    alerts.AlertEngine(run["spec"]).load_kernels()
    loaded = list(pressure_statistics_kernel.signatures)
    assert len(loaded) == 1
    _, events, stats = fold(alerts.AlertEngine, run, True)
    assert sum(x is not None for x in stats) > 100  # the kernel was used
    assert list(pressure_statistics_kernel.signatures) == loaded
    original = alerts.AlertEngine.__init__

    def loading(self, *a, **k):
        original(self, *a, **k)
        self.load_kernels()

    monkeypatch.setattr(alerts.AlertEngine, "__init__", loading)
    _, events_loaded, stats_loaded = fold(alerts.AlertEngine, run, True)
    assert events_loaded == events
    for x, r in zip(stats_loaded, stats, strict=True):
        assert (x is None) == (r is None)
        if x is not None:
            assert_allclose(x, r, rtol=0.0, atol=0.0, equal_nan=True)
