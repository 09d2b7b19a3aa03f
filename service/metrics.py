"""Prometheus metrics of the service on the app's own CollectorRegistry (never the process-global one, so two apps
in one process, or a test, never share series).

    frictionwatch_fmep_bar{engine,cylinder}        smoothed FMEP where measured (NaN where it is a share, the
                                                    prior, unresolved or withheld: a prior is never a reading)
    frictionwatch_engine_fmep_bar{engine}           the engine's FMEP where measured, NaN otherwise
    frictionwatch_cycles_processed_total{engine}    cycles analysed
    frictionwatch_cycles_skipped_total{engine,reason}
    frictionwatch_cycle_latency_seconds{engine}     histogram: the record completing a cycle read -> its result
    frictionwatch_cycle_to_api_seconds{engine}      histogram: a result -> visible to the API's routes
    frictionwatch_listener_drops_total{engine,listener}  events a full listener queue dropped
    frictionwatch_listener_left_total{engine,listener}   events a stop left undelivered (EngineService.stop's line)
    frictionwatch_listener_errors_total{engine,listener} events whose listener raised
    frictionwatch_listener_queued_events{engine,listener}  gauge: events waiting in the listener's queue
    frictionwatch_listener_waited_seconds_total{engine,listener}  seconds a replay faster than real time waited for
                                                    the listener's full queue (it ran at that listener's pace)
    frictionwatch_sse_dropped_total                 events slow stream clients lost
    frictionwatch_ingest_queued_cycles{engine}      gauge: cycles of data waiting for the monitor (NaN before the first)
    frictionwatch_ingest_queued_seconds{engine}     gauge: acquisition seconds waiting
    frictionwatch_ingest_behind_seconds{engine}     gauge: wall seconds the oldest waiting data have waited
    frictionwatch_ingest_dropped_records_total{engine}  records the bounded queue dropped (the oldest go)
    frictionwatch_ingest_dropped_seconds_total{engine}  acquisition seconds they covered
    frictionwatch_ingest_holding{engine}            gauge: 1 while a warm-up's hold keeps a board's input past
                                                    the queue's span (serve --hold-mb, design note 136), else 0
    frictionwatch_ingest_held_seconds{engine}       gauge: the most acquisition seconds the hold kept at once
    frictionwatch_ingest_held_bytes{engine}         gauge: the most bytes it kept at once (an estimate)
    frictionwatch_store_cycles_total{engine,outcome}  the store listener's cycles: written, written_late (kept while
                                                    the store was down, then written), lost
    frictionwatch_store_backlog_cycles{engine}      gauge: cycles kept for a store that is down (bounded)
    frictionwatch_rate_limited_total                large queries refused with 429
    frictionwatch_http_request_seconds{route}       histogram: a request's time in the server (queued for a worker
                                                    thread included), by route function (what a client's p99 is
                                                    made of, without the client's own delays)
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from typing import Any

from frictionwatch.service.listeners import ServiceEvent
from prometheus_client import CollectorRegistry, Histogram
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.openmetrics.exposition import UNDERSCORES, _escape, escape_label_name, escape_metric_name
from prometheus_client.registry import Collector
from prometheus_client.utils import floatToGoString

LATENCY_BUCKETS_S = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)


class ServiceMetrics:
    """The app's registry and the metrics updated per cycle (the counters are read from the engines at scrape)."""

    def __init__(self, engines: Callable[[], Iterable[Any]], sse_dropped: Callable[[], int]) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        self.latency = Histogram("frictionwatch_cycle_latency_seconds", "Record completing a cycle read -> result",
                                 ["engine"], buckets=LATENCY_BUCKETS_S, registry=self.registry)
        self.to_api = Histogram("frictionwatch_cycle_to_api_seconds", "Result -> visible to the API",
                                ["engine"], buckets=LATENCY_BUCKETS_S, registry=self.registry)
        self.requests = Histogram("frictionwatch_http_request_seconds", "Request received -> response sent",
                                  ["route"], buckets=LATENCY_BUCKETS_S, registry=self.registry)
        self.rate_limited: Callable[[], int] = lambda: 0  # the app sets its bucket's count
        self.registry.register(_EngineCounters(engines, sse_dropped))
        self.registry.register(_Fmep(engines))
        self.registry.register(_Backlog(engines, lambda: self.rate_limited()))
        self._exposition = Exposition(self.registry)

    def observer(self, engine_id: str) -> CycleObserver:
        return CycleObserver(self, engine_id)

    def text(self) -> bytes:
        return self._exposition.text()


