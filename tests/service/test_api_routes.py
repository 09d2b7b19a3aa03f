"""The API in-process (TestClient) on two engines of one process: the demo log whole (id 'demo-a') and from 1.0 s on
('demo-b'), each at full speed to its end. The figures are checked against `frictionwatch analyze`'s JSON document
(service/cmd_analyze.summary) made from the same engine's results: the API must say what analyze says."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from fastapi.testclient import TestClient
from frictionwatch.service.api import create_app
from frictionwatch.service.cmd_analyze import summary
from numpy.testing import assert_allclose
from prometheus_client.parser import text_string_to_metric_families

from tests.analyze_doc import assert_fmep_is_torque_over_displacement
from tests.service.serve_helpers import DEMO, FakeAlerts, demo_service, wait_until

TOKEN = "t0ken-for-the-tests-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture(scope="module")
def served():
    a = demo_service("demo-a", alerts=lambda engine_id, spec: FakeAlerts(spec, cylinder=2, at_cycle=5))
    b = demo_service("demo-b", f"mcap:{DEMO}?start=1.0", alerts=lambda engine_id, spec: FakeAlerts(spec, cylinder=7))
    app = create_app([a, b], token=TOKEN)
    with TestClient(app) as client:
        for s in (a, b):  # every result delivered to the API's state
            assert wait_until(lambda s=s: s.sources_ended and s.session.cycles_ok > 0 and
                              s.state.snapshot(1)[0] is s.session.results[-1], timeout=900, every=0.5)
        yield client, a, b


@pytest.fixture(scope="module")
def analyzed(served):
    """`frictionwatch analyze --json`'s document made from engine a's own results."""
    session = served[1].session
    doc = summary(replace(session.analysis(), spec=session.pipeline.spec))  # the session holds the model as .spec
    assert_fmep_is_torque_over_displacement(doc)
    return doc


def test_engines_are_independent(served) -> None:
    client, a, b = served
    rows = {r["engine_id"]: r for r in client.get("/api/v1/engines").json()}
    assert set(rows) == {"demo-a", "demo-b"}
    assert rows["demo-a"]["cycles_ok"] == a.session.cycles_ok and rows["demo-b"]["cycles_ok"] == b.session.cycles_ok
    assert rows["demo-b"]["cycles_ok"] < rows["demo-a"]["cycles_ok"]  # b started 1 s into the log
    assert rows["demo-a"]["n_cylinders"] == 20 and rows["demo-a"]["engine_name"] == "genset-v20"
    assert all(n == 0 for r in rows.values() for n in r["listener_drops"].values())
    la = client.get("/api/v1/engines/demo-a/cycles/latest").json()
    lb = client.get("/api/v1/engines/demo-b/cycles/latest").json()
    assert la["engine_id"] == "demo-a" and lb["engine_id"] == "demo-b"
    # each engine's own alert engine: a's raised on cylinder 2, b's on cylinder 7
    assert [x["cylinder"] for x in client.get("/api/v1/engines/demo-a/alerts").json()] == [2]
    assert [x["cylinder"] for x in client.get("/api/v1/engines/demo-b/alerts").json()] == [7]


def test_health(served) -> None:
    client, *_ = served
    doc = client.get("/api/v1/health").json()
    assert {e["engine_id"] for e in doc["engines"]} == {"demo-a", "demo-b"}
    assert all(e["running"] and e["last_cycle_age_s"] >= 0 for e in doc["engines"])
    assert doc["status"] in ("ok", "degraded") and doc["uptime_s"] > 0


def test_latest_cycle_is_the_newest_result(served, analyzed) -> None:
    client, a, _ = served
    doc = client.get("/api/v1/engines/demo-a/cycles/latest").json()
    assert doc["cycle_index"] == analyzed["last_cycle"]
    assert_allclose(doc["rpm_mean"], a.session.results[-1].rpm_mean, rtol=1e-12)
    assert len(doc["imep_bar"]) == len(doc["pmax_bar"]) == 20
    assert_allclose(doc["imep_bar"], a.session.results[-1].imep / 1e5, rtol=1e-12)


def test_losses_now_say_what_analyze_says(served, analyzed) -> None:
    client, *_ = served
    doc = client.get("/api/v1/engines/demo-a/losses").json()
    assert doc["cycle_index"] == analyzed["last_cycle"]
    assert doc["window"]["first_cycle"] == analyzed["friction"]["window"]["first_cycle"]
    assert_allclose(doc["window"]["cycles"], analyzed["friction"]["window"]["effective_cycles"], rtol=1e-12)
    assert doc["engine"]["status"] == analyzed["friction"]["status"]
    if analyzed["friction"]["fmep_bar"] is not None:
        assert_allclose(doc["engine"]["fmep_bar"], analyzed["friction"]["fmep_bar"], rtol=1e-9)
    for got, want in zip(doc["cylinders"], analyzed["cylinders"], strict=True):
        f = want["friction"]
        assert (got["cylinder"], got["status"], got["reason"]) == (want["cylinder"], f["status"], f["reason"])
        # a value under the name of what it is: the measurement keys as analyze's flat keys (null unless measured),
        # a share under share_*
        named = {"measured": "", "share": "share_"}.get(f["status"])
        for key in ("fmep_bar", "fmep_sigma_bar", "friction_torque_mean_nm", "friction_torque_sigma_nm"):
            for prefix in ("", "share_"):
                if prefix == named and f[key] is not None:
                    assert_allclose(got[prefix + key], f[key], rtol=1e-9, err_msg=prefix + key)
                else:
                    assert got[prefix + key] is None, prefix + key  # never a number where analyze shows none
            if want[key] is not None:
                assert_allclose(got[key], want[key], rtol=1e-9, err_msg=key)
        if f["data_weight"] is None:
            assert got["data_weight"] is None
        else:
            assert_allclose(got["data_weight"], f["data_weight"], rtol=1e-9)
        assert list(got["coefficients"]) == list(got["coefficient_sigmas"]) and len(got["coefficients"]) >= 6
    # a prior or an unresolved figure is never labelled measured
    assert all(c["status"] != "measured" or c["fmep_bar"] is not None for c in doc["cylinders"])


def test_losses_over_a_window(served) -> None:
    client, a, _ = served
    doc = client.get("/api/v1/engines/demo-a/losses", params={"window_cycles": 10}).json()
    results = a.session.results[-10:]
    assert doc["window"] == {"first_cycle": results[0].index, "last_cycle": results[-1].index, "cycles": 10,
                             "cycles_left_out": 0, "left_out": None, "cycles_missing": 0, "cycles_dropped": 0,
                             "missing": None}
    shown = 0
    for c in doc["cylinders"]:
        cyls = [r.to_json(smoothed=False)["cylinders"][c["cylinder"] - 1] for r in results]
        per_cycle = [x["friction"] for x in cyls]
        if c["status"] in ("measured", "share"):  # a mean only over cycles that all show it as this
            shown += 1
            assert all(f["status"] == c["status"] for f in per_cycle)
            values = [f["friction_torque_mean_nm"] for f in per_cycle]
            key = ("" if c["status"] == "measured" else "share_") + "friction_torque_mean_nm"  # a share's own keys
            assert_allclose(c[key], np.mean(values), rtol=1e-12)
            # the sem of the window's scatter and the calibration's part, which no number of cycles averages down
            assert c["calibration"] == "uncalibrated" and c["calibration_sigma_nm"] > 0
            assert_allclose(c["calibration_sigma_nm"], per_cycle[-1]["calibration_sigma_nm"], rtol=1e-12)
            assert_allclose(c[key.replace("mean", "sigma")], np.hypot(np.std(values, ddof=1) / np.sqrt(10),
                                                                    c["calibration_sigma_nm"]), rtol=1e-9)
            for j, name in enumerate(c["coefficients"]):  # a coefficient the data do not resolve stays null
                finite = [x["coefficients"][j] for x in cyls if x["coefficients"][j] is not None]
                if finite:
                    assert_allclose(c["coefficients"][name], np.mean(finite), rtol=1e-12)
                else:
                    assert c["coefficients"][name] is None
        else:
            assert c["fmep_bar"] is None and c["friction_torque_mean_nm"] is None
    assert shown > 0  # the demo's cylinders show a figure over the window
    # a window longer than what is held: the window says how many cycles it used, and that the log's first cycle
    # (no cycle before it, no estimate of its own) was left out (tests/service/test_window_seam.py)
    whole = client.get("/api/v1/engines/demo-a/losses", params={"window_cycles": 5000}).json()
    assert whole["window"]["first_cycle"] == 0 and whole["window"]["cycles_left_out"] == 1
    assert whole["window"]["cycles"] == len(a.session.results) - 1


def test_traces_and_sensor_health(served) -> None:
    client, a, _ = served
    ft = client.get("/api/v1/engines/demo-a/friction-torque").json()
    n = len(ft["crank_angle_deg"])
    assert n > 100 and len(ft["friction_torque_nm"]) == n
    assert len(ft["friction_torque_cyl_nm"]) == 20 and all(len(row) == n for row in ft["friction_torque_cyl_nm"])
    assert_allclose(np.sum(ft["friction_torque_cyl_nm"], axis=0), ft["friction_torque_nm"], rtol=1e-6, atol=1e-6)
    sp = client.get("/api/v1/engines/demo-a/speed", params={"cycles": 5}).json()
    assert len(sp["speed_measured_rpm"]) == len(sp["speed_model_rpm"]) == len(sp["crank_angle_deg"])
    assert_allclose(np.mean(sp["speed_measured_rpm"]), 1500, rtol=0.02)
    assert len(sp["history"]["cycle_index"]) == 5 and sp["history"]["cycle_index"][-1] == sp["cycle_index"]
    sh = client.get("/api/v1/engines/demo-a/sensor-health").json()
    assert sh["enabled"] is False and a.session.results[-1].sensor_health is None  # the speed-based stage: opt-in
    assert sh["cylinders"] == [] and sh["wheel_tdc_offset_deg"] is None
    # the TDC watch is on: the demo's 40 cycles are fewer than its first window, which it says
    watch = a.session.pipeline.tdc_watch
    assert watch.last is None and sh["tdc_watch"]["window_last_cycle"] is None and sh["tdc_watch"]["cylinders"] == []
    assert 0 < sh["tdc_watch"]["cycles_gathered"] == watch.cycles < sh["tdc_watch"]["window_cycles"] == 100
    assert sh["calibration"]["status"] == "uncalibrated" and sh["calibration"]["tdc_wheel_sigma_deg"] == 0.5


def test_state_changes_need_the_token(served) -> None:
    client, *_ = served
    url = "/api/v1/engines/demo-a/alerts/1/acknowledge"
    assert client.post(url).status_code == 401
    assert client.post(url, headers={"Authorization": "Bearer wrong-token-wrong-token"}).status_code == 401
    assert client.post(url, headers={"Authorization": TOKEN}).status_code == 401  # no 'Bearer '
    assert client.post("/api/v1/engines/demo-a/baseline").status_code == 401
    ok = client.post(url, headers=AUTH, json={"by": "shift lead"})
    assert ok.status_code == 200, ok.text
    assert ok.json()["state"] == "acknowledged" and ok.json()["acknowledged_by"] == "shift lead"
    assert client.post("/api/v1/engines/demo-a/alerts/99/acknowledge", headers=AUTH).status_code == 404
    assert client.post(url, headers=AUTH, json={"by": "../../etc"}).status_code == 422
    base = client.post("/api/v1/engines/demo-a/baseline", headers=AUTH)
    assert base.status_code == 200 and base.json()["ok"] is True and base.json()["baseline"]["from_cycle"] >= 0
    all_alerts = client.get("/api/v1/engines/demo-a/alerts", params={"state": "all"}).json()
    assert [x["state"] for x in all_alerts] == ["acknowledged"]


@pytest.mark.parametrize("path, code", [
    ("/api/v1/engines/nope/losses", 404),
    ("/api/v1/engines/NOPE/losses", 422),
    ("/api/v1/engines/..%2F..%2Fetc/losses", 404),
    ("/api/v1/engines/" + "a" * 41 + "/losses", 422),
    ("/api/v1/engines/demo-a/losses?window_cycles=0", 422),
    ("/api/v1/engines/demo-a/losses?window_cycles=100001", 422),
    ("/api/v1/engines/demo-a/losses?window_cycles=x", 422),
    ("/api/v1/engines/demo-a/speed?cycles=0", 422),
    ("/api/v1/engines/demo-a/alerts?state=some", 422),
    ("/api/v1/stream?engine_id=Bad_Id", 422),
    ("/api/v1/stream?engine_id=nope", 404),
    ("/static/../pyproject.toml", 404),
    ("/static/..%2F..%2Fpyproject.toml", 404),
])
def test_bad_requests_get_clear_errors(served, path: str, code: int) -> None:
    client, *_ = served
    r = client.get(path)
    assert r.status_code == code, r.text
    assert "pyproject" not in r.text and "[project]" not in r.text
    if "/engines/nope/" in path:
        assert "known: demo-a, demo-b" in r.json()["detail"]


def test_metrics(served) -> None:
    client, a, b = served
    text = client.get("/metrics").text
    fams = {f.name: f for f in text_string_to_metric_families(text)}
    processed = {s.labels["engine"]: s.value for s in fams["frictionwatch_cycles_processed"].samples}
    assert processed == {"demo-a": a.session.cycles_ok, "demo-b": b.session.cycles_ok}
    fmep = [s for s in fams["frictionwatch_fmep_bar"].samples if s.labels["engine"] == "demo-a"]
    assert sorted(int(s.labels["cylinder"]) for s in fmep) == list(range(1, 21))
    counts = [s for s in fams["frictionwatch_cycle_latency_seconds"].samples if s.name.endswith("_count")]
    assert {s.labels["engine"]: s.value for s in counts}["demo-a"] == a.session.cycles_ok
    to_api = [s for s in fams["frictionwatch_cycle_to_api_seconds"].samples if s.name.endswith("_count")]
    assert {s.labels["engine"]: s.value for s in to_api} == {"demo-a": a.session.cycles_ok,
                                                             "demo-b": b.session.cycles_ok}
    drops = fams["frictionwatch_listener_drops"].samples
    # the metrics' histograms are observed on the API state's thread (design note 92): no listener of their own
    assert {s.labels["listener"] for s in drops} == {"api-state", "sse"}


def test_openapi_lists_every_route(served) -> None:
    client, *_ = served
    paths = set(client.get("/openapi.json").json()["paths"])
    assert paths >= {"/api/v1/health", "/api/v1/engines", "/api/v1/engines/{engine_id}/cycles/latest",
                     "/api/v1/engines/{engine_id}/losses", "/api/v1/engines/{engine_id}/friction-torque",
                     "/api/v1/engines/{engine_id}/speed", "/api/v1/engines/{engine_id}/sensor-health",
                     "/api/v1/engines/{engine_id}/alerts", "/api/v1/engines/{engine_id}/alerts/{alert_id}/acknowledge",
                     "/api/v1/engines/{engine_id}/baseline", "/api/v1/stream", "/api/v1/fleet"}
    json.dumps(client.get("/openapi.json").json())
