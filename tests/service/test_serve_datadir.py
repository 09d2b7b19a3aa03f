"""--data-dir wiring (service/serve.py DataDir) against a stand-in of the store interface of the contract
(h-store's service/store provides the real one): the engine is registered with its model, its saved alert baseline
reaches the alert engine, and a StoreListener joins the engine's fan-out and gets every event."""

from __future__ import annotations

import sys
import types

import pytest
from frictionwatch.service.listeners import ServiceEvent
from frictionwatch.service.serve import DataDir

from tests.service.serve_helpers import FakeAlerts, FakeBaseline, demo_service


class FakeStore:
    def __init__(self, url: str) -> None:
        self.url, self.engines, self.closed = url, {}, False
        self.baselines = {"demo-a": {"from_cycle": 7}}

    def register_engine(self, engine_id: str, engine_toml: str) -> int:
        self.engines[engine_id] = engine_toml
        return 1

    def load_baseline(self, engine_id: str) -> dict | None:
        return self.baselines.get(engine_id)

    def close(self) -> None:
        self.closed = True


class FakeStoreListener:
    name = "store"

    def __init__(self, store: FakeStore, engine_id: str) -> None:
        self.store, self.engine_id, self.events = store, engine_id, []

    def on_message_received(self, event: ServiceEvent) -> None:
        self.events.append(event)


@pytest.fixture
def fake_store(monkeypatch):
    store_mod = types.ModuleType("frictionwatch.service.store")
    store_mod.open_store, store_mod.StoreListener = FakeStore, FakeStoreListener
    alerts_mod = types.ModuleType("frictionwatch.service.alerts")
    alerts_mod.Baseline = types.SimpleNamespace(from_dict=lambda d: FakeBaseline(**d))
    monkeypatch.setitem(sys.modules, "frictionwatch.service.store", store_mod)
    monkeypatch.setitem(sys.modules, "frictionwatch.service.alerts", alerts_mod)


def test_data_dir_registers_loads_the_baseline_and_listens(fake_store, tmp_path) -> None:
    data = DataDir(tmp_path / "data")
    assert data.store.url == str(tmp_path / "data" / "frictionwatch.db")
    made = {}

    def alerts(engine_id, spec, baseline=None):
        made[engine_id] = FakeAlerts(spec, baseline=baseline)
        return made[engine_id]

    a = demo_service("demo-a", alerts=data.with_baseline(alerts))
    b = demo_service("demo-b", alerts=data.with_baseline(alerts))
    for svc in (a, b):
        data.attach(svc)
    assert made["demo-a"].baseline == FakeBaseline(7) and made["demo-b"].baseline is None
    assert set(data.store.engines) == {"demo-a", "demo-b"}
    assert data.store.engines["demo-a"] == a.model.to_toml()
    assert "store" in a.fanout.names
    a.fanout.start()
    a.fanout.publish(ServiceEvent("demo-a", None, 0.0, alerts=({"alert_id": 1},)))
    a.fanout.stop()
    listener = next(w.listener for w in a.fanout._workers if w.name == "store")
    assert [e.alerts for e in listener.events] == [({"alert_id": 1},)]
    data.close()
    assert data.store.closed
    for svc in (a, b):
        svc.session.stop()


def test_data_dir_that_is_a_file_is_refused(fake_store, tmp_path) -> None:
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(NotADirectoryError, match="is a file"):
        DataDir(f)
