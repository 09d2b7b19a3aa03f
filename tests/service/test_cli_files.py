"""Files and faults of `simulate` and `import-daq` (issue 20): outputs whole or absent, refused early when they cannot
be written, never half-written by an interruption, a full disk or a concurrent run."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.core.types import ToothBatch
from frictionwatch.drivers.logs.mcap_log import LogReader, LogWriter
from frictionwatch.service import cmd_import_daq, cmd_simulate
from frictionwatch.service.cli import main
from frictionwatch.service.output_files import atomic_paths
from frictionwatch.service.progress import Bar

from tests.json_close import assert_json_close

DEUTZ = ["simulate", "--engine", "deutz-1cyl", "--rpm", "2600", "--load", "0.8", "--seed", "4"]
K9K = ["simulate", "--engine", "k9k-4cyl", "--rpm", "1700", "--seed", "1"]
TUE = Path(__file__).resolve().parents[3] / "shared/realdata/tue-4gb10-si-encoder-pressure/group14_E0FULLOAD1.txt.gz"


def names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def one_line(err: str, *needles: str) -> str:
    err = err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, err
    return err


def one_line_error(capsys, *needles: str) -> str:
    return one_line(capsys.readouterr().err, *needles)


def old_pair(folder: Path) -> None:
    """A previous run's output, which a failed run must leave as it was."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "x.mcap").write_bytes(b"old log")
    (folder / "x.truth.json").write_text("{}")


def assert_old_pair_only(folder: Path) -> None:
    assert names(folder) == ["x.mcap", "x.truth.json"]
    assert (folder / "x.mcap").read_bytes() == b"old log" and (folder / "x.truth.json").read_text() == "{}"


def test_simulate_writes_the_log_and_the_streamed_truth_whole(tmp_path):
    out = tmp_path / "d.mcap"
    assert main([*DEUTZ, "--cycles", "3", "-o", str(out)]) == 0
    assert names(tmp_path) == ["d.mcap", "d.truth.json"]  # no temporary left
    probe = tmp_path / "probe"
    probe.write_text("")
    assert out.stat().st_mode & 0o777 == probe.stat().st_mode & 0o777  # the umask's mode, not mkstemp's 0600
    want = simulate(load_engine("deutz-1cyl"), 2600, 0.8, 3, 4).truth
    assert_json_close(json.loads((tmp_path / "d.truth.json").read_text()), want, rtol=1e-12, atol=1e-300)
    with LogReader(out) as log:
        assert sum(1 for _ in log.records()) > 0 and not log.damage


class FailingWriter(LogWriter):
    """A LogWriter whose ``write`` fails with ``error`` once ``after`` records went through."""

    after = 50
    error: BaseException = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    written = 0

    def write(self, record) -> None:
        if FailingWriter.written >= self.after:
            raise self.error
        FailingWriter.written += 1
        super().write(record)


@pytest.mark.parametrize("error", [OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)), KeyboardInterrupt()],
                         ids=["disk-full", "ctrl-c"])
def test_writer_failure_mid_run_leaves_the_old_files(tmp_path, monkeypatch, capsys, error):
    old_pair(tmp_path)
    monkeypatch.setattr(FailingWriter, "error", error)
    monkeypatch.setattr(FailingWriter, "written", 0)
    monkeypatch.setattr(cmd_simulate, "LogWriter", FailingWriter)
    rc = main([*K9K, "--cycles", "12", "-o", str(tmp_path / "x.mcap")])
    assert FailingWriter.written == FailingWriter.after  # records were being written when it failed
    assert_old_pair_only(tmp_path)
    if isinstance(error, KeyboardInterrupt):
        assert rc == 130
    else:
        assert rc == 2
        one_line_error(capsys, "No space left on device", "nothing was written")


def test_ctrl_c_from_the_progress_bar_late_in_the_run_leaves_nothing(tmp_path, monkeypatch):
    seen = []
    set_fraction = Bar.set_fraction

    def interrupt(self, fraction):
        set_fraction(self, fraction)
        seen.append(fraction)
        if fraction > 0.9:
            raise KeyboardInterrupt

    monkeypatch.setattr(Bar, "set_fraction", interrupt)
    monkeypatch.setattr(FailingWriter, "after", 10**9)
    monkeypatch.setattr(FailingWriter, "written", 0)
    monkeypatch.setattr(cmd_simulate, "LogWriter", FailingWriter)
    assert main([*K9K, "--cycles", "12", "-o", str(tmp_path / "out" / "k.mcap")]) == 130
    assert FailingWriter.written > 100 and max(seen) < 1.0
    assert names(tmp_path / "out") == []


@pytest.fixture
def small_tmpfs(tmp_path):
    """A 200 kB tmpfs (a real full disk); skipped where mounting is not permitted."""
    folder = tmp_path / "small"
    folder.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=200k", "tmpfs", str(folder)],
                             capture_output=True, check=False).returncode == 0 if os.geteuid() == 0 else False
    if not mounted:
        pytest.skip("cannot mount a small tmpfs here (needs root and mount permission)")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=True)


def test_real_full_disk_leaves_nothing(small_tmpfs, capsys):
    rc = main([*K9K, "--cycles", "25", "-o", str(small_tmpfs / "k.mcap")])  # about 270 kB of log: does not fit
    assert rc == 2
    one_line_error(capsys, "No space left on device", "nothing was written")
    assert names(small_tmpfs) == []