SERIES_KEPT = 20_000  # Exposition's remembered series: past this it starts again (a bound, not reached by serve's)
_OPENMETRICS_SUFFIXES = ("_created", "_gsum", "_gcount")


class Exposition:
    """``prometheus_client.generate_latest(registry)``, the same bytes (the text format, names escaped with
    'underscores'), with each series' name and labels written once and remembered: generate_latest escapes and
    checks every name and label of every sample on every scrape, ~half of a scrape's ~2-4 ms with four gensets
    (design note 154). tests/service/test_metrics_exposition.py holds the two byte for byte."""

    def __init__(self, registry: Collector) -> None:
        self.registry = registry
        self._series: dict[tuple, str] = {}

    def _line_head(self, name: str, labels: dict[str, str]) -> str:
        key = (name, *labels.items())
        head = self._series.get(key)
        if head is None:
            if len(self._series) >= SERIES_KEPT:
                self._series.clear()
            text = ",".join('{}="{}"'.format(escape_label_name(k, UNDERSCORES), _escape(v, "allow-utf-8", False))
                            for k, v in sorted(labels.items()))
            head = self._series[key] = f"{escape_metric_name(name, UNDERSCORES)}{'{' + text + '}' if text else ''} "
        return head

    def _line(self, sample: Any) -> str:
        stamp = "" if sample.timestamp is None else f" {int(float(sample.timestamp) * 1000):d}"
        return f"{self._line_head(sample.name, sample.labels)}{floatToGoString(sample.value)}{stamp}\n"

    def text(self) -> bytes:
        output = []
        for metric in self.registry.collect():
            mname, mtype = metric.name, metric.type
            if mtype == "counter":  # generate_latest's munging from OpenMetrics into the Prometheus format
                mname = mname + "_total"
            elif mtype == "info":
                mname, mtype = mname + "_info", "gauge"
            elif mtype == "stateset":
                mtype = "gauge"
            elif mtype == "gaugehistogram":
                mtype = "histogram"
            elif mtype == "unknown":
                mtype = "untyped"
            doc = metric.documentation.replace("\\", r"\\").replace("\n", r"\n")
            shown = escape_metric_name(mname, UNDERSCORES)
            output.append(f"# HELP {shown} {doc}\n")
            output.append(f"# TYPE {shown} {mtype}\n")
            om_samples: dict[str, list[str]] = {}
            for s in metric.samples:
                for suffix in _OPENMETRICS_SUFFIXES:
                    if s.name == metric.name + suffix:  # OpenMetrics' own, put in a gauge at the end
                        om_samples.setdefault(suffix, []).append(self._line(s))
                        break
                else:
                    output.append(self._line(s))
            for suffix, lines in sorted(om_samples.items()):
                shown = escape_metric_name(metric.name + suffix, UNDERSCORES)
                output.append(f"# HELP {shown} {doc}\n")
                output.append(f"# TYPE {shown} gauge\n")
                output.extend(lines)
        return "".join(output).encode("utf-8")


