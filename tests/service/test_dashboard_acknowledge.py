"""Acknowledging an alert from the dashboard, in headless Chromium: the alert with its evidence, a wrong token
refused in words (401), the right one accepted, the name it was acknowledged by shown and kept by the service.

The service runs in this process (create_app on the bundled demo log) with a stand-in alert engine that raises one
alarm at the first cycle: the demo log is healthy, so the real alert engine must raise nothing on it, and this test
is about the page, not about when an alert is raised (service/alerts.py has its own tests).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import pytest
import uvicorn

from tests.service.dashboard_browser import Chromium, find_chromium, free_port

if find_chromium() is None:
    pytest.skip("no chromium on PATH: scripts/install-chromium.sh installs Debian's", allow_module_level=True)

from frictionwatch.drivers.source import open_source  # noqa: E402 - after the skip: the service needs numba warm
from frictionwatch.drivers.timebase import Clocks  # noqa: E402
from frictionwatch.service.api import create_app  # noqa: E402
from frictionwatch.service.engine_service import EngineService  # noqa: E402
from frictionwatch.service.pipeline import resolve_model  # noqa: E402

DEMO = Path(__file__).resolve().parents[2] / "replay_logs" / "demo.mcap"
TOKEN = "acknowledge-test-token"
pytestmark = pytest.mark.timeout(1200)  # the numba kernels compile in this process if no cache is at hand


@dataclass
class Raised:
    kind: str
    alert: object


@dataclass
class StandInAlert:
    doc: dict

    def to_dict(self) -> dict:
        return dict(self.doc)


@dataclass
class OneAlarm:
    """The alert engine's interface (the contract of issue #17): one ring_wear alarm on cylinder 3 at the first
    cycle, with evidence in the contract's units."""

    spec: object
    alerts: dict[int, StandInAlert] = field(default_factory=dict)
    baseline: object = None

    def update(self, result) -> list[Raised]:
        if self.alerts:
            return []
        c = int(result.index)
        self.alerts[1] = StandInAlert({
            "alert_id": 1, "cylinder": 3, "kind": "ring_wear", "severity": "alarm", "state": "active",
            "raised_cycle": c, "raised_at_s": float(result.t_start), "cleared_cycle": None, "acknowledged_by": None,
            "message": "cylinder 3 friction above its baseline and its siblings",
            "evidence": {"fmep_bar": 1.95, "baseline_fmep_bar": 1.79, "cycles": [c]}})
        return [Raised("raised", self.alerts[1])]

    def active(self) -> list[StandInAlert]:
        return [a for a in self.alerts.values() if a.doc["state"] != "cleared"]

    def history(self) -> list[StandInAlert]:
        return list(self.alerts.values())

    def acknowledge(self, alert_id: int, by: str) -> StandInAlert:
        a = self.alerts[alert_id]  # KeyError: the service answers 404
        a.doc.update(state="acknowledged", acknowledged_by=by)
        return a

    def rebaseline(self) -> None:
        pass


def alerts_raised(base: str) -> bool:
    try:
        return bool(httpx.get(f"{base}/api/v1/engines/genset-v20/alerts", timeout=5).json())
    except httpx.HTTPError:
        return False


# the store's fleet view as service/store/fleet.py gives it: this engine, and one another process wrote and left
FLEET = [
    {"engine_id": "genset-v20", "writer": "box-a:4242:abcd", "writer_live": True, "heartbeat_age_s": 3.0,
     "run_id": 2, "last_cycle": 1843, "t_start_s": 147.4, "last_cycle_age_s": 0.4,
     "engine": {"fmep_bar": 1.9512, "fmep_sigma_bar": 0.0251, "status": "measured", "reason": None},
     "active_alerts": 1, "acknowledged_alerts": 0},
    {"engine_id": "genset-7", "writer": "box-b:99:ef01", "writer_live": False, "heartbeat_age_s": 600.0,
     "run_id": 5, "last_cycle": 120, "t_start_s": 9.6, "last_cycle_age_s": 612.0,
     "engine": {"fmep_bar": None, "fmep_sigma_bar": None, "status": "unresolved", "reason": "warm-up"},
     "active_alerts": 0, "acknowledged_alerts": 2},
]


