"""Issue 28's check: the real `frictionwatch serve` restarted three times on one --data-dir (SQLite), ended once by
SIGTERM, once by SIGKILL, once by SIGTERM, on the bundled demo log looped at twice real time.

Run 1 learns the alert baseline from the healthy demo and stores it as it is learnt. Between runs 1 and 2 the stored
baseline is moved so that cylinder 3 now reads as leaking against it (what a ring worn while the service was down
looks like): run 2 must compare with the stored baseline, not relearn one (a relearnt one would call the worn ring
healthy and raise nothing), raise the alert, take an acknowledgement (alice) and die by SIGKILL. Run 3 must show that
alert still open, acknowledged by alice, not raised again, and append bob's acknowledgement without overwriting hers.
Throughout: every run's cycles numbered on from the last stored one, each row carrying its run, run 1's cycles and
estimates byte-for-byte what they were (nothing overwritten), SIGTERM losing no cycle the API had shown, and the file
passing SQLite's integrity check."""

from __future__ import annotations

import json
import os
import queue
import signal
import sqlite3
import subprocess
import sys
import threading
from pathlib import Path

import httpx
import numpy as np
import pytest
from frictionwatch.service.alert_baseline import INDICATORS, Baseline

from tests.service.serve_helpers import DEMO, ROOT, wait_until
from tests.service.test_serve_process import read_line

ENGINE = "genset-v20"
API = f"/api/v1/engines/{ENGINE}"
# a leak's signature in the indicators (service.alert_baseline.INDICATORS order): compression ratio and compression
# exponent down, expansion exponent up, expansion deficit down (tests/service/test_alerts.py _leak)
LEAK_SIGN = np.array([-1.5, -1.0, 1.0, -0.5])
pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]


class Serve:
    """One `frictionwatch serve` process on the demo log with --data-dir; its dashboard URL and token."""

    def __init__(self, data: Path) -> None:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen([sys.executable, "-m", "frictionwatch.service.cli", "serve", "--port", "0",
                                      "--source", f"mcap:{DEMO}?loop=1&speed=2", "--data-dir", str(data)],
                                     cwd=ROOT, env=env, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.lines: queue.Queue = queue.Queue()
        threading.Thread(target=lambda: [self.lines.put(x) for x in self.proc.stdout], daemon=True).start()
        self.said = read_line(self.proc, self.lines, rf"{ENGINE}: run (\d+), cycles from (\d+)", timeout=120)
        url = read_line(self.proc, self.lines, r"dashboard at (http://127\.0\.0\.1:\d+/)", timeout=600)[1]
        token = read_line(self.proc, self.lines, r"\(this run only\): (\S+)", timeout=10)[1]
        self.client = httpx.Client(base_url=url, timeout=30, headers={"Authorization": f"Bearer {token}"})

    def alerts(self) -> list[dict]:
        return self.client.get(f"{API}/alerts", params={"state": "all"}).json()

    def end(self, sig: int) -> int:
        self.client.close()
        self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout=120)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait(10)


