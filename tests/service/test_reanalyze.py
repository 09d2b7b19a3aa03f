"""`frictionwatch reanalyze DIR` (issue 18 item 4): one result per log, named by its path under DIR, the same
document `analyze --json` prints; failed logs as rows with their reason; up-to-date results kept, --force and a
changed log or model redo them.

The archive: three short k9k-4cyl logs (two named x.mcap in two folders, one deeper), one truncated log with no
whole cycle left and a text file named .mcap; every truth file beside them is overwritten with garbage (reanalyze
never reads them). Most runs go through `--scheduler` to an in-process LocalCluster (1 worker thread,
processes=False: Dask's scheduler, task submission and completion as in any run, without starting processes); one
run uses the default local cluster of worker processes (the results pickled back from another process).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from frictionwatch.service.cli import main

from tests.analyze_doc import assert_fmep_is_torque_over_displacement
from tests.json_close import assert_json_close

pytestmark = pytest.mark.slow  # collected first (tests/conftest.py): one of the suite's longest files

distributed = pytest.importorskip("distributed")

OK = ["a/deep/y.mcap", "a/x.mcap", "b/x.mcap"]
FAILED = ["a/junk.mcap", "b/cut.mcap"]


def simulate(path: Path, rpm: int, seed: int, cycles: int = 8) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert main(["simulate", "--engine", "k9k-4cyl", "--rpm", str(rpm), "--load", "0.6", "--cycles", str(cycles),
                 "--seed", str(seed), "-o", str(path)]) == 0
    path.with_name(path.stem + ".truth.json").write_text("not json: never read")


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("archive")
    simulate(root / "a" / "x.mcap", 2000, 1)
    simulate(root / "b" / "x.mcap", 1500, 2)
    simulate(root / "a" / "deep" / "y.mcap", 2500, 3)
    data = (root / "a" / "x.mcap").read_bytes()
    (root / "b" / "cut.mcap").write_bytes(data[:len(data) // 5])
    (root / "a" / "junk.mcap").write_text("a text file, not a log\n")
    return root


@pytest.fixture(scope="module")
def scheduler():
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as c:
        yield c.scheduler_address


def reanalyze(capsys, *args: str) -> tuple[int, dict]:
    rc = main(["reanalyze", *args, "--json"])
    out = capsys.readouterr().out
    return rc, json.loads(out)


def rows(index: dict) -> dict[str, dict]:
    return {r["log"]: r for r in index["logs"]}


def analyze_json(log: Path, capsys, *extra: str) -> dict:
    assert main(["analyze", str(log), "--json", *extra]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert_fmep_is_torque_over_displacement(doc)
    return doc


def test_one_result_per_log_and_failed_rows_with_reasons(archive, scheduler, tmp_path, capsys):
    out = tmp_path / "out"
    rc, index = reanalyze(capsys, str(archive), "--out", str(out), "--scheduler", scheduler)
    assert rc == 1  # some logs failed
    by = rows(index)
    assert sorted(by) == sorted(OK + FAILED) and index["logs_found"] == 5
    assert (index["ok"], index["failed"], index["analysed_this_run"]) == (3, 2, 5)
    for rel in OK:
        r = by[rel]
        assert r["status"] == "ok" and r["reason"] is None and r["cycles"] > 0 and r["engine"] == "k9k-4cyl"
        assert r["result"] == rel + ".json" and (out / r["result"]).is_file()
        doc = json.loads((out / r["result"]).read_text())
        assert doc["cycles_ok"] == r["cycles"] and doc["friction"]["fmep_bar"] == r["fmep_bar"]
    assert "not an MCAP file" in by["a/junk.mcap"]["reason"]
    assert "truncated" in by["b/cut.mcap"]["reason"]
    for rel in FAILED:
        assert by[rel]["status"] == "failed" and by[rel]["result"] is None and "\n" not in by[rel]["reason"]
        assert not (out / (rel + ".json")).exists()
    # the two x.mcap are two results, not one overwriting the other (different speeds: different figures)
    ax, bx = (json.loads((out / f"{d}/x.mcap.json").read_text()) for d in "ab")
    assert abs(ax["rpm_mean"] - 2000) < 50 and abs(bx["rpm_mean"] - 1500) < 50
    assert json.loads((out / "index.json").read_text()) == index
    assert sorted(p.name for p in out.rglob("*.part")) == []


def test_each_result_is_what_analyze_json_prints(archive, scheduler, tmp_path, capsys):
    out = tmp_path / "out"
    reanalyze(capsys, str(archive / "a"), "--out", str(out), "--scheduler", scheduler, "--engine", "k9k-4cyl")
    for rel in ("x.mcap", "deep/y.mcap"):
        want = analyze_json(archive / "a" / rel, capsys, "--engine", "k9k-4cyl")
        got = json.loads((out / (rel + ".json")).read_text())
        assert_json_close(got, want, rtol=1e-12, atol=0.0, where=rel)  # same input, same code


def test_rerun_keeps_up_to_date_results_and_force_or_a_newer_log_redoes(archive, scheduler, tmp_path, capsys):
    out = tmp_path / "out"
    common = [str(archive), "--out", str(out), "--scheduler", scheduler]
    reanalyze(capsys, *common)
    stamps = {rel: (out / (rel + ".json")).stat().st_mtime_ns for rel in OK}

    rc, index = reanalyze(capsys, *common)
    by = rows(index)
    assert rc == 1 and index["up_to_date_kept"] == 3 and index["analysed_this_run"] == 2
    assert all(not by[rel]["this_run"] for rel in OK) and all(by[rel]["this_run"] for rel in FAILED)
    assert {rel: (out / (rel + ".json")).stat().st_mtime_ns for rel in OK} == stamps
    assert [by[rel]["fmep_bar"] for rel in OK] == [r["fmep_bar"] for r in index["logs"] if r["log"] in OK]

    later = time.time() + 5  # the log changed after its result was written
    os.utime(archive / "b" / "x.mcap", (later, later))
    try:
        by = rows(reanalyze(capsys, *common)[1])
        assert by["b/x.mcap"]["this_run"] and not by["a/x.mcap"]["this_run"]
    finally:
        os.utime(archive / "b" / "x.mcap")

    rc, index = reanalyze(capsys, *common, "--force")
    assert index["analysed_this_run"] == 5 and index["up_to_date_kept"] == 0
    assert all((out / (rel + ".json")).stat().st_mtime_ns > stamps[rel] for rel in OK)

    # another model: nothing is up to date for it (the index keeps each result's model digest)
    rc, index = reanalyze(capsys, *common, "--engine", "k9k-4cyl")
    assert index["analysed_this_run"] == 5 and index["model_sha256"] is not None
    # a model that cannot be this engine: every log fails, and no result of the earlier model is left as if current
    rc, index = reanalyze(capsys, *common, "--engine", "deutz-1cyl")
    by = rows(index)
    assert rc == 1 and index["ok"] == 0
    assert all("does not match" in by[rel]["reason"] for rel in OK)
    assert not any((out / (rel + ".json")).exists() for rel in OK)


def test_sensor_health_is_analyze_sensor_health_and_part_of_up_to_date(archive, scheduler, tmp_path, capsys):
    out = tmp_path / "out"
    common = [str(archive / "a"), "--out", str(out), "--scheduler", scheduler]
    _, index = reanalyze(capsys, *common)
    assert index["sensor_health"] is False and all(r["sensor_health"] is False for r in index["logs"])
    _, index = reanalyze(capsys, *common, "--sensor-health")  # results without the stage are not its results
    by = rows(index)
    assert index["sensor_health"] is True and by["x.mcap"]["this_run"] and by["x.mcap"]["sensor_health"] is True
    got = json.loads((out / "x.mcap.json").read_text())
    assert got["sensor_health"] is not None and len(got["sensor_health"]["cylinders"]) == 4
    assert_json_close(got, analyze_json(archive / "a" / "x.mcap", capsys, "--sensor-health"), rtol=1e-12, atol=0.0,
                      where="x.mcap")
    _, index = reanalyze(capsys, *common, "--sensor-health")
    assert not rows(index)["x.mcap"]["this_run"]  # the same settings: kept
    _, index = reanalyze(capsys, *common)
    assert rows(index)["x.mcap"]["this_run"] and json.loads((out / "x.mcap.json").read_text())["sensor_health"] is None


def test_the_default_local_cluster_of_worker_processes(archive, tmp_path, capsys):
    single = tmp_path / "one"
    single.mkdir()
    (single / "x.mcap").write_bytes((archive / "a" / "x.mcap").read_bytes())
    rc, index = reanalyze(capsys, str(single), "--workers", "1")
    assert rc == 0 and index["ok"] == 1 and "1 worker processes" in index["cluster"]
    got = json.loads((single / "reanalysis" / "x.mcap.json").read_text())
    assert_json_close(got, analyze_json(single / "x.mcap", capsys), rtol=1e-12, atol=0.0)
    rc, index = reanalyze(capsys, str(single), "--workers", "1")  # the output folder inside DIR is not searched
    assert rc == 0 and index["logs_found"] == 1 and index["up_to_date_kept"] == 1


@pytest.mark.parametrize("args, needle", [
    (["{missing}"], "is not a folder"),
    (["{empty}"], "no *.mcap log under"),
    (["{archive}", "--model", "{bad_model}"], "bad.toml"),
    (["{archive}", "--engine", "no-such-engine"], "unknown engine"),
    (["{archive}", "--workers", "0"], "--workers must be >= 1"),
])
def test_usage_errors_are_one_line_exit_2(archive, tmp_path, capsys, args, needle):
    (tmp_path / "empty").mkdir()
    (tmp_path / "bad.toml").write_text("name = [unclosed\n")
    paths = {"missing": tmp_path / "nope", "empty": tmp_path / "empty", "archive": archive,
             "bad_model": tmp_path / "bad.toml"}
    rc = main(["reanalyze", *(a.format(**paths) for a in args)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and needle in err, err


def test_analyze_does_not_import_dask():
    code = ("import sys; from frictionwatch.service.cli import build_parser; build_parser(); "
            "print(sorted(m for m in ('dask', 'distributed') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
