"""tests/service/test_restart.py's check one level down, on both store backends: SQLite, and PostgreSQL where
FW_TEST_POSTGRES_URL is set (.ci/run starts one; skipped otherwise, saying why). `serve` takes only a --data-dir
folder (SQLite), so the service is assembled as serve assembles it — DataDir on the store, an EngineService on the
demo log looped as fast as it can be read, the real alert engine — and restarted twice on the same database.

Run 1 learns the alert baseline and stores it; while the service is down the stored baseline is moved so that
cylinder 3 reads as leaking against it (test_restart.py's worn ring). Run 2 must compare with it (not relearn),
raise the alert and take alice's acknowledgement; run 3 must get that alert back acknowledged by alice, not raise it
again, and append bob's acknowledgement. Each run's cycles are numbered on from the last stored one, and run 1's
cycles and estimates read back exactly as they were (nothing overwritten; float64 in and out, compared equal)."""

from __future__ import annotations

import pytest
from frictionwatch.service.data_dir import DataDir
from frictionwatch.service.serve import _alerts_factory

from tests.service.serve_helpers import DEMO, demo_service, wait_until
from tests.service.test_restart import _worn_baseline
from tests.service.test_store_backends import store_url  # noqa: F401 - the fixture, on both backends

ENGINE = "genset-v20"
pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]


class Run:
    """One start of the service on the store at ``url``: DataDir.attach says what it took back."""

    def __init__(self, url: str) -> None:
        self.data = DataDir(url)
        self.svc = demo_service(ENGINE, f"mcap:{DEMO}?loop=1", alerts=self.data.with_baseline(_alerts_factory()))
        self.said = self.data.attach(self.svc)
        self.store = self.data.store
        self.svc.start()

    def stored(self, run_id: int) -> int:
        return sum(r["run_id"] == run_id for r in self.store.cycles(ENGINE, 0, 10**9))

    def alerts_on(self, cylinder: int) -> list[dict]:
        return [a for a in self.svc.alert_list(active_only=False)[0] if a["cylinder"] == cylinder]

    def end(self) -> None:
        try:
            self.svc.stop()
        finally:
            self.data.close()


def test_a_restart_keeps_and_continues_everything(store_url):  # noqa: F811
    # ---- run 1: learn the baseline ------------------------------------------------------------------------------
    run1 = Run(store_url)
    try:
        assert run1.said.startswith(f"{ENGINE}: run 1, cycles from 0"), run1.said
        assert wait_until(lambda: run1.store.load_baseline(ENGINE) is not None, timeout=600), \
            "run 1 stored no learnt baseline"
        assert wait_until(lambda: run1.stored(1) >= 250, timeout=300)
    finally:
        run1.svc.stop()
    store = run1.store
    cycles1, estimates1 = store.cycles(ENGINE, 0, 10**9), store.estimates(ENGINE, 0, 10**9)
    last1 = cycles1[-1]["cycle_index"]
    assert [r["cycle_index"] for r in cycles1] == list(range(last1 + 1))  # every cycle, none lost at the stop
    assert estimates1 and {r["run_id"] for r in estimates1} == {1}
    learnt = store.load_baseline(ENGINE)
    assert learnt["bands"][0]["cycles"] == 200  # AlertConfig.baseline_cycles: learnt whole, then stored
    store.save_baseline(ENGINE, _worn_baseline(learnt, 3))  # the ring wears while the service is down
    run1.data.close()

    # ---- run 2: the stored baseline in force, the alert raised and acknowledged -----------------------------------
    run2 = Run(store_url)
    try:
        assert run2.said.startswith(f"{ENGINE}: run 2, cycles from {last1 + 1}"), run2.said
        assert wait_until(lambda: run2.alerts_on(3), timeout=300), "the worn ring raised no alert"
        (alert,) = run2.alerts_on(3)
        assert alert["raised_cycle"] > last1
        assert run2.svc.acknowledge(alert["alert_id"], "alice")["acknowledged_by"] == "alice"
        assert wait_until(lambda: any(a["alert_id"] == alert["alert_id"] and a["state"] == "acknowledged"
                                      for a in run2.store.load_alerts(ENGINE)), timeout=30)
        assert wait_until(lambda: run2.stored(2) >= 100, timeout=300)
    finally:
        run2.end()

    # ---- run 3: the alert back as it was, a second acknowledgement appended ----------------------------------------
    run3 = Run(store_url)
    try:
        last2 = run3.store.latest_cycle(ENGINE)
        assert run3.said.startswith(f"{ENGINE}: run 3, cycles from {last2 + 1}"), run3.said
        (back,) = run3.alerts_on(3)
        assert back["alert_id"] == alert["alert_id"] and back["acknowledged_by"] == "alice"
        again = run3.svc.acknowledge(alert["alert_id"], "bob")
        assert again["acknowledged_by"] == "alice" and [a["by"] for a in again["acknowledgements"]] == ["alice", "bob"]
        assert wait_until(lambda: run3.stored(3) >= 100, timeout=300)
        assert [a["alert_id"] for a in run3.alerts_on(3)] == [alert["alert_id"]], "the worn ring was alerted on again"
    finally:
        run3.svc.stop()

    # ---- what the database holds ----------------------------------------------------------------------------------
    store = run3.store
    try:
        runs = store.runs(ENGINE)
        assert [(r["run_id"], r["first_cycle"]) for r in runs] == [(1, 0), (2, last1 + 1), (3, last2 + 1)]
        rows = store.cycles(ENGINE, 0, 10**9)
        assert [r["cycle_index"] for r in rows] == list(range(len(rows)))  # numbered on, no hole, no overlap
        assert [r["run_id"] for r in rows] == sorted(r["run_id"] for r in rows)
        assert store.cycles(ENGINE, 0, last1) == cycles1  # run 1's rows exactly as they were
        assert [e for e in store.estimates(ENGINE, 0, last1)] == estimates1
        (kept,) = [a for a in store.load_alerts(ENGINE) if a["alert_id"] == alert["alert_id"]]
        assert kept["acknowledged_by"] == "alice" and [a["by"] for a in kept["acknowledgements"]] == ["alice", "bob"]
    finally:
        run3.data.close()
