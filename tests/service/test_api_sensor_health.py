"""What checks the sensors, as the API shows it, and the options that switch the speed-based stage on.

The engine: the bundled K9K log (60 cycles, 1700 rpm) looped at 3x real time (~40 cycles/s: the monitor keeps up, so
stopping leaves no backlog) through a real EngineService with the speed-based stage on (`--sensor-health`), until the
TDC watch has closed its first window of 100 cycles; then stopped, so that the API's answer can be held against the
pipeline's own state. The options: `analyze --sensor-health` and
`serve --sensor-health` on the bundled Maruti log (60 cycles)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from fastapi.testclient import TestClient
from frictionwatch.core.model.calibration import UNCALIBRATED_SOURCE, Calibration
from frictionwatch.core.monitor.calibration.tdc_watch import WINDOW_CYCLES, TdcWatchState
from frictionwatch.drivers.source import open_source
from frictionwatch.drivers.timebase import Clocks
from frictionwatch.service import api_views, serve
from frictionwatch.service.api import create_app
from frictionwatch.service.cli import build_parser, main
from frictionwatch.service.cmd_analyze import monitor_config
from frictionwatch.service.engine_service import EngineService, TdcWatchView
from frictionwatch.service.pipeline import resolve_model

from tests.service.serve_helpers import ROOT, wait_until

K9K = ROOT / "replay_logs" / "k9k-4cyl.mcap"
MARUTI = ROOT / "replay_logs" / "maruti-3cyl.mcap"


@pytest.fixture(scope="module")
def watched():
    url = f"mcap:{K9K}?loop=1&speed=3"
    src = open_source(url, Clocks())
    model = resolve_model(src.engine_toml, None, "k9k", src.info)
    svc = EngineService("k9k", model, src.info, {"log": src}, urls=[url], config=monitor_config(True))
    svc.start()
    try:  # the log's 59 consecutive pairs a pass: the first window closes in the second pass (~5 s)
        assert wait_until(lambda: svc.tdc_watch.window_cycle is not None, timeout=600, every=0.2)
    finally:
        svc.stop(timeout=60)
    assert not svc.running  # every result analysed and published: the API's newest is the session's
    assert svc.state.snapshot(1)[0] is svc.session.results[-1]
    client = TestClient(create_app([svc], manage=False))
    return client, svc, client.get("/api/v1/engines/k9k/sensor-health").json()


def test_the_tdc_watch_is_the_pipelines(watched) -> None:
    _, svc, doc = watched
    pipe = svc.session.pipeline
    assert svc.tdc_watch.state is pipe.tdc_watch  # the stopped session's last state was published
    watch = doc["tdc_watch"]
    assert watch["window_cycles"] == WINDOW_CYCLES
    assert watch["window_last_cycle"] == pipe.tdc_window_cycle is not None
    assert watch["cycles_gathered"] == pipe.tdc_watch.cycles < WINDOW_CYCLES
    # the window closed within the cycles analysed: at least 100 consecutive pairs after the first cycle
    assert svc.session.results[0].index + WINDOW_CYCLES <= watch["window_last_cycle"] <= svc.session.results[-1].index
    assert [c["cylinder"] for c in watch["cylinders"]] == [1, 2, 3, 4]
    for c, e in zip(watch["cylinders"], pipe.tdc_watch.last, strict=True):
        # the same estimate, in degrees at the edge (the one conversion: 1e-12 relative)
        assert c["offset_deg"] == pytest.approx(math.degrees(e.offset_rad), rel=1e-12, abs=1e-15)
        assert c["sigma_deg"] == pytest.approx(math.degrees(e.sigma_rad), rel=1e-12)
        assert c["method"] == e.method
    offsets = [c["offset_deg"] for c in watch["cylinders"]]
    assert watch["wheel_offset_deg"] == pytest.approx(float(np.median(offsets)), abs=1e-12)
    assert watch["wheel_sigma_deg"] == pytest.approx(float(np.median([c["sigma_deg"] for c in watch["cylinders"]])),
                                                     abs=1e-12)
    assert watch["flags"] == list(pipe.tdc_watch.flags)
    # a healthy simulated log: the pressure agrees with the model's TDC within what an uncalibrated wheel allows
    # (0.5 deg; the watch's own sigma here is ~0.3-0.6 deg) and nothing is flagged
    assert abs(watch["wheel_offset_deg"]) < 0.5 and watch["flags"] == []


def test_flags_are_every_sensor_flag_of_the_newest_cycle(watched) -> None:
    _, svc, doc = watched
    newest = svc.session.results[-1]
    assert doc["cycle_index"] == newest.index
    assert doc["flags"] == sorted(f for f in newest.flags if f.startswith("sensor_"))
    assert set(doc["tdc_watch"]["flags"]) <= set(doc["flags"])  # the watch's flags ride on every cycle's flags


def test_the_calibration_is_the_models(watched) -> None:
    _, svc, doc = watched
    cal = svc.model.calibration
    assert cal == Calibration()  # the bundled log's spec: no calibration section
    assert doc["calibration"] == {"status": "uncalibrated", "source": UNCALIBRATED_SOURCE,
                                  "tdc_wheel_sigma_deg": 0.5, "tdc_cylinder_sigma_deg": 0.2,
                                  "gain_sigma_pct": pytest.approx(3.0, rel=1e-12),
                                  "tdc_cylinder_sigmas_deg": pytest.approx([0.2] * 4, rel=1e-12),
                                  "gain_sigmas_pct": pytest.approx([3.0] * 4, rel=1e-12),
                                  "gain_common_sigma_pct": pytest.approx(1.0, rel=1e-12),
                                  "inertia_sigma_pct": pytest.approx(5.0, rel=1e-12),
                                  "load_torque_sigma_pct": pytest.approx(0.5, rel=1e-12),
                                  "load_power_sigma_pct": pytest.approx(3.0, rel=1e-12), "generator_efficiency": 1.0}


def test_the_speed_based_stage_when_switched_on(watched) -> None:
    _, svc, doc = watched
    stage = svc.session.results[-1].sensor_health
    assert svc.config.sensor_health is not None and stage is not None
    assert doc["enabled"] is True
    assert doc["wheel_tdc_offset_deg"] == pytest.approx(math.degrees(stage.wheel_tdc_offset), rel=1e-12, abs=1e-15)
    assert doc["friction_sigma_nm"] == pytest.approx(stage.friction_sigma, rel=1e-12)
    assert doc["speed_based_flags"] == list(stage.flags)
    assert [c["cylinder"] for c in doc["cylinders"]] == [1, 2, 3, 4]
    for c, k in zip(doc["cylinders"], range(4), strict=True):
        assert c["pressure_gain"] == pytest.approx(stage.pressure_gain[k], rel=1e-12)


def test_before_the_first_window_and_a_commissioned_model(watched) -> None:
    """The view on its own: no window yet (37 cycles gathered), a commissioned calibration, the stage off."""
    _, svc, _ = watched
    result = svc.session.results[-1]
    from dataclasses import replace

    off = replace(result, sensor_health=None)
    empty = TdcWatchView(TdcWatchState(None, np.zeros(5), 37, None, None, (), 0.0), None)
    cal = Calibration(status="commissioned", tdc_wheel_sigma_deg=0.07, tdc_cylinder_sigma_deg=0.05,
                      gain_sigma=0.004, gain_common_sigma=0.012, inertia_sigma=0.06, source="commission, 2 files",
                      gain_sigmas=(0.004, 0.004, 0.031, 0.004))
    doc = api_views.sensor_health(off, empty, cal, 4)
    assert doc["tdc_watch"] == {"window_cycles": 100, "cycles_gathered": 37, "window_last_cycle": None,
                                "wheel_offset_deg": None, "wheel_sigma_deg": None, "flags": [], "cylinders": []}
    assert doc["enabled"] is False and doc["cylinders"] == [] and doc["speed_based_flags"] == []
    assert doc["wheel_tdc_offset_deg"] is None and doc["friction_sigma_nm"] is None
    assert doc["calibration"]["status"] == "commissioned" and doc["calibration"]["source"] == "commission, 2 files"
    assert doc["calibration"]["gain_sigma_pct"] == pytest.approx(0.4, rel=1e-12)
    assert doc["calibration"]["inertia_sigma_pct"] == pytest.approx(6.0, rel=1e-12)
    # each cylinder's own: the channel commissioning corrected apart, the TDC's the one scalar for each
    assert doc["calibration"]["gain_sigmas_pct"] == pytest.approx([0.4, 0.4, 3.1, 0.4], rel=1e-12)
    assert doc["calibration"]["tdc_cylinder_sigmas_deg"] == pytest.approx([0.05] * 4, rel=1e-12)


def test_openapi_types_the_sensor_health(watched) -> None:
    client, *_ = watched
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    props = schemas["SensorHealth"]["properties"]
    assert props["tdc_watch"]["$ref"].endswith("/TdcWatch") and props["calibration"]["$ref"].endswith(
        "/CalibrationState")
    assert "serve --sensor-health" in props["enabled"]["description"]
    assert {"window_last_cycle", "wheel_offset_deg", "flags", "cylinders"} <= set(schemas["TdcWatch"]["required"])
    assert "sensor_tdc_offset_cyl<k>" in schemas["TdcWatch"]["properties"]["flags"]["description"]
    assert schemas["CalibrationState"]["properties"]["status"]["enum"] == ["uncalibrated", "commissioned"]


def test_analyze_sensor_health_switches_the_speed_based_stage_on(capsys) -> None:
    docs = {}
    for extra in ([], ["--sensor-health"]):
        assert main(["analyze", str(MARUTI), "--json", *extra]) == 0
        docs[bool(extra)] = json.loads(capsys.readouterr().out)
    assert docs[False]["sensor_health"] is None
    on = docs[True]["sensor_health"]
    assert on is not None and len(on["cylinders"]) == 3
    assert all(c["pressure_gain"] is not None for c in on["cylinders"])
    assert docs[True]["cycles_ok"] == docs[False]["cycles_ok"]


def test_serve_sensor_health_reaches_the_engines_pipeline() -> None:
    parser = build_parser()
    for extra, on in (([], False), (["--sensor-health"], True)):
        args = parser.parse_args(["serve", "--source", f"mcap:{MARUTI}", *extra])
        (svc,) = serve.build_engines(args, None)
        try:
            assert (svc.session.pipeline.config.sensor_health is not None) is on
            if on:  # and the results carry the stage's figures
                svc.start()
                assert wait_until(lambda svc=svc: svc.cycles_ok >= 3, timeout=300)
                assert svc.session.results[-1].sensor_health is not None
        finally:
            svc.stop()
