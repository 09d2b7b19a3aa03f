"""--data-dir wiring (service/serve.py DataDir) with the real store (SQLite in WAL mode) and the real alert engine:
the engine is registered with its model, a baseline saved by an earlier run reaches that engine's alert engine (and
only that one's), and the store listener in the engine's fan-out keeps every cycle the service analysed."""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.service.alert_baseline import Baseline, BaselineLearner
from frictionwatch.service.alerts import AlertConfig, AlertEngine
from frictionwatch.service.serve import DataDir
from frictionwatch.service.store import open_store
from numpy.testing import assert_allclose

from tests.service.serve_helpers import demo_service, wait_until
from tests.service.store_samples import TOML, alert, summary


def _saved_baseline(n_cyl: int) -> Baseline:
    learner = BaselineLearner(n_cyl)
    rng = np.random.default_rng(3)
    for cycle in range(5):
        learner.add(rng.normal(0.0, 0.01, (4, n_cyl)), cycle, 17.0e5)  # commissioned at 17 bar IMEP
    return learner.baseline(0.1)


def test_data_dir_registers_loads_the_baseline_and_keeps_every_cycle(tmp_path) -> None:
    folder = tmp_path / "data"
    earlier = DataDir(folder)  # an earlier run of the service left a baseline for demo-a
    probe = demo_service("probe")
    saved = _saved_baseline(probe.spec.n_cyl)
    probe.session.stop()
    earlier.store.register_engine("demo-a", probe.model.to_toml())
    earlier.store.save_baseline("demo-a", saved.to_dict())
    earlier.close()

    data = DataDir(folder)
    made: dict[str, AlertEngine] = {}

    def alerts(engine_id, spec, baseline=None):
        made[engine_id] = AlertEngine(spec, AlertConfig(), baseline=baseline)
        return made[engine_id]

    a = demo_service("demo-a", alerts=data.with_baseline(alerts))
    b = demo_service("demo-b", alerts=data.with_baseline(alerts))
    try:
        for svc in (a, b):
            data.attach(svc)
        assert made["demo-a"].baseline is not None and made["demo-b"].baseline is None
        assert_allclose(made["demo-a"].baseline.mean, saved.mean, rtol=1e-12)
        assert "store" in a.fanout.names
        a.start()
        assert wait_until(lambda: a.sources_ended, timeout=600.0), "the demo log did not end"
    finally:
        a.stop(timeout=30.0)
        b.session.stop()
        data.close()
    assert a.cycles_ok > 10
    store = open_store(str(folder / "frictionwatch.db"))
    try:
        assert store.model_versions("demo-a")[-1]["version"] >= 1
        rows = store.cycles("demo-a", 0, 10**9)
        assert len(rows) == a.cycles_ok  # the listener committed every cycle the service published
        assert store.latest_cycle("demo-b") is None
    finally:
        store.close()


def test_data_dir_that_is_a_file_is_refused(tmp_path) -> None:
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(NotADirectoryError, match="is a file"):
        DataDir(f)


def test_retention_is_scheduled_and_deletes_only_old_cycles(tmp_path) -> None:
    """--keep-days: a sweep at start and then every retention_every_s (here 0.05 s); rows written 3 days ago go,
    today's stay, alerts stay; a sweep that fails is counted, not raised."""
    folder = tmp_path / "data"
    data = DataDir(folder, keep_days=2.0, retention_every_s=0.05)
    store = data.store
    store.register_engine("eng-1", TOML)
    store.write_batch("eng-1", cycles=[summary(i) for i in range(10)], alerts=[alert(1)])
    with store._transaction() as cur:  # cycles 0..5 written three days ago
        cur.execute("UPDATE cycles SET written_at = written_at - 3 * 86400 WHERE cycle_index < 6")
    data.start_retention()
    try:
        assert wait_until(lambda: data.retention["sweeps"] >= 2, timeout=10.0)
        assert data.retention["cycles"] == 6 and data.retention["errors"] == 0
        assert [r["cycle_index"] for r in store.cycles("eng-1", 0, 100)] == list(range(6, 10))
        assert [a["alert_id"] for a in store.load_alerts("eng-1")] == [1]
    finally:
        data.close()
    assert not data._retention_thread.is_alive()
    broken = DataDir(tmp_path / "other", keep_days=1.0)
    broken.store.close()  # a sweep on a closed store: counted and logged
    assert broken.sweep() == {} and broken.retention["errors"] == 1
    with pytest.raises(ValueError, match="--keep-days must be > 0"):
        DataDir(tmp_path / "third", keep_days=0.0)


def test_a_rebaseline_stored_as_a_reset_keeps_the_old_baseline_out_after_a_restart(tmp_path) -> None:
    folder = tmp_path / "data"
    earlier = DataDir(folder)
    probe = demo_service("probe")
    probe.session.stop()
    earlier.store.register_engine("demo-a", probe.model.to_toml())
    earlier.store.save_baseline("demo-a", _saved_baseline(probe.spec.n_cyl).to_dict())
    earlier.close()

    def alerts(engine_id, spec, baseline=None):
        return AlertEngine(spec, AlertConfig(), baseline=baseline)

    for reset, bands in ((False, 1), (True, 0)):
        data = DataDir(folder)
        if reset:  # what EngineService.rebaseline publishes and the store listener saves
            data.store.register_engine("demo-a", probe.model.to_toml())
            data.store.save_baseline("demo-a", {"reset": True, "at_s": 1.0})
        svc = demo_service("demo-a", alerts=data.with_baseline(alerts))
        try:
            said = data.attach(svc)
            assert f"baseline of {bands} load bands" in said
            assert (svc.alerts.baseline is None) == reset
        finally:
            svc.session.stop()
            data.close()