class Db:
    """Read-only looks into the service's SQLite file while it runs (WAL: readers never block the writer)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def rows(self, sql: str, *params) -> list[tuple]:
        if not self.path.exists():
            return []
        conn = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True, timeout=30)
        try:
            return conn.execute(sql, params).fetchall()
        except sqlite3.OperationalError:  # the tables are not made yet
            return []
        finally:
            conn.close()

    def one(self, sql: str, *params):
        rows = self.rows(sql, *params)
        return rows[0][0] if rows else None


def _worn_baseline(doc: dict, cylinder: int) -> dict:
    """The stored baseline as if cylinder ``cylinder`` (1-based) had been healthy when it leaked 4 per-cycle sigmas
    less: the same engine now reads as leaking against it."""
    base = Baseline.from_dict(doc)
    out = json.loads(json.dumps(doc))
    for band, stored in zip(base.bands, out["bands"]):
        mean = np.array(stored["mean"], dtype=float).reshape(len(INDICATORS), -1)
        mean[:, cylinder - 1] -= 4.0 * LEAK_SIGN * band.sd[:, cylinder - 1]
        stored["mean"] = mean.tolist()
    return out


def test_restart_after_sigterm_and_sigkill_keeps_and_continues_everything(tmp_path):
    data = tmp_path / "data"
    db = Db(data / "frictionwatch.db")

    # ---- run 1: learn the baseline, end by SIGTERM ----------------------------------------------------------------
    run1 = Serve(data)
    assert run1.said.groups() == ("1", "0")
    assert wait_until(lambda: db.one("SELECT COUNT(*) FROM baselines") and
                      (db.one("SELECT MAX(cycle_index) FROM cycles") or 0) > 250, timeout=600), \
        "run 1 stored no learnt baseline within 600 s"
    shown = run1.client.get(f"{API}/cycles/latest").json()["cycle_index"]
    assert run1.end(signal.SIGTERM) == 0
    cycles1 = db.rows("SELECT cycle_index, run_id, rpm_mean, imep_bar, written_at FROM cycles ORDER BY cycle_index")
    estimates1 = db.rows("SELECT cycle_index, cylinder, run_id, fmep_bar, coefficients FROM estimates "
                         "ORDER BY cycle_index, cylinder")
    last1 = cycles1[-1][0]
    assert last1 >= shown, "SIGTERM lost cycles the API had shown"
    assert {r[1] for r in cycles1} == {1} and estimates1 and {r[2] for r in estimates1} == {1}
    learnt = json.loads(db.one("SELECT doc FROM baselines ORDER BY seq DESC LIMIT 1"))
    assert learnt["bands"][0]["cycles"] == 200  # AlertConfig.baseline_cycles: learnt whole, then stored

    # the ring of cylinder 3 wears while the service is down (module doc)
    conn = sqlite3.connect(data / "frictionwatch.db", isolation_level=None)
    conn.execute("INSERT INTO baselines (engine_id, seq, doc, saved_at) SELECT ?, MAX(seq) + 1, ?, 0 FROM baselines",
                 (ENGINE, json.dumps(_worn_baseline(learnt, 3))))
    conn.close()

    # ---- run 2: the stored baseline in force, the alert raised and acknowledged, then SIGKILL ------------------------
    run2 = Serve(data)
    assert run2.said.groups() == ("2", str(last1 + 1))
    assert wait_until(lambda: any(a["cylinder"] == 3 for a in run2.alerts()), timeout=300), run2.alerts()
    (alert,) = [a for a in run2.alerts() if a["cylinder"] == 3]
    assert alert["raised_cycle"] > last1
    acked = run2.client.post(f"{API}/alerts/{alert['alert_id']}/acknowledge", json={"by": "alice"}).json()
    assert acked["acknowledged_by"] == "alice"
    assert wait_until(lambda: db.one("SELECT state FROM alerts WHERE alert_id = ?", alert["alert_id"])
                      == "acknowledged", timeout=30)
    assert wait_until(lambda: db.one("SELECT COUNT(*) FROM cycles WHERE run_id = 2") >= 100, timeout=300)
    assert run2.end(signal.SIGKILL) == -signal.SIGKILL
    last2 = db.one("SELECT MAX(cycle_index) FROM cycles")

    # ---- run 3: the alert back as it was, a second acknowledgement appended, then SIGTERM ----------------------------
    run3 = Serve(data)
    assert run3.said.groups() == ("3", str(last2 + 1))
    back = [a for a in run3.alerts() if a["alert_id"] == alert["alert_id"]]
    assert back and back[0]["state"] == "acknowledged" and back[0]["acknowledged_by"] == "alice"
    again = run3.client.post(f"{API}/alerts/{alert['alert_id']}/acknowledge", json={"by": "bob"}).json()
    assert again["acknowledged_by"] == "alice"
    assert [a["by"] for a in again["acknowledgements"]] == ["alice", "bob"]
    assert wait_until(lambda: db.one("SELECT COUNT(*) FROM cycles WHERE run_id = 3") >= 100, timeout=300)
    on_cyl3 = [a for a in run3.alerts() if a["cylinder"] == 3]
    assert [a["alert_id"] for a in on_cyl3] == [alert["alert_id"]], "the worn ring was alerted on again"
    assert run3.end(signal.SIGTERM) == 0

    # ---- what the file holds ----------------------------------------------------------------------------------------
    runs = db.rows("SELECT run_id, first_cycle, last_cycle FROM runs ORDER BY run_id")
    assert [(r[0], r[1]) for r in runs] == [(1, 0), (2, last1 + 1), (3, last2 + 1)]
    cycles = db.rows("SELECT cycle_index, run_id FROM cycles ORDER BY cycle_index")
    assert [r[1] for r in cycles] == sorted(r[1] for r in cycles)  # numbering monotone across runs
    assert {r[1] for r in cycles} == {1, 2, 3}
    # run 1's rows as they were when it ended: exact equality (nothing rewritten, not even written_at)
    assert db.rows("SELECT cycle_index, run_id, rpm_mean, imep_bar, written_at FROM cycles WHERE run_id = 1 "
                   "ORDER BY cycle_index") == cycles1
    assert db.rows("SELECT cycle_index, cylinder, run_id, fmep_bar, coefficients FROM estimates WHERE run_id = 1 "
                   "ORDER BY cycle_index, cylinder") == estimates1
    assert db.one("SELECT COUNT(*) FROM estimates WHERE run_id = 3") > 0
    stored = json.loads(db.one("SELECT doc FROM alerts WHERE alert_id = ?", alert["alert_id"]))
    assert stored["acknowledged_by"] == "alice" and [a["by"] for a in stored["acknowledgements"]] == ["alice", "bob"]
    assert db.one("SELECT COUNT(*) FROM baselines") >= 2  # every baseline kept
    assert db.one("PRAGMA integrity_check") == "ok"
