"""GET .../ring-condition: each cylinder's ring-condition figure with its sigma and the evidence under it, as the
alert engine's RingConditionRule left it (driven here with constructed per-cycle results: a leak in cylinder 7 of
the demo's twenty from the first cycle is named against its siblings)."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient
from frictionwatch.service.alerts import AlertConfig, AlertEngine
from frictionwatch.service.api import create_app

from tests.service.serve_helpers import demo_service
from tests.service.test_alerts import _leak, _result

URL = "/api/v1/engines/demo/ring-condition"


def test_the_figures_of_every_cylinder_and_the_one_that_stands_off():
    made = {}

    def alerts(engine_id, spec):
        made["alerts"] = AlertEngine(spec, AlertConfig(baseline_cycles=100, skip_cycles=0))
        return made["alerts"]

    svc = demo_service("demo", alerts=alerts)
    try:
        with TestClient(create_app([svc], manage=False)) as client:
            assert client.get(URL).json() == []  # before the first cycle
            eng, rng = made["alerts"], np.random.default_rng(8)
            z = eng.spec.n_cyl
            for i in range(160):
                eng.update(_result(i, rng, _leak(7, 0.004, z=z), z=z))
            r = client.get(URL)
            assert r.status_code == 200
            rows = r.json()
            assert [row["cylinder"] for row in rows] == list(range(1, z + 1))
            seven = rows[6]
            assert seven["ring_condition_reference"] == "against_siblings"
            # 4 units of the floor (0.004 / 0.001) against the allowance of one unit
            assert abs(seven["ring_condition"] - 4.0) < 0.5 and abs(seven["ring_condition_sigma"] - 1.0) < 0.2
            assert max(abs(row["ring_condition_against_siblings"]) for row in rows if row["cylinder"] != 7) < 1.0
            assert [a["cylinder"] for a in client.get("/api/v1/engines/demo/alerts").json()
                    if a["kind"] == "ring_wear"] == [7]
    finally:
        svc.session.stop()
