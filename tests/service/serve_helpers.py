"""Shared by the serve / API tests: engine services on the bundled demo log, and a test double of the alert engine
that implements exactly the contract's interface (service/alerts.py, h-alerts, replaces it after the merge)."""

from __future__ import annotations

import signal
import subprocess
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from frictionwatch.drivers.source import open_source
from frictionwatch.drivers.timebase import Clocks
from frictionwatch.service.engine_service import EngineService
from frictionwatch.service.pipeline import resolve_model

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "replay_logs" / "demo.mcap"


@dataclass(frozen=True)
class FakeAlert:
    alert_id: int
    cylinder: int | None
    kind: str
    raised_cycle: int
    raised_at_s: float
    state: str = "active"
    acknowledged_by: str | None = None

    def to_dict(self) -> dict:
        return {"alert_id": self.alert_id, "cylinder": self.cylinder, "kind": self.kind, "severity": "warning",
                "state": self.state, "raised_cycle": self.raised_cycle, "raised_at_s": self.raised_at_s,
                "cleared_cycle": None, "acknowledged_by": self.acknowledged_by,
                "message": f"{self.kind} on cylinder {self.cylinder}", "evidence": {"cycles": [self.raised_cycle]}}


@dataclass(frozen=True)
class FakeEvent:
    kind: str
    alert: FakeAlert


@dataclass
class FakeBaseline:
    from_cycle: int

    def to_dict(self) -> dict:
        return {"from_cycle": self.from_cycle}


@dataclass
class FakeAlerts:
    """AlertEngine's interface: raises one ring_wear alert on cylinder ``cylinder`` at cycle ``at_cycle``."""

    spec: object
    cylinder: int = 2
    at_cycle: int = 5
    alerts: dict = field(default_factory=dict)
    baseline: FakeBaseline | None = None
    last_cycle: int = -1

    def update(self, result) -> list[FakeEvent]:
        self.last_cycle = int(result.index)
        if result.index == self.at_cycle:
            a = FakeAlert(len(self.alerts) + 1, self.cylinder, "ring_wear", int(result.index), float(result.t_start))
            self.alerts[a.alert_id] = a
            return [FakeEvent("raised", a)]
        return []

    def active(self) -> list[FakeAlert]:
        return [a for a in self.alerts.values() if a.state != "cleared"]

    def history(self) -> list[FakeAlert]:
        return list(self.alerts.values())

    def acknowledge(self, alert_id: int, by: str) -> FakeAlert:
        a = replace(self.alerts[alert_id], state="acknowledged", acknowledged_by=by)  # KeyError when unknown
        self.alerts[alert_id] = a
        return a

    def rebaseline(self) -> None:
        self.baseline = FakeBaseline(self.last_cycle)


def demo_service(engine_id: str, url: str = f"mcap:{DEMO}", **options) -> EngineService:
    src = open_source(url, Clocks())
    model = resolve_model(src.engine_toml, None, "demo", src.info)
    return EngineService(engine_id, model, src.info, {"log": src}, urls=[url], **options)


def stop_server(proc, timeout: float = 30.0) -> None:
    """SIGTERM a serve process (if it still runs) and wait; killed if it does not stop within ``timeout`` s."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def wait_until(pred, timeout: float, every: float = 0.1) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(every)
    return pred()
