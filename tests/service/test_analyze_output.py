"""What `frictionwatch analyze` says and writes: the JSON document against its schema (docs/results.md), the status,
data weight and window of every figure, flags per window in JSON / CSV / table, the CSV's values, and the progress.

Logs: a k9k-4cyl log that misfires cylinder 2 in ~1 of 5 cycles (the simulator's truth names the misfired cycles),
and the same log with its load records removed (a log the monitor is not told has no load)."""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.monitor.report.figure_status import friction_status, split_flag
from frictionwatch.core.monitor.report.run_summary import (
    active_flags,
    estimate_window,
    flag_summary,
    mean_and_sem,
    smoothed_mean_and_sigma,
)
from frictionwatch.core.types import LoadSample
from frictionwatch.drivers.logs.mcap_log import LogReader, LogWriter
from frictionwatch.service.cli import main
from frictionwatch.service.cmd_analyze import SCHEMA_FILE, SCHEMA_VERSION
from frictionwatch.service.progress import Bar, log_extent
from numpy.testing import assert_allclose

from tests.analyze_doc import assert_fmep_is_torque_over_displacement

jsonschema = pytest.importorskip("jsonschema")
CYCLES = 80


@pytest.fixture(scope="module")
def misfire_log(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("output") / "misfire.mcap"
    assert main(["simulate", "--engine", "k9k-4cyl", "--rpm", "1700", "--load", "0.8", "--cycles", str(CYCLES),
                 "--seed", "3", "--effect", "misfire:cylinder=2,probability=0.2", "-o", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def misfire_run(misfire_log, tmp_path_factory):
    """(document, CSV rows, CSV text, table text, stderr) of one analyze run with --json and --csv."""
    folder = tmp_path_factory.mktemp("run")
    csv_path = folder / "misfire.csv"
    cap = _Capture()
    with cap:
        assert main(["analyze", str(misfire_log), "--json", "--csv", str(csv_path)]) == 0
    text = csv_path.read_bytes().decode()
    assert assert_fmep_is_torque_over_displacement(json.loads(cap.out)) >= 6
    return json.loads(cap.out), list(csv.DictReader(text.splitlines())), text, cap.err, csv_path


@pytest.fixture(scope="module")
def truth(misfire_log) -> dict:
    return json.loads(misfire_log.with_name("misfire.truth.json").read_text())


def misfired(truth: dict, cylinder: int) -> list[int]:
    """Cycles in which the simulator gave the cylinder no fuel (net IMEP below zero: a motored cycle)."""
    return [c["index"] for c in truth["cycles"] if c["cylinders"][cylinder - 1]["imep_bar"] < 0.0]


def test_the_document_follows_its_schema(misfire_run):
    doc = misfire_run[0]
    schema = json.loads(SCHEMA_FILE.read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    jsonschema.validate(doc, schema)
    assert doc["schema_version"] == SCHEMA_VERSION
    bad = json.loads(json.dumps(doc))
    bad["cylinders"][0]["friction"]["status"] = "estimated"  # not a status: the schema must refuse it
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema)
    del bad["cylinders"][0]["friction"]
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema)


def test_per_cylinder_keys_are_the_truth_files_where_they_mean_the_same(misfire_run, truth):
    doc = misfire_run[0]
    shared = {"cylinder", "friction_torque_mean_nm", "fmep_bar", "imep_bar", "pmax_bar_mean", "coefficients",
              "coefficients_normalised"}
    for got, want in zip(doc["cylinders"], truth["cylinders"]):
        assert shared <= set(got) and shared <= set(want)
        # both the run mean, misfires included; analyze's window is centred on the cylinder's own firing TDC, the
        # truth's is the cycle's: at the run's ends they hold up to one different cycle (a misfire or not)
        per_cycle = [c["cylinders"][got["cylinder"] - 1]["imep_bar"] for c in truth["cycles"]]
        edge = (max(per_cycle) - min(per_cycle)) / len(per_cycle)
        assert abs(got["imep_bar"] - want["imep_bar"]) <= 0.01 * abs(want["imep_bar"]) + edge
        assert_allclose(got["pmax_bar_mean"], want["pmax_bar_mean"], rtol=0.01)
    assert_allclose(doc["rpm_mean"], truth["rpm_mean"], rtol=0.002)
    assert_allclose(doc["load_torque_mean_nm"], truth["load_torque_mean_nm"], rtol=0.02)


def test_misfires_every_fifth_cycle_are_in_json_and_csv(misfire_run, truth):
    doc, rows = misfire_run[:2]
    want = misfired(truth, 2)
    assert 0.1 * CYCLES <= len(want) <= 0.35 * CYCLES  # the log does misfire about one cycle in five
    assert doc["flags"]["cycles"]["misfire_cyl2"] == want
    assert doc["flags"]["run"]["misfire_cyl2"] == len(want)
    assert sum(w["counts"].get("misfire_cyl2", 0) for w in doc["flags"]["windows"]) == len(want)
    assert "misfire" in doc["flags"]["kinds"] and "misfire_cyl2" in doc["active_flags"]
    assert not any(k.startswith("misfire_cyl") and k != "misfire_cyl2" for k in doc["flags"]["run"])
    flagged = {(int(r["cycle"]), int(r["cylinder"])) for r in rows if r["flag_misfire"] == "1"}
    assert flagged == {(c, 2) for c in want}


def test_every_figure_says_what_it_is(misfire_run):
    doc = misfire_run[0]
    eng = doc["friction"]
    assert eng["status"] == "measured" and eng["reason"] is None  # the log has a load measurement
    assert doc["fmep_bar"] == eng["fmep_bar"] and doc["fmep_sigma_bar"] > 0
    w = eng["window"]
    assert w["first_cycle"] == 20 and w["last_cycle"] == CYCLES - 1  # the monitor's 20 warm-up cycles
    assert 0 < w["effective_cycles"] <= CYCLES - 20 and w["first_cycle"] < w["centre_cycle"] < w["last_cycle"]
    assert 0.99 < w["forgetting"] < 1.0
    for c in doc["cylinders"]:
        f = c["friction"]
        assert 0.0 < f["data_weight"] <= 1.0
        if f["status"] == "measured":
            assert c["friction_torque_mean_nm"] == f["friction_torque_mean_nm"] is not None
        else:  # never a number under the measured keys
            assert f["status"] == "share" and "not a measurement" in f["reason"]
            assert c["friction_torque_mean_nm"] is None and c["fmep_bar"] is None
            assert f["friction_torque_mean_nm"] == c["share_friction_torque_mean_nm"]


def test_the_run_mean_is_reported_beside_the_end_of_run_estimate(misfire_run, truth):
    doc = misfire_run[0]
    run = doc["friction_run_mean_balance"]
    # every cycle but the first, which has no cycle before it (no kinetic-energy term, so no balance)
    assert run["status"] == "measured" and run["window"]["effective_cycles"] == CYCLES - 1
    assert run["window"]["forgetting"] == 1.0 and run["window"]["centre_cycle"] == CYCLES / 2
    # the run mean of the balance against the truth's run mean, within 2 of its own sigmas
    assert abs(run["fmep_bar"] - truth["fmep_bar"]) <= 2 * run["fmep_sigma_bar"]


def test_csv_values_sigmas_status_and_line_endings(misfire_run, misfire_log):
    doc, rows, text, err, path = misfire_run
    assert "\r" not in text and text.endswith("\n")
    assert len(rows) == 4 * CYCLES and err.strip().splitlines()[-1] == f"wrote {path}"  # stdout: the JSON only
    last = [r for r in rows if int(r["cycle"]) == CYCLES - 1]
    for r, c in zip(last, doc["cylinders"]):
        assert r["friction_status"] == c["friction"]["status"]
        assert_allclose(float(r["friction_torque_mean_nm"]), c["friction"]["friction_torque_mean_nm"], rtol=1e-12)
        assert_allclose(float(r["fmep_bar"]), c["friction"]["fmep_bar"], rtol=1e-12)
        assert float(r["friction_torque_sigma_nm"]) > 0 and float(r["imep_smoothed_sigma_bar"]) > 0
        assert_allclose(float(r["engine_fmep_bar"]), doc["fmep_bar"], rtol=1e-12)
    accumulated = [r for r in rows if int(r["cycle"]) >= 20]
    assert all(r["friction_torque_mean_nm"] and r["fmep_bar"] for r in accumulated)  # no longer empty
    assert {r["engine_friction_status"] for r in rows if 0 < int(r["cycle"]) < 20} == {"prior"}  # the warm-up
    assert {r["engine_friction_status"] for r in rows if int(r["cycle"]) == 0} == {"unresolved"}  # no cycle before
    # the smoothed IMEP of cylinder 1 with the estimate's forgetting, recomputed from the per-cycle column
    lam = doc["friction"]["window"]["forgetting"]
    imep = np.array([float(r["imep_bar"]) for r in rows if r["cylinder"] == "1"])
    wts = lam ** np.arange(CYCLES - 1, -1, -1)
    assert_allclose(float([r for r in rows if r["cylinder"] == "1"][-1]["imep_smoothed_bar"]),
                    np.sum(wts * imep) / wts.sum(), rtol=1e-9)


def test_the_table_says_what_the_numbers_are(misfire_log, capsys):
    assert main(["analyze", str(misfire_log)]) == 0
    out = capsys.readouterr().out
    assert "kW" in out and "N·m" in out and "± is 1σ" in out
    assert "paper" not in out and "Eq." not in out
    rows = [ln for ln in out.splitlines() if ln[:4].strip().isdigit() and "rpm" not in ln]  # not the transient lines
    assert len(rows) == 4 and all(ln.endswith(("measured", "share, not measured")) for ln in rows)
    assert "end-of-run estimate over cycles 20-" in out and "mean over the whole run" in out
    lines = out.splitlines()
    flags_at = next(i for i, ln in enumerate(lines) if ln.startswith("flags"))
    assert any("misfire_cyl2" in ln for ln in lines[flags_at:])
    assert flags_at > next(i for i, ln in enumerate(lines) if ln.strip().startswith("4 "))  # under the numbers


def test_no_load_measurement_gives_no_engine_friction(misfire_log, tmp_path, capsys):
    """The same log without its load records: the engine's friction cannot be balanced, so it is unresolved (no
    number anywhere under the measured keys) and no cylinder shows a share of it."""
    noload = tmp_path / "noload.mcap"
    with LogReader(misfire_log) as reader, LogWriter(noload, reader.engine_toml, reader.info) as writer:
        for record in reader.records():
            if not isinstance(record, LoadSample):
                writer.write(record)
    assert main(["analyze", str(noload), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert_fmep_is_torque_over_displacement(doc)
    jsonschema.validate(doc, json.loads(SCHEMA_FILE.read_text()))
    assert doc["friction"]["status"] == "unresolved" and "no load measurement" in doc["friction"]["reason"]
    assert doc["fmep_bar"] is None and doc["friction"]["fmep_bar"] is None
    assert doc["friction_run_mean_balance"]["status"] == "unresolved" and doc["load_torque_mean_nm"] is None
    assert all(c["friction"]["status"] in ("measured", "unresolved") for c in doc["cylinders"])
    assert "no_load_measurement" in doc["active_flags"]
    assert main(["analyze", str(noload)]) == 0
    assert "load not measured" in capsys.readouterr().out


# ---- the status rules and the run bookkeeping on made-up inputs ---------------------------------------------------

class _Est:
    def __init__(self, resolved, gain, mean, share, total=20.0, weight=50.0):
        self.resolved = np.array(resolved)
        self.data_gain = np.array(gain, dtype=float)
        self.friction_torque_mean = np.array(mean, dtype=float)
        self.prior_friction_torque_mean = np.array(share, dtype=float)
        self.total_friction_torque = total
        self.weight = weight
        self.source = "data"


def test_status_rules():
    est = _Est([True, False, False], [0.8, 0.2, 0.9], [5.0, math.nan, math.nan], [4.9, 5.1, 5.0])
    st = friction_status(est, ["misfire_cyl2"])
    assert st.engine.status == "measured"
    assert [c.status for c in st.cylinders] == ["measured", "share", "share"]
    assert st.cylinders[1].data_weight == 0.2 and "0.20" in st.cylinders[1].reason
    # any sensor_* kind withholds: on a cylinder that cylinder, on the engine everything
    st = friction_status(est, ["sensor_gain_cyl1", "operating_point_changed"])
    assert [c.status for c in st.cylinders] == ["withheld", "share", "share"] and st.engine.status == "measured"
    assert "sensor_gain_cyl1" in st.cylinders[0].reason
    st = friction_status(est, ["sensor_tdc_offset"])
    assert st.engine.status == "withheld" and {c.status for c in st.cylinders} == {"withheld"}
    st = friction_status(est, ["no_load_measurement"])
    assert st.engine.status == "unresolved" and [c.status for c in st.cylinders] == ["measured", "unresolved",
                                                                                      "unresolved"]
    st = friction_status(_Est([False] * 3, [0.3] * 3, [math.nan] * 3, [5.0] * 3, weight=0.0), [])
    assert st.engine.status == "prior" and {c.status for c in st.cylinders} == {"unresolved"}
    assert {c.data_weight for c in st.cylinders} == {0.0}  # nothing accumulated: nothing from the data
    one = friction_status(_Est([True], [1.0], [7.0], [7.0]), [])
    assert one.cylinders[0].status == "measured" and one.cylinders[0].data_weight is None  # no split to learn


def test_split_flag():
    assert split_flag("misfire_cyl12") == ("misfire", 12)
    assert split_flag("sensor_pegging_offset_cyl3") == ("sensor_pegging_offset", 3)
    assert split_flag("no_load_measurement") == ("no_load_measurement", None)
    assert split_flag("odd_cyl0") == ("odd_cyl0", None)


def test_estimate_window_recovers_the_forgetting_and_centre():
    lam, warm, n = 0.99, 5, 300
    w, acc = [], 0.0
    for i in range(n):
        if i >= warm:
            acc = lam * acc + 1.0
        w.append(acc)
    idx = np.arange(100, 100 + n)
    win = estimate_window(idx, w)
    assert (win.first_cycle, win.last_cycle) == (105, 399)
    assert_allclose(win.forgetting, lam, rtol=1e-12)
    age = np.arange(n - warm - 1, -1, -1)
    assert_allclose(win.centre_cycle, np.sum(lam ** age * idx[warm:]) / np.sum(lam ** age), rtol=1e-12)
    assert win.centre_cycle > 100 + n / 2  # an end-of-run estimate is not the run's mean
    assert estimate_window([3, 4], [0.0, 0.0]).first_cycle is None
    # a restart of the accumulation (the weight back to one cycle's) starts the window again: first cycle, centre
    # and forgetting those of the cycles after it (the ring's first cycle and middle before)
    restart = 200
    w2 = list(w[:restart])
    acc = 0.0
    for _ in range(restart, n):
        acc = lam * acc + 1.0
        w2.append(acc)
    win = estimate_window(idx, w2)
    assert (win.first_cycle, win.last_cycle) == (100 + restart, 399)
    assert_allclose(win.effective_cycles, w2[-1], rtol=0)
    assert_allclose(win.forgetting, lam, rtol=1e-12)
    age = np.arange(n - restart - 1, -1, -1)
    assert_allclose(win.centre_cycle, np.sum(lam ** age * idx[restart:]) / np.sum(lam ** age), rtol=1e-12)
    # a long run: the weight reaches its floating-point fixed point and stops changing; the window still ends at
    # the last cycle, centred ~1/(1 - lambda) - 1 cycles before it
    lam, w, acc = 1.0 - 1.0 / 400.0, [], 0.0
    for _ in range(20000):
        acc = lam * acc + 1.0
        w.append(acc)
    assert w[-1] == w[-2]
    win = estimate_window(np.arange(20000), w)
    assert_allclose(win.forgetting, lam, rtol=1e-12)
    assert_allclose(win.centre_cycle, 19999 - lam / (1.0 - lam), rtol=1e-9)


def test_flag_windows_and_active_flags():
    idx = list(range(1000, 1250))
    flags = [("misfire_cyl2",) if i % 5 == 0 else () for i in idx]
    flags[-1] = ("sensor_gain_cyl1",)
    s = flag_summary(idx, flags, window_cycles=100)
    assert [(w["first_cycle"], w["cycles"]) for w in s["windows"]] == [(1000, 100), (1100, 100), (1200, 50)]
    assert [w["counts"]["misfire_cyl2"] for w in s["windows"]] == [20, 20, 10]
    assert s["run"] == {"misfire_cyl2": 50, "sensor_gain_cyl1": 1} and s["cycles"]["sensor_gain_cyl1"] == [1249]
    assert s["kinds"] == ["misfire", "sensor_gain"]
    assert active_flags(flags, 100) == {"misfire_cyl2", "sensor_gain_cyl1"}  # 20 % of the window; the newest
    assert active_flags(flags[:-1] + [()], 1000) == {"misfire_cyl2"}


def test_smoothed_mean_and_sigma_against_direct_sums():
    rng = np.random.default_rng(1)
    x = rng.normal(10.0, 2.0, size=(400, 3))
    mean, sigma = smoothed_mean_and_sigma(x, 0.98)
    wts = 0.98 ** np.arange(399, -1, -1)
    m = wts @ x / wts.sum()
    n_eff = wts.sum() ** 2 / (wts ** 2).sum()
    var = (wts @ (x - m) ** 2 / wts.sum()) * n_eff / (n_eff - 1)
    assert_allclose(mean[-1], m, rtol=1e-12)
    assert_allclose(sigma[-1], np.sqrt(var / n_eff), rtol=1e-9)
    plain, plain_sig = smoothed_mean_and_sigma(x[:, 0], None)
    assert_allclose(plain[-1], x[:, 0].mean(), rtol=1e-12)
    assert_allclose(plain_sig[-1], mean_and_sem(x[:, 0])[1], rtol=1e-9)
    assert np.isnan(plain_sig[0])


# ---- progress and output paths --------------------------------------------------------------------------------------

def test_progress_counts_cycles_and_follows_the_log(misfire_log):
    extent = log_extent(misfire_log)
    assert extent.known and 0.5 * CYCLES * 120 / 1700 < extent.end_s - extent.start_s < 1.5 * CYCLES * 120 / 1700
    assert extent.fraction(extent.start_s) == 0.0 and extent.fraction(extent.end_s + 1.0) == 1.0

    class FakeTqdm:
        n, total = 0, 1

        def refresh(self):
            pass

        def update(self, n):
            self.n += n

    shown = FakeTqdm()
    bar = Bar(shown, 1)
    for i in range(10):
        bar.advance(extent.fraction(extent.start_s + (i + 1) * (extent.end_s - extent.start_s) / 20))
    assert bar.count == shown.n == 10 and shown.total == 20  # half-way through the log: ~20 cycles in all
    counted = FakeTqdm()
    unknown = Bar(counted, 0)
    unknown.advance(None)
    assert unknown.count == counted.n == 1 and counted.total == 1


def test_an_unwritable_output_is_refused_before_the_run(misfire_log, tmp_path, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    for args, needle in ((["--csv", str(blocker / "x.csv")], "is a file, not a folder"),
                         (["--csv", str(tmp_path)], "is a folder"),
                         (["--plot", str(blocker)], "is a file, expected a folder")):
        rc = main(["analyze", str(misfire_log), *args])
        out, err = capsys.readouterr()
        assert rc == 2 and needle in err and len(err.splitlines()) == 1, err
        assert out == ""  # no table: the run never started
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        if not os.access(folder, os.W_OK):  # (root writes anyway: that case is covered above)
            assert main(["analyze", str(misfire_log), "--csv", str(folder / "x.csv")]) == 2
            assert "not writable" in capsys.readouterr().err
    finally:
        folder.chmod(0o700)


class _Capture:
    """stdout and stderr of an in-process CLI call (pytest's capsys does not mix with module-scoped fixtures)."""

    def __enter__(self):
        import io
        import sys

        self._saved = sys.stdout, sys.stderr
        sys.stdout, sys.stderr = io.StringIO(), io.StringIO()
        return self

    def __exit__(self, *exc):
        import sys

        self.out, self.err = sys.stdout.getvalue(), sys.stderr.getvalue()
        sys.stdout, sys.stderr = self._saved


def test_real_fired_file_without_a_load_reports_no_friction(tmp_path, capsys):
    """TU/e 4GB10, a fired file (10 cycles, no load channel): no friction figure may read as a measurement."""
    from tests.realdata.conftest import REALDATA

    raw = REALDATA / "tue-4gb10-si-encoder-pressure" / "group14_E0FULLOAD1.txt.gz"
    if not raw.is_file():
        pytest.skip(f"real data {raw} is absent")
    log = tmp_path / "tue-full1.mcap"
    assert main(["import-daq", str(raw), "--engine", "tue-4gb10", "--tdc-deg", "244.5", "--gain-bar-per-v", "12.4",
                 "-o", str(log)]) == 0
    capsys.readouterr()
    assert main(["analyze", str(log), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert_fmep_is_torque_over_displacement(doc)
    jsonschema.validate(doc, json.loads(SCHEMA_FILE.read_text()))
    assert doc["friction"]["status"] == "unresolved" and doc["fmep_bar"] is None
    assert doc["friction"]["fmep_bar"] is None and doc["friction_run_mean_balance"]["fmep_bar"] is None
    assert [c["friction"]["status"] for c in doc["cylinders"]] == ["unresolved"]
    assert doc["flags"]["run"]["no_load_measurement"] == doc["cycles_ok"]
