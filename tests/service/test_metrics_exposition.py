"""/metrics' text (service/metrics.py ``Exposition``, design note 154) is prometheus_client's ``generate_latest`` of
the same registry byte for byte: every kind of metric the service exposes (histograms with their _created gauges,
counters, gauges), label values that need escaping, NaN and infinities, a timestamp, scrape after scrape."""

from __future__ import annotations

import math

from frictionwatch.service.metrics import Exposition, ServiceMetrics
from prometheus_client import generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily


class _Odd:
    """A collector of the values whose text needs care."""

    def collect(self):
        g = GaugeMetricFamily("odd_values", 'help with a \\ backslash and a\nnewline', labels=["engine", "what"])
        for i, v in enumerate((math.nan, math.inf, -math.inf, 1e7, 123456789.0, 0.1, -2.5, 0.0)):
            g.add_metric(["g1", f"v{i}"], v)
        g.add_metric(['we"ird\\name\n', "x"], 1.0)
        g.add_metric(["g2", "stamped"], 3.0, timestamp=1700000000.25)
        yield g
        c = CounterMetricFamily("odd_things", "counted", labels=["engine"])
        c.add_metric(["g1"], 7)
        yield c

    def describe(self):
        return []


def test_the_exposition_is_generate_latest_byte_for_byte() -> None:
    metrics = ServiceMetrics(lambda: [], lambda: 3)
    metrics.registry.register(_Odd())
    assert metrics.text() == generate_latest(metrics.registry)  # before any request or cycle
    for route in ("losses", "health", 'odd"route'):
        for v in (0.0004, 0.03, 7.0):
            metrics.requests.labels(route).observe(v)
    observe = metrics.observer("g1")
    assert isinstance(metrics._exposition, Exposition)
    for _ in range(3):  # the remembered series' lines with new values
        metrics.to_api.labels("g1").observe(0.01)
        observe.metrics.latency.labels("g1").observe(0.2)
        assert metrics.text() == generate_latest(metrics.registry)