class RequestTimer:
    """Pure ASGI middleware: each HTTP request's time into ``metrics.requests``, labelled by the route's function
    name (a fixed set; 'other' for a path no route matched). The event stream is left out: it lasts as long as its
    client."""

    def __init__(self, app: Any, metrics: ServiceMetrics) -> None:
        self.app, self.metrics = app, metrics

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] != "http" or scope["path"].endswith("/stream"):
            await self.app(scope, receive, send)
            return
        t = time.perf_counter()
        try:
            await self.app(scope, receive, send)
        finally:
            endpoint = scope.get("endpoint")
            route = getattr(endpoint, "__name__", "other")
            self.metrics.requests.labels(route).observe(time.perf_counter() - t)


class CycleObserver:
    """The per-cycle histograms of one engine: each result's latency (record read -> result) and its time to the API
    (result -> visible to the routes). Called by the engine's API state (``listeners.LatestState.on_visible``) on
    its listener thread right after a result becomes visible, not by a listener of its own: a listener of its own
    was one more queue hand-over and thread wake-up a cycle for one histogram's ``observe`` (design note 92). The
    FMEP gauges are read from the newest result at scrape time (``_Fmep``)."""

    def __init__(self, metrics: ServiceMetrics, engine_id: str) -> None:
        self.metrics, self.engine_id = metrics, engine_id
        # this engine's labelled series, kept (``labels`` takes the metric's lock and builds its key each call); the
        # latency's looked up at its first value (a series appears in /metrics when it has one), the time to the API's
        # at once (as it was)
        self._latency: Any = None
        self._to_api = metrics.to_api.labels(engine_id)

    def __call__(self, event: ServiceEvent, to_api_s: float) -> None:
        self._to_api.observe(to_api_s)
        if event.result is None or event.arrived_s is None:
            return
        if self._latency is None:
            self._latency = self.metrics.latency.labels(self.engine_id)
        self._latency.observe(max(0.0, event.result_s - event.arrived_s))


class _Fmep(Collector):
    """The smoothed FMEP gauges, from each engine's newest result (``EngineService.state.newest``, what the API shows)
    at scrape time: where its status is "measured" (``CycleResult.measured_fmep_bar``: this cycle's flags), NaN
    otherwise; no series before an engine's first result. Per scrape rather than per cycle: a genset-v20 cycle's
    statuses and figures cost the ingest thread ~0.07 ms at 12.5 cycles a second, a scrape comes every few seconds
    (design notes 47)."""

    def __init__(self, engines: Callable[[], Iterable[Any]]) -> None:
        self.engines = engines

    def collect(self) -> Iterable[GaugeMetricFamily]:
        cylinders = GaugeMetricFamily("frictionwatch_fmep_bar", "Smoothed FMEP per cylinder where measured (NaN "
                                      "otherwise)", labels=["engine", "cylinder"])
        engine = GaugeMetricFamily("frictionwatch_engine_fmep_bar", "Smoothed engine FMEP where measured (NaN "
                                   "otherwise)", labels=["engine"])
        for e in self.engines():
            newest = e.state.newest
            if newest is None:
                continue
            total, each = newest.measured_fmep_bar()
            engine.add_metric([e.engine_id], total)
            for k, v in enumerate(each):
                cylinders.add_metric([e.engine_id, str(k + 1)], v)
        yield from (cylinders, engine)

    def describe(self) -> Iterable[GaugeMetricFamily]:
        return []