@pytest.fixture(scope="module")
def base_url():
    src = open_source(f"mcap:{DEMO}?loop=1&speed=1", Clocks())  # real time: the other test worker needs the CPU too
    model = resolve_model(src.engine_toml, None, "demo", src.info)
    svc = EngineService("genset-v20", model, src.info, {"log": src}, urls=["demo"], alerts=lambda _id, spec: OneAlarm(spec))
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app([svc], token=TOKEN, fleet=lambda: FLEET), host="127.0.0.1",
                                           port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, name="dashboard-ack-server", daemon=True)
    thread.start()
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 900  # the first cycle waits for the numba kernels
        while not alerts_raised(base):
            if not thread.is_alive():
                pytest.fail("the in-process server stopped before its first cycle")
            if time.monotonic() > deadline:
                pytest.fail("no alert from the stand-in alert engine in 900 s")
            time.sleep(0.2)
        yield base
    finally:
        server.should_exit = True
        thread.join(timeout=60)


def set_input(page, element_id: str, value: str) -> None:
    page.evaluate(f"(() => {{ const t = document.getElementById({element_id!r}); t.value = {value!r};"
                  " t.dispatchEvent(new Event('input')); })()")


def test_acknowledge_from_the_page(base_url, tmp_path):
    with Chromium.start(tmp_path / "profile") as browser:
        page = browser.new_page(width=1400, height=1000)
        page.navigate(f"{base_url}/")
        page.wait_for("document.querySelector('#alerts li.alert.state-active button') !== null", timeout=60)
        heading = page.evaluate("document.querySelector('#alerts li.alert h3').textContent")
        assert heading.startswith("alarm ring wear — cylinder 3 (active, alert 1)"), heading
        evidence = page.evaluate("Object.fromEntries([...document.querySelectorAll('#alerts dt')].map("
                                 "dt => [dt.textContent, dt.nextElementSibling.textContent]))")
        assert evidence["fmep"] == "1.950 bar" and evidence["baseline fmep"] == "1.790 bar"
        assert evidence["cycles"].isdigit() and evidence["raised"].startswith(f"cycle {evidence['cycles']}, t = ")
        assert page.evaluate("document.getElementById('active-alerts').textContent") == "1 active, 0 acknowledged"

        click = "document.querySelector('#alerts li.alert button').click()"
        message = "document.getElementById('alerts-message').textContent"
        set_input(page, "token", "not-the-token")
        page.evaluate(click)
        said = page.wait_for(f"{message}.includes('401') && {message}", timeout=10)
        assert said.startswith("Not acknowledged alert 1 (ring wear): the service refused the token (HTTP 401).")

        set_input(page, "token", TOKEN)
        set_input(page, "ack-by", "night shift")
        page.evaluate(click)
        assert page.wait_for(f"{message}.startsWith('Acknowledged') && {message}", timeout=10) == \
            "Acknowledged alert 1 (ring wear)."
        page.wait_for("document.querySelector('#alerts li.alert.state-acknowledged') !== null", timeout=10)
        assert page.evaluate("document.querySelector('#alerts li.alert button')") is None  # nothing left to do
        shown = page.evaluate("[...document.querySelectorAll('#alerts dt')].find(dt => dt.textContent === "
                              "'acknowledged by').nextElementSibling.textContent")
        assert shown == "night shift"
        assert page.evaluate("sessionStorage.getItem('frictionwatch.acknowledged-by')") == "night shift"
        # the browser logs the refused request itself; nothing else may be an error
        assert [e for e in page.console_errors if "status of 401" not in e] == []

    api = httpx.get(f"{base_url}/api/v1/engines/genset-v20/alerts", params={"state": "all"}, timeout=5).json()
    assert [(a["state"], a["acknowledged_by"]) for a in api] == [("acknowledged", "night shift")]


def test_the_fleet_panel_lists_every_engine_of_the_store(base_url, tmp_path):
    """With a store the page shows the fleet: each engine's writer (or that none is live), its newest cycle and the
    engine's FMEP only where measured."""
    with Chromium.start(tmp_path / "profile") as browser:
        page = browser.new_page(width=1400, height=1000)
        page.navigate(f"{base_url}/")
        page.wait_for("document.querySelectorAll('#fleet-table tbody tr').length === 2", timeout=60)
        assert page.evaluate("document.getElementById('fleet-panel').hidden") is False
        rows = page.evaluate("[...document.querySelectorAll('#fleet-table tbody tr')].map(tr => "
                             "[...tr.children].map(td => td.textContent))")
        assert rows[0] == ["genset-v20 (here)", "box-a:4242", "#1843", "0", "1.951", "0.025", "measured", "1"]
        assert rows[1] == ["genset-7", "no live writer", "#120", "612", "—", "—", "unresolved",
                           "0 (+2 acknowledged)"]
