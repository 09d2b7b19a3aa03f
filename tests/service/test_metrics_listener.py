"""The metrics (service/metrics.py): each engine's measured FMEPs from its newest result at scrape time, and each
cycle's latency and time to the API (the observer the API state calls) under the engine's labels; no FMEP or latency
series of an engine before its first result (a gauge would read 0)."""

from __future__ import annotations

import math
from types import SimpleNamespace

from frictionwatch.service.listeners import ServiceEvent
from frictionwatch.service.metrics import CycleObserver, ServiceMetrics
from numpy.testing import assert_allclose
from prometheus_client.parser import text_string_to_metric_families


class FakeResult:
    def __init__(self, engine: float, cylinders: list[float]) -> None:
        self.figures = (engine, cylinders)

    def measured_fmep_bar(self) -> tuple[float, list[float]]:
        return self.figures


class FakeEngine:
    """What the metrics' collectors read of an EngineService."""

    def __init__(self, engine_id: str) -> None:
        self.engine_id, self.cycles_ok, self.skipped = engine_id, 0, {}
        self.state = SimpleNamespace(newest=None)
        self.fanout = SimpleNamespace(drops={}, left={}, errors={}, queued={}, waited_s={}, listener=lambda name: None)

    def backlog(self) -> dict:
        lag = dict.fromkeys(("queued_cycles", "queued_s", "behind_s", "dropped_records", "dropped_s", "held_s",
                             "held_bytes"), 0.0)
        return {**lag, "holding": False}


def samples(metrics: ServiceMetrics, name: str, engine: str) -> dict:
    fams = {f.name: f for f in text_string_to_metric_families(metrics.text().decode())}
    return {s.labels.get("cylinder", s.name): s.value for s in fams[name].samples
            if s.labels.get("engine") == engine}


def test_each_cycle_sets_the_engines_series_and_no_series_before_the_first() -> None:
    engines = {"a": FakeEngine("a"), "b": FakeEngine("b")}
    metrics = ServiceMetrics(lambda: engines.values(), lambda: 0)
    a, b = metrics.observer("a"), metrics.observer("b")
    assert isinstance(a, CycleObserver)
    assert samples(metrics, "frictionwatch_engine_fmep_bar", "a") == {}
    assert samples(metrics, "frictionwatch_fmep_bar", "a") == {}
    for engine_id, result, at in (("a", FakeResult(1.5, [1.0, math.nan, 2.0]), (10.0, 9.9)),
                                  ("b", FakeResult(math.nan, [0.5, 0.25]), (10.0, None)),
                                  ("a", FakeResult(1.75, [1.25, 3.0, math.nan]), (10.5, 10.2))):
        engines[engine_id].state.newest = result  # the API's state has it (the engine's LatestState)
        (a if engine_id == "a" else b)(ServiceEvent(engine_id, result, *at), 0.25 if engine_id == "a" else 0.5)
    assert_allclose(samples(metrics, "frictionwatch_engine_fmep_bar", "a")["frictionwatch_engine_fmep_bar"], 1.75)
    assert math.isnan(samples(metrics, "frictionwatch_engine_fmep_bar", "b")["frictionwatch_engine_fmep_bar"])
    cyl_a = samples(metrics, "frictionwatch_fmep_bar", "a")
    assert_allclose([cyl_a["1"], cyl_a["2"]], [1.25, 3.0], rtol=0, atol=0)
    assert math.isnan(cyl_a["3"]) and set(cyl_a) == {"1", "2", "3"}
    assert samples(metrics, "frictionwatch_fmep_bar", "b") == {"1": 0.5, "2": 0.25}
    lat = samples(metrics, "frictionwatch_cycle_latency_seconds", "a")
    assert lat["frictionwatch_cycle_latency_seconds_count"] == 2
    assert_allclose(lat["frictionwatch_cycle_latency_seconds_sum"], 0.1 + 0.3, rtol=1e-12)
    assert samples(metrics, "frictionwatch_cycle_latency_seconds", "b") == {}  # no arrival time: no latency
    to_api = samples(metrics, "frictionwatch_cycle_to_api_seconds", "a")
    assert to_api["frictionwatch_cycle_to_api_seconds_count"] == 2
    assert_allclose(to_api["frictionwatch_cycle_to_api_seconds_sum"], 0.5, rtol=1e-12)
    assert samples(metrics, "frictionwatch_cycle_to_api_seconds", "b")["frictionwatch_cycle_to_api_seconds_count"] == 1


def test_the_api_state_does_not_call_the_observer_for_an_event_without_a_result() -> None:
    from frictionwatch.service.listeners import LatestState

    seen = []
    state = LatestState()
    state.on_visible = lambda event, s: seen.append((event.result_s, s))
    state.on_message_received(ServiceEvent("a", None, 1.0))  # an API action's event: no result, nothing seen
    assert seen == []


def test_a_warm_ups_hold_is_on_the_metrics_as_on_health() -> None:
    """The hold's figures (EngineService.backlog's ``holding``, ``held_s``, ``held_bytes``; design note 136) are
    gauges under the engine's label: an operator's Prometheus sees what /health says of a cold start."""
    engine = FakeEngine("a")
    engine.backlog = lambda: {**FakeEngine.backlog(engine), "holding": True, "held_s": 12.5, "held_bytes": 4.0e7}
    metrics = ServiceMetrics(lambda: [engine], lambda: 0)
    for name, value in (("frictionwatch_ingest_holding", 1.0), ("frictionwatch_ingest_held_seconds", 12.5),
                        ("frictionwatch_ingest_held_bytes", 4.0e7)):
        assert_allclose(samples(metrics, name, "a")[name], value, rtol=0, atol=0)
