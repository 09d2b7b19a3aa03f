"""POST/GET /api/v1/engines/{id}/discrepancy in-process (TestClient): a short simulated k9k log replayed through the
service, the workflow run as a job on the engine's recorded window; the route's auth, validation, 404s and the
one-job-at-a-time 409; a window too short fails with the workflow's own reason."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient
from frictionwatch.core.discrepancy import Options
from frictionwatch.service import discrepancy_jobs
from frictionwatch.service.api import create_app
from frictionwatch.service.cli import main
from frictionwatch.service.cmd_discrepancy import run_discrepancy
from frictionwatch.service.engine_service import RecentRecords

from tests.service.job_standins import ends_without_a_word, reports_a_bug, reports_a_report, reports_its_policy
from tests.service.serve_helpers import demo_service, wait_until

TOKEN = "t0ken-for-the-tests-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    path = tmp_path_factory.mktemp("apidisc") / "k9k.mcap"
    assert main(["simulate", "--engine", "k9k-4cyl", "--rpm", "2500", "--load", "0.8", "--cycles", "36", "--seed",
                 "3", "-o", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def served(log):
    whole = demo_service("k9k", f"mcap:{log}")
    short = demo_service("k9k-short", f"mcap:{log}", recent_s=0.5)  # ~10 cycles at 2500 rpm: too few
    with TestClient(create_app([whole, short], token=TOKEN)) as client:
        for s in (whole, short):
            assert wait_until(lambda s=s: s.sources_ended and s.session.cycles_ok > 0 and
                              s.state.snapshot(1)[0] is s.session.results[-1], timeout=900, every=0.5)
        yield client, whole, short


def _finished(client, engine: str, job_id: str, timeout: float = 900.0) -> dict:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        doc = client.get(f"/api/v1/engines/{engine}/discrepancy/{job_id}").json()
        if doc["state"] != "running":
            return doc
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} still running after {timeout} s")


def test_job_on_the_recorded_window_reports_what_the_cli_reports(served, log):
    client, whole, _ = served
    r = client.post("/api/v1/engines/k9k/discrepancy", json={"cycles": 2000, "max_steps": 0}, headers=AUTH)
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["state"] == "running" and job["report"] is None and job["records"] == len(whole.recent)
    doc = _finished(client, "k9k", job["job_id"])
    assert doc["state"] == "done" and doc["reason"] is None, doc["reason"]
    rep = doc["report"]
    print(f"job: {doc['records']} records, {rep['cycles']} cycles, {doc['elapsed_s']:.1f} s, gap {rep['gap_before']:.3g}")
    assert {"found", "gap_before", "gap_after", "metric", "verdict"} <= rep.keys()
    assert rep["found"] == [] and rep["cycles"] >= 28 and rep["engine"] == "k9k-4cyl"
    # the window is the whole replayed log: the same cycles and the same gap as the workflow on the file
    ref = run_discrepancy(log, "k9k-4cyl", Options(max_steps=0))
    assert rep["cycles"] == ref["cycles"]
    np.testing.assert_allclose([rep["gap_before"], rep["gap_after"]], [ref["gap_before"], ref["gap_after"]],
                               rtol=1e-9)


def test_too_few_cycles_fail_with_the_workflows_reason(served):
    client, _, short = served
    r = client.post("/api/v1/engines/k9k-short/discrepancy", json={"cycles": 28}, headers=AUTH)
    assert r.status_code == 202, r.text
    doc = _finished(client, "k9k-short", r.json()["job_id"])
    assert doc["state"] == "failed" and doc["report"] is None
    assert "the workflow needs at least 28" in doc["reason"] and "\n" not in doc["reason"]


def test_auth_and_validation(served):
    client, *_ = served
    url = "/api/v1/engines/k9k/discrepancy"
    assert client.post(url).status_code == 401
    assert client.post(url, headers={"Authorization": "Bearer wrong"}).status_code == 401
    for body in ({"baseline": "stiff"}, {"baseline": "without:../x"}, {"cycles": 5}, {"cycles": 10**6},
                 {"max_steps": -1}, {"window": 3}):
        assert client.post(url, json=body, headers=AUTH).status_code == 422, body
    r = client.post(url, json={"baseline": "without:ring_wear"}, headers=AUTH)  # well formed, not in the model
    assert r.status_code == 422 and "ring_wear" in r.json()["detail"]
    assert client.post("/api/v1/engines/nope/discrepancy", headers=AUTH).status_code == 404
    assert client.get("/api/v1/engines/nope/discrepancy/0123456789abcdef").status_code == 404
    assert client.get("/api/v1/engines/k9k/discrepancy/0123456789abcdef").status_code == 404
    assert client.get("/api/v1/engines/k9k/discrepancy/not-a-job").status_code == 422


def test_one_job_at_a_time(served, monkeypatch):
    client, *_ = served
    gate = threading.Event()
    real = discrepancy_jobs.run_job

    def held(*args, **kwargs):  # the jobs' bookkeeping under test, so a stand-in child (the workflow's: above)
        gate.wait(60)
        return real(*args, target=reports_a_report, **kwargs)

    monkeypatch.setattr(discrepancy_jobs, "run_job", held)
    url = "/api/v1/engines/k9k/discrepancy"
    first = client.post(url, json={"max_steps": 0, "cycles": 2000}, headers=AUTH)
    assert first.status_code == 202
    busy = client.post("/api/v1/engines/k9k-short/discrepancy", headers=AUTH)
    assert busy.status_code == 409 and first.json()["job_id"] in busy.json()["detail"]
    # the job of one engine is not another engine's
    assert client.get(f"/api/v1/engines/k9k-short/discrepancy/{first.json()['job_id']}").status_code == 404
    gate.set()
    done = _finished(client, "k9k", first.json()["job_id"])
    assert done["state"] == "done" and done["report"]["verdict"] == "a stand-in's report"
    again = client.post(url, json={"max_steps": 0, "cycles": 2000}, headers=AUTH)
    assert again.status_code == 202
    _finished(client, "k9k", again.json()["job_id"])


def test_recent_records_keep_the_newest_window():
    from frictionwatch.core.types import CamBatch

    ring = RecentRecords(window_s=1.0, tick_hz=1000.0)
    for t in range(0, 5000, 100):
        ring.append(CamBatch(ticks=np.array([t], dtype=np.int64)))
    kept = [int(r.ticks[-1]) for r in ring.window()]
    assert kept == list(range(3900, 5000, 100))  # ticks within 1 s (1000 ticks) of the newest
    assert [int(r.ticks[-1]) for r in ring.window(0.25)] == [4700, 4800, 4900]
    batched = RecentRecords(window_s=1.0, tick_hz=1000.0)  # the ingest thread's batches: the same records kept
    records = [CamBatch(ticks=np.array([t], dtype=np.int64)) for t in range(0, 5000, 100)]
    for i in range(0, len(records), 7):
        batched.extend(records[i:i + 7])
    batched.extend([])
    assert [int(r.ticks[-1]) for r in batched.window()] == kept
    with pytest.raises(ValueError, match="window"):
        RecentRecords(0.0, 1000.0)


def test_the_workflow_runs_in_a_process_of_its_own(served, monkeypatch):
    """A job's minutes of CPU take no share of serve's GIL: the workflow runs in a spawned child process. Here the
    workflow is broken in this process only; the job still finishes with the right report (on a thread of serve it
    would fail with this process's error)."""
    client, *_ = served

    def broken(*args, **kwargs):
        raise RuntimeError("the workflow ran in serve's own process")

    monkeypatch.setattr(discrepancy_jobs, "run_discrepancy", broken)
    r = client.post("/api/v1/engines/k9k/discrepancy", json={"cycles": 2000, "max_steps": 0}, headers=AUTH)
    doc = _finished(client, "k9k", r.json()["job_id"])
    assert doc["state"] == "done", doc["reason"]
    assert doc["report"]["found"] == [] and doc["report"]["cycles"] >= 28


def test_a_job_whose_process_dies_or_fails_says_so_in_one_line():
    from frictionwatch.service.discrepancy_jobs import JobProcessError, run_job

    with pytest.raises(JobProcessError, match=r"^the job's process ended without a report \(exit code 3\)$"):
        run_job(None, [], None, 0, target=ends_without_a_word)
    with pytest.raises(JobProcessError, match=r"^KeyError: 'odd'$"):
        run_job(None, [], None, 0, target=reports_a_bug)


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="Linux's SCHED_IDLE only")
def test_the_jobs_process_runs_only_where_nothing_else_wants_the_cpu():
    from frictionwatch.service.discrepancy_jobs import run_job

    assert run_job(None, [], None, 0, target=reports_its_policy) == {"policy": os.SCHED_IDLE}
