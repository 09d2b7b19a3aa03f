"""`frictionwatch analyze` on damaged logs: a truncated log, a corrupt chunk in the middle, and logs with nothing
usable. Every intact cycle is analysed, the damage is in the output (table line, ``--json`` keys ``log_damage``,
``cycles_skipped``, ``data_gaps``), exit code 0 with some good cycle, 2 with one line on stderr without one.

The log: the cached k9k-4cyl session of tests/service/live_helpers.py (20 cycles of 60 ms) written with 8 KiB chunks
(31 chunks of about 40 ms each), so one damaged chunk costs one or two cycles. Which data a chunk holds comes from the
intact file's chunk index (mcap's own reader): messages with log time in [message_start_time, message_end_time], each
holding up to about 10 ms of data before its log time (docs/replay-format.md §4, batching).

Per-cycle comparison with the intact log: before the damage everything is identical (same input, same monitor
history); after it the monitor's learned state has missed cycles, so pmax and mean speed (this cycle's own samples
and edges) must agree to 1e-9 and IMEP (through the learned tooth angles) to 1e-3.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from frictionwatch.drivers.logs.mcap_log import LogReader, LogWriter
from frictionwatch.drivers.logs.mcap_schema import last_tick
from frictionwatch.service.cli import main
from frictionwatch.service.pipeline import analyze_log
from mcap.reader import make_reader

from tests.analyze_doc import assert_fmep_is_torque_over_displacement
from tests.service.live_helpers import RPM, per_cycle, session

BATCH_S = 0.02  # a message holds at most about 10 ms of data before its log time; 20 ms to be safe


@pytest.fixture(scope="module")
def intact(tmp_path_factory):
    s = session()
    path = tmp_path_factory.mktemp("damaged") / "intact.mcap"
    with LogWriter(path, s.spec.source_text, s.sim.info, chunk_bytes=8 * 1024) as writer:
        for r in s.sim.records:
            writer.write(r)
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    return path, chunks, analyze_log(path)


def analyze_cli(path: Path, capsys, *extra: str) -> tuple[int, str, str]:
    rc = main(["analyze", str(path), *extra])
    out, err = capsys.readouterr()
    return rc, out, err


def touched(results, lo_s: float, hi_s: float) -> set[int]:
    """Cycles whose teeth (one pitch either side of the 720 deg window) or pressure meet [lo_s, hi_s]."""
    pitch = 60.0 / (RPM * session().sim.info.wheel_teeth)
    return {r.index for r in results if r.t_start - pitch <= hi_s and r.t_start + 120.0 / r.rpm_mean + pitch >= lo_s}


def assert_identical(got, want) -> None:
    for name, value in per_cycle(want).items():
        np.testing.assert_allclose(per_cycle(got)[name], value, rtol=1e-9, atol=0, err_msg=f"{name}, {want.index}")


def test_intact_log_reports_no_damage(intact, capsys):
    path, _, full = intact
    assert [r.index for r in full.results] == list(range(20))
    rc, out, _ = analyze_cli(path, capsys, "--json")
    doc = json.loads(out)
    assert_fmep_is_torque_over_displacement(doc)
    assert rc == 0 and doc["cycles_ok"] == 20
    assert doc["log_damage"] == {} and doc["cycles_skipped"] == {} and doc["data_gaps"] == []


def test_truncated_log_analyses_every_cycle_before_the_cut(intact, tmp_path, capsys):
    path, chunks, full = intact
    cut_chunk = chunks[len(chunks) * 6 // 10]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:cut_chunk.chunk_start_offset + cut_chunk.chunk_length // 2])
    rc, out, _ = analyze_cli(cut, capsys, "--json")
    doc = json.loads(out)
    assert rc == 0
    assert doc["log_damage"].get("truncated") == 1 and doc["log_damage"].get("partial chunk", 0) <= 1
    part = analyze_log(cut)
    # every cycle whose data lies before the first chunk cut away is there, identical to the intact log's
    complete_until = min(c.message_start_time for c in chunks[len(chunks) * 6 // 10:]) / 1e9 - BATCH_S
    must = {r.index for r in full.results if r.t_start + 120.0 / r.rpm_mean < complete_until}
    assert must and must <= {r.index for r in part.results}
    assert [r.index for r in part.results] == list(range(len(part.results))) and len(part.results) < 20
    for got in part.results:
        assert_identical(got, full.results[got.index])
    assert doc["cycles_ok"] == len(part.results) and doc["data_gaps"] == []
    rc, out, _ = analyze_cli(cut, capsys)  # the table says it too
    assert rc == 0 and "log damage: " in out and "truncated 1" in out


def test_corrupt_chunk_costs_only_the_cycles_it_held(intact, tmp_path, capsys):
    path, chunks, full = intact
    bad = chunks[len(chunks) // 2]
    data = bytearray(path.read_bytes())
    middle = bad.chunk_start_offset + bad.chunk_length // 2
    data[middle:middle + 16] = bytes(b ^ 0xFF for b in data[middle:middle + 16])
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(bytes(data))

    rc, out, _ = analyze_cli(broken, capsys, "--json")
    doc = json.loads(out)
    assert rc == 0
    assert doc["log_damage"] == {"corrupt chunk (crc)": 1}
    assert set(doc["cycles_skipped"]) <= {"data_gap", "sync_lost", "pressure_missing", "missing_tooth"}
    lo, hi = bad.message_start_time / 1e9 - BATCH_S, bad.message_end_time / 1e9
    assert len(doc["data_gaps"]) == 1
    gap = doc["data_gaps"][0]
    assert gap["from_s"] <= hi and gap["to_s"] >= lo

    got = analyze_log(broken).results
    by_start = {round(r.t_start, 6): r for r in full.results}
    found = {by_start[round(r.t_start, 6)].index for r in got}  # match by time: a new sync may renumber
    lost = {r.index for r in full.results} - found
    assert lost and lost <= touched(full.results, lo, hi)  # no good cycle outside the damaged span is lost
    assert gap["cycles"] == pytest.approx(len(lost), abs=0.5)
    for r in got:
        want = by_start[round(r.t_start, 6)]
        if want.index < min(lost):
            assert_identical(r, want)
        else:
            np.testing.assert_allclose(r.pmax, want.pmax, rtol=1e-9)
            np.testing.assert_allclose(r.rpm_mean, want.rpm_mean, rtol=1e-9)
            # the first cycle after the gap has no cycle before: IMEP over its own window (flagged), 2.3 % off here
            np.testing.assert_allclose(r.imep, want.imep, rtol=3e-2 if "no_previous_cycle" in r.flags else 1e-3)
    rc, out, _ = analyze_cli(broken, capsys)
    assert rc == 0 and "log damage: corrupt chunk (crc) 1" in out and "not analysed: " in out


def _cut_in_first_cycle(path: Path, chunks, full) -> bytes:
    """The log up to the end of its first chunk: readable records, none after cycle 0 ends."""
    data = path.read_bytes()[:chunks[0].chunk_start_offset + chunks[0].chunk_length]
    return data


@pytest.mark.parametrize("damage", ["empty", "not_mcap", "header_only", "cut_in_first_cycle"])
def test_no_good_cycle_is_one_line_and_exit_2(intact, tmp_path, capsys, damage):
    path, chunks, full = intact
    content = {
        "empty": b"",
        "not_mcap": b"time,rpm\n0.0,1500\n" * 200,
        "header_only": path.read_bytes()[:chunks[0].chunk_start_offset],
        "cut_in_first_cycle": _cut_in_first_cycle(path, chunks, full),
    }[damage]
    bad = tmp_path / f"{damage}.mcap"
    bad.write_bytes(content)
    if damage == "cut_in_first_cycle":  # precondition: something is readable, but not one whole cycle
        with LogReader(bad) as reader:
            ticks = [last_tick(r) for r in reader.records()]
        cycle0_end = full.results[0].t_start + 120.0 / full.results[0].rpm_mean
        assert ticks and max(ticks) / session().tick_hz < cycle0_end
    rc, out, err = analyze_cli(bad, capsys, "--json")
    lines = err.strip().splitlines()
    assert rc == 2 and out == ""
    assert len(lines) == 1 and "Traceback" not in err and lines[0].startswith("frictionwatch analyze: error: ")
    assert bad.name in lines[0]
    if damage == "cut_in_first_cycle":
        assert "no good cycle" in lines[0] and "truncated" in lines[0]