def test_read_only_filesystem_is_refused_before_simulating(small_tmpfs, capsys):
    subprocess.run(["mount", "-o", "remount,ro", str(small_tmpfs)], check=True)
    start = time.perf_counter()
    assert main(["simulate", "--engine", "genset-v20", "--rpm", "1500", "--cycles", "100000",
                 "-o", str(small_tmpfs / "v20.mcap")]) == 2
    assert time.perf_counter() - start < 1.0
    one_line_error(capsys, "not writable")


def test_impossible_output_is_refused_at_once(tmp_path, capsys):
    (tmp_path / "some_file").write_text("")
    start = time.perf_counter()
    assert main(["simulate", "--engine", "genset-v20", "--rpm", "1500", "--cycles", "100000",
                 "-o", str(tmp_path / "some_file" / "out.mcap")]) == 2
    assert time.perf_counter() - start < 1.0  # refused before the (hours long) simulation, not after it
    one_line_error(capsys, "some_file is a file, not a folder")
    assert names(tmp_path) == ["some_file"]


def test_two_concurrent_simulate_runs_leave_one_whole_pair(tmp_path):
    """Both runs finish; the log on disk decodes whole and the truth beside it is the same run's (3 or 5 cycles)."""
    out = tmp_path / "x.mcap"
    procs = [subprocess.Popen([sys.executable, "-m", "frictionwatch.service.cli", *DEUTZ, "--cycles", str(n),
                               "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE) for n in (3, 5)]
    for p in procs:
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err.decode()
    assert names(tmp_path) == ["x.mcap", "x.truth.json"]
    truth = json.loads((tmp_path / "x.truth.json").read_text())
    with LogReader(out) as log:
        teeth = np.concatenate([r.ticks for r in log.records() if isinstance(r, ToothBatch)])
        assert not log.damage
        tick_hz = log.info.tick_hz
    # the run ends at theta_F = 4 pi cycles + pi/2: the last tooth 1.125 cycles after the last cycle's start
    period = 120.0 / truth["rpm_mean"]
    expected_end = truth["cycles"][-1]["t_start_s"] + 1.125 * period
    assert abs(teeth[-1] / tick_hz - expected_end) < 0.1 * period, truth["cycles_count"]


COMMIT_LOOP = """
import sys
from pathlib import Path
from frictionwatch.service.output_files import atomic_paths
folder, tag = Path(sys.argv[1]), sys.argv[2]
for i in range(40):
    with atomic_paths(folder / "a.json", folder / "b.log") as (a, b):
        a.write_text(f"{tag}-{i}")
        b.write_text(f"{tag}-{i}" * 1000)
"""


def test_concurrent_commits_of_a_pair_never_mix_two_runs(tmp_path):
    procs = [subprocess.Popen([sys.executable, "-c", COMMIT_LOOP, str(tmp_path), tag]) for tag in "pqrs"]
    assert all(p.wait(timeout=120) == 0 for p in procs)
    assert names(tmp_path) == ["a.json", "b.log"]
    token = (tmp_path / "a.json").read_text()
    assert (tmp_path / "b.log").read_text() == token * 1000


def test_atomic_paths_removes_every_temporary_on_failure(tmp_path):
    with pytest.raises(KeyboardInterrupt), atomic_paths(tmp_path / "a", tmp_path / "b") as (a, b):
        a.write_text("x")
        b.write_text("y")
        raise KeyboardInterrupt
    assert names(tmp_path) == []
    with pytest.raises(ValueError, match="same output twice"), atomic_paths(tmp_path / "a", tmp_path / "a"):
        pass


TUE_OPTS = ("--engine", "tue-4gb10", "--tdc-deg", "244.5", "--gain-bar-per-v", "12.4")  # the rig, stated


@pytest.mark.skipif(not TUE.exists(), reason="real data folder ../shared/realdata absent")
def test_import_daq_is_whole_or_absent(tmp_path, monkeypatch, capsys):
    (tmp_path / "some_file").write_text("")
    start = time.perf_counter()
    assert main(["import-daq", str(TUE), *TUE_OPTS, "-o", str(tmp_path / "some_file" / "t.mcap")]) == 2
    assert time.perf_counter() - start < 1.0  # before reading the table
    one_line_error(capsys, "is a file, not a folder")
    monkeypatch.setattr(FailingWriter, "after", 20)
    monkeypatch.setattr(FailingWriter, "written", 0)
    monkeypatch.setattr(cmd_import_daq, "LogWriter", FailingWriter)
    assert main(["import-daq", str(TUE), *TUE_OPTS, "-o", str(tmp_path / "t.mcap")]) == 2
    one_line_error(capsys, "No space left on device", "nothing was written")
    assert names(tmp_path) == ["some_file"]


def test_analyze_does_not_call_a_cut_log_complete(tmp_path, capsys):
    """A log cut short (what a non-atomic writer left behind) is reported as damaged, never as a whole recording:
    cut after some chunks it is analysed with a "log damage" line; cut inside its first chunk it is refused."""
    out = tmp_path / "k.mcap"
    assert main([*K9K, "--cycles", "30", "-o", str(out)]) == 0
    data = out.read_bytes()
    capsys.readouterr()
    for fraction, rc in ((0.75, 0), (0.02, 2)):
        cut = tmp_path / f"cut{fraction}.mcap"
        cut.write_bytes(data[: int(len(data) * fraction)])
        assert main(["analyze", str(cut)]) == rc
        said = capsys.readouterr()
        report = said.out if rc == 0 else one_line(said.err, "damage")
        assert ("log damage" in report or rc == 2) and "truncated" in report, report
