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