class _EngineCounters(Collector):
    """Counters read from each engine service at scrape time (the session and the fan-out own the counts)."""

    def __init__(self, engines: Callable[[], Iterable[Any]], sse_dropped: Callable[[], int]) -> None:
        self.engines, self.sse_dropped = engines, sse_dropped

    def collect(self) -> Iterable[CounterMetricFamily]:
        ok = CounterMetricFamily("frictionwatch_cycles_processed", "Cycles analysed", labels=["engine"])
        skipped = CounterMetricFamily("frictionwatch_cycles_skipped", "Cycles lost, by reason",
                                      labels=["engine", "reason"])
        drops = CounterMetricFamily("frictionwatch_listener_drops", "Events dropped by a full listener queue",
                                    labels=["engine", "listener"])
        per_listener = {
            "drops": drops,
            "left": CounterMetricFamily("frictionwatch_listener_left", "Events a stop left undelivered",
                                        labels=["engine", "listener"]),
            "errors": CounterMetricFamily("frictionwatch_listener_errors", "Events whose listener raised",
                                          labels=["engine", "listener"]),
            "queued": GaugeMetricFamily("frictionwatch_listener_queued_events", "Events waiting in the listener's "
                                        "queue", labels=["engine", "listener"]),
            "waited_s": CounterMetricFamily("frictionwatch_listener_waited_seconds", "Seconds a replay faster than "
                                            "real time waited for the listener's full queue",
                                            labels=["engine", "listener"])}
        for e in self.engines():
            ok.add_metric([e.engine_id], e.cycles_ok)
            for reason, n in sorted(e.skipped.items()):
                skipped.add_metric([e.engine_id, reason], n)
            for attr, family in per_listener.items():
                for name, n in getattr(e.fanout, attr).items():
                    family.add_metric([e.engine_id, name], n)
        stored = CounterMetricFamily("frictionwatch_store_cycles", "Cycles the store listener wrote, wrote late, "
                                     "lost", labels=["engine", "outcome"])
        waiting = GaugeMetricFamily("frictionwatch_store_backlog_cycles", "Cycles kept for a store that is down",
                                    labels=["engine"])
        for e in self.engines():
            listener = e.fanout.listener("store")
            if listener is not None:
                for outcome, key in (("written", "cycles_written"), ("written_late", "cycles_written_late"),
                                     ("lost", "lost_cycles")):
                    stored.add_metric([e.engine_id, outcome], listener.stats[key])
                waiting.add_metric([e.engine_id], listener.backlog)
        sse = CounterMetricFamily("frictionwatch_sse_dropped", "Events lost to slow stream clients")
        sse.add_metric([], self.sse_dropped())
        yield from (ok, skipped, *per_listener.values(), stored, waiting, sse)

    def describe(self) -> Iterable[CounterMetricFamily]:
        return []


class _Backlog(Collector):
    """Each engine's ingest backlog (EngineService.backlog), read at scrape time."""

    def __init__(self, engines: Callable[[], Iterable[Any]], rate_limited: Callable[[], int]) -> None:
        self.engines, self.rate_limited = engines, rate_limited

    def collect(self) -> Iterable[Any]:
        gauges = {key: GaugeMetricFamily(f"frictionwatch_ingest_{name}", text, labels=["engine"]) for key, name, text in (
            ("queued_cycles", "queued_cycles", "Cycles of data waiting for the monitor"),
            ("queued_s", "queued_seconds", "Acquisition seconds waiting for the monitor"),
            ("behind_s", "behind_seconds", "Wall seconds the oldest waiting data have waited"),
            ("holding", "holding", "1 while a warm-up's hold keeps a board's input past the queue's span"),
            ("held_s", "held_seconds", "The most acquisition seconds the warm-up's hold kept at once"),
            ("held_bytes", "held_bytes", "The most bytes the warm-up's hold kept at once (an estimate)"))}
        counters = {key: CounterMetricFamily(f"frictionwatch_ingest_{name}", text, labels=["engine"]) for key, name, text
                    in (("dropped_records", "dropped_records", "Records the bounded ingest queue dropped"),
                        ("dropped_s", "dropped_seconds", "Acquisition seconds the dropped records covered"))}
        for e in self.engines():
            lag = e.backlog()
            for key, fam in (*gauges.items(), *counters.items()):
                fam.add_metric([e.engine_id], math.nan if lag[key] is None else float(lag[key]))
        limited = CounterMetricFamily("frictionwatch_rate_limited", "Large queries refused with 429")
        limited.add_metric([], self.rate_limited())
        yield from (*gauges.values(), *counters.values(), limited)

    def describe(self) -> Iterable[Any]:
        return []
