"""serve's warm-up (service/warmup.py, design note 126): after it, a live run of the engine meets no kernel it has not
compiled or loaded, and a replay starts only once it is over.

The check runs each engine in a fresh process: a kernel specialisation, once compiled or loaded from numba's cache,
stays in the process, so a pipeline run before it (another test) would hide a kernel the warm-up missed. It counts
every specialisation numba adds to a dispatcher of ours after the warm-up (compiled or loaded from the on-disk cache:
either is the mid-run stall on a cold cache), while the engine's bundled replay log is analysed as serve analyses
it (the pipeline and the alert engine, the log looped) past every count the stages wait for: the TDC and gain watches'
third 100-cycle window, the alert baseline's 200 cycles.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from frictionwatch.core.monitor.pipeline import STAGES
from frictionwatch.core.monitor.warmup import WARM_CYCLES, warm_stages
from frictionwatch.drivers.source import Source
from frictionwatch.service.serve import stop_summary
from numpy.testing import assert_allclose

ROOT = Path(__file__).resolve().parents[2]
RUN_CYCLES = 320  # past the watches' third window (300) and the alert baseline (skip 5 + 200)

# in a fresh process: warm up the engine of LOG, then analyse LOG looped for RUN_CYCLES cycles; print the kernel
# specialisations added after the warm-up as JSON. BREAK: "stages" runs the warm-up with the stages as they are;
# "noblocks" without its third pass (service.warmup.block_pass); "nohealth" with the monitor's default settings;
# "nosensor" without the second pass's sensor fault (core.monitor.warmup.sensor_fault_state); "notraces" without
# the result's traces asked for (service.warmup.warm_traces). Every result goes through the API's views of one
# result as a dashboard's requests would (service/api_views.py: friction torque, speed).
# KIND: "blocks" the log's pressure frames as one PressureBlock per cylinder (a CAN, DAQ or serial source's
# records); "faults" the monitor with its sensor-health stage (serve --sensor-health) over the engine simulated with
# a pressure channel's gain and the wheel's TDC off (the simulator's effects: flagged within ~20 cycles, then
# corrected), simulated before the snapshot
_CHILD = r"""
import gc, json, sys
from numba.core.dispatcher import Dispatcher
log, cycles, brk, kind = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]

def ours():
    return {id(d): (f"{d.py_func.__module__}.{d.py_func.__qualname__}", set(d.overloads)) for d in gc.get_objects()
            if isinstance(d, Dispatcher) and d.py_func.__module__.startswith("frictionwatch.")}

from frictionwatch.drivers.logs.mcap_replay import McapSource
from frictionwatch.service import warmup
from frictionwatch.service.alerts import AlertEngine
from frictionwatch.service.pipeline import EnginePipeline, resolve_model
from frictionwatch.core.types import PressureFrame
from frictionwatch.drivers.assembly.pressure_ring import frame_blocks
if brk == "stages":
    from frictionwatch.core.monitor.pipeline import STAGES
    warmup.warm_stages = lambda: STAGES
if brk == "noblocks":
    warmup.block_pass = lambda records, rpm, info: []
if brk == "nosensor":
    warmup.sensor_fault_state = lambda state: state
if brk == "notraces":
    warmup.warm_traces = lambda result: None
from frictionwatch.service import api_views
src = McapSource(log, speed=None, loop=True)
model = resolve_model(src.engine_toml, None, log, src.info)
config = None
info, flags = src.info, set()
if kind == "faults":
    from frictionwatch.core.model.engine_model import EngineModel
    from frictionwatch.core.monitor.checks.sensor_health import SensorHealthConfig
    from frictionwatch.core.monitor.state import MonitorConfig
    from frictionwatch.core.plant.simulate import simulate
    config = MonitorConfig(sensor_health=SensorHealthConfig())
alerts = AlertEngine(model.spec)
alerts.load_kernels()
progress = warmup.WarmUpProgress()
warmup.warm_up(model, src.info, None if brk == "nohealth" else config, alerts, progress)
if kind == "faults":
    faulty = EngineModel.from_spec(model.spec, effects={"pressure_gain": {"cylinder": min(2, model.spec.n_cyl),
                                                                          "gain": 1.15},
                                                        "tdc_offset": {"cylinder": 0, "deg": 3.0}})
    second = src.info.second_wheel is not None and model.spec.sensors.second_wheel is not None
    sim = simulate(faulty, *warmup.warm_point(model), cycles + 4, 3, second_wheel=second)
    info, stream = sim.info, iter([sim.records])
else:
    stream = iter(lambda: src.read(0.1), None)
before = ours()
pipe = EnginePipeline(model, info, config)
n = 0
for records in stream:
    if kind == "blocks":
        records = [b for r in records for b in (frame_blocks(r) if isinstance(r, PressureFrame) else (r,))]
    for record in records:
        for result in pipe.feed(record):
            alerts.update(result)
            flags.update(result.flags)
            api_views.friction_torque(result)
            api_views.speed(result, [result])
            n += 1
    if n >= cycles:
        break
added = [f"{name} {sorted(map(str, sigs - before.get(key, (name, set()))[1]))}"
         for key, (name, sigs) in ours().items() if sigs - before.get(key, (name, set()))[1]]
print(json.dumps({"added": added, "cycles": n, "tdc_windows": pipe.tdc_window_cycle, "error": progress.error,
                  "steps": [progress.step, progress.steps], "flags": sorted(flags),
                  "pressure_blocks": sum(len(c) == 1 for c in pipe.assembler.buf.groups)}))
"""


def added_after_warm_up(log: str, cycles: int = RUN_CYCLES, brk: str = "", kind: str = "log") -> dict:
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(ROOT / "replay_logs" / log), str(cycles), brk, kind],
                          capture_output=True, text=True, timeout=1500, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("log", ["demo.mcap", "k9k-4cyl.mcap", "deutz-1cyl.mcap"])
def test_no_kernel_is_added_after_the_warm_up(log):
    """genset-v20 (20 cylinders: the TDC watch fits four a window and screens the rest), k9k-4cyl (a second wheel,
    the joint fit) and deutz-1cyl (one cylinder: no sibling comparisons): nothing compiled or loaded mid-run."""
    out = added_after_warm_up(log)
    assert out["error"] is None
    assert out["steps"][0] == out["steps"][1]
    assert out["cycles"] >= RUN_CYCLES and out["tdc_windows"] is not None and out["tdc_windows"] >= 300
    assert out["added"] == [], "kernels compiled or loaded after the warm-up:\n" + "\n".join(out["added"])


def test_the_check_sees_a_stage_the_warm_up_leaves_out():
    """The same check with the stages as a live run has them (100-cycle windows, no ``warm_up()``): the TDC
    watch's fit is first reached mid-run, and the check says so (the check can fail)."""
    out = added_after_warm_up("deutz-1cyl.mcap", cycles=110, brk="stages")
    assert any("tdc_kernels.gauss_newton_kernel" in a for a in out["added"]), out["added"]


def test_the_check_sees_a_trace_the_warm_up_leaves_out():
    """The same check with the warm-up's ``warm_traces`` left out: the API's friction-torque view first compiles
    core's ``rows_on_grid`` at a dashboard's first request, mid-run (as a fresh install's `make run` did)."""
    out = added_after_warm_up("deutz-1cyl.mcap", cycles=5, brk="notraces")
    assert any("grid_rows.rows_on_grid" in a for a in out["added"]), out["added"]


BLOCK_RUN_CYCLES = 120  # the pressure rings wrap within a few cycles; the monitor's own paths are the log check's


def test_no_kernel_is_added_by_pressure_blocks():
    """A source that delivers pressure as one PressureBlock per cylinder (CAN, the DAQ import, a log of either):
    the assembler's block rings are warmed by the warm-up's third pass (service.warmup.block_pass): nothing compiled
    or loaded mid-run (before it, design note 136: ``write_block``, ``pressure_rows`` and ``search_sorted`` on 1-D
    arrays were)."""
    out = added_after_warm_up("k9k-4cyl.mcap", cycles=BLOCK_RUN_CYCLES, kind="blocks")
    assert out["error"] is None and out["steps"][0] == out["steps"][1]
    assert out["cycles"] >= BLOCK_RUN_CYCLES and out["pressure_blocks"] == 4  # every cylinder a ring of its own
    assert out["added"] == [], "kernels compiled or loaded after the warm-up:\n" + "\n".join(out["added"])


def test_the_check_sees_pressure_blocks_the_warm_up_leaves_out():
    """The same check with the warm-up's third pass left out: the block kernels are first reached mid-run."""
    out = added_after_warm_up("k9k-4cyl.mcap", cycles=20, brk="noblocks", kind="blocks")
    assert any("ringbuffer.write_block" in a for a in out["added"]), out["added"]


FAULT_CYCLES = 80  # the faults below are flagged by cycle ~20 (min_cycles 8, then the evidence's 4 sigma)


@pytest.mark.parametrize("log", ["demo.mcap", "k9k-4cyl.mcap"])
def test_no_kernel_is_added_by_a_sensor_fault(log):
    """serve --sensor-health over an engine whose pressure channel 2 reads 15 % high and whose wheel is 3 deg off
    (simulated): the stage flags both and corrects the pressure and the pistons' phases from then on (a branch of
    its own, core.monitor.checks.sensor_health.corrected_inputs), with nothing compiled or loaded mid-run.
    genset-v20 estimates the wheel alone (20 cylinders), k9k-4cyl jointly with each cylinder's own offset."""
    out = added_after_warm_up(log, cycles=FAULT_CYCLES, kind="faults")
    assert out["error"] is None and out["cycles"] >= FAULT_CYCLES
    assert {"sensor_pressure_gain_cyl2", "sensor_tdc_offset"} <= set(out["flags"]), out["flags"]
    assert out["added"] == [], "kernels compiled or loaded after the warm-up:\n" + "\n".join(out["added"])


def test_warm_stages_shorten_every_windowed_stage():
    """Each stage with a window has a warm-up form whose window fits the warm-up's cycles."""
    for live, warm in zip(STAGES, warm_stages(), strict=True):
        window = getattr(live, "window", None)
        if window is not None:
            assert warm.window * 3 < WARM_CYCLES < window, (live, warm)


def test_a_replay_starts_after_the_warm_up_and_health_says_starting(monkeypatch):
    """While the warm-up runs the replay's session has not started (its clock has not either: nothing to drop),
    /startup and /health say 'compiling kernels: k of N'; then the replay runs."""
    from fastapi.testclient import TestClient
    from frictionwatch.service import warmup
    from frictionwatch.service.api import create_app
    from frictionwatch.service.serve import build_engine

    release, entered = threading.Event(), threading.Event()

    def held_warm_up(model, info, config, alerts, progress):
        progress.started_s = time.monotonic()
        progress.step = 3
        entered.set()
        release.wait(30)
        progress.step, progress.ended_s = progress.steps, time.monotonic()
        return 0.0

    monkeypatch.setattr(warmup, "warm_up", held_warm_up)
    svc = build_engine(None, [f"mcap:{ROOT / 'replay_logs' / 'deutz-1cyl.mcap'}?speed=max"], None, set())
    try:
        with TestClient(create_app([svc], token="t" * 32)) as client:
            assert entered.wait(10)
            assert not svc.session._started and svc.running
            health = client.get("/api/v1/health").json()
            assert health["status"] == "starting"
            # "compiling" where this process has compiled a kernel (a cold cache), else "loading"
            assert health["engines"][0]["warming_up"]
            assert health["engines"][0]["startup"].endswith(f"ing kernels: 3 of {svc.warmup.steps}")
            startup = client.get("/api/v1/startup").json()
            assert startup["engines"][0]["warm_up"] == health["engines"][0]["startup"]
            assert startup["message"].endswith(f": 3 of {svc.warmup.steps} warm-up steps")
            release.set()
            assert svc.session.wait_results(3, timeout=600)  # a cold cache compiles the pipeline here
            assert not svc.warming_up and svc.backlog()["dropped_records"] == 0
    finally:
        release.set()
        svc.stop()


class Board(Source):
    """A source that runs at the engine's pace and cannot wait (``speed`` set, no ``reanchor``: what
    service.live.is_realtime and is_replay_paced read), fed by a replay at real time: a serial or CAN board's
    stand-in."""

    speed = 1.0

    def __init__(self, inner: Source) -> None:
        super().__init__()
        self.feed, self.info, self.engine_toml = inner, inner.info, inner.engine_toml

    def _read_internal(self, timeout: float | None) -> list:
        return self.feed.read(timeout)

    def _close_internal(self) -> None:
        self.feed.close()


def test_a_board_without_a_hold_counts_what_its_queue_cannot_hold(monkeypatch):
    """A board's session starts at once: its input is queued while the ingest thread warms up; with no hold
    (serve --hold-mb 0) what the queue (1 s here) cannot hold is dropped and counted as a hole, not lost unsaid
    (design note 126)."""
    from frictionwatch.drivers.logs.mcap_replay import McapSource
    from frictionwatch.service import warmup
    from frictionwatch.service.engine_service import EngineService
    from frictionwatch.service.pipeline import resolve_model

    release = threading.Event()

    def held_warm_up(model, info, config, alerts, progress):
        progress.started_s = time.monotonic()
        release.wait(30)
        progress.step, progress.ended_s = progress.steps, time.monotonic()
        return 0.0

    monkeypatch.setattr(warmup, "warm_up", held_warm_up)
    board = Board(McapSource(ROOT / "replay_logs" / "deutz-1cyl.mcap", speed=1.0, loop=True))
    model = resolve_model(board.engine_toml, None, "deutz", board.info)
    svc = EngineService("board", model, board.info, {"board": board}, warm=True, max_queue_s=1.0,
                        hold_bytes=0).start()
    try:
        assert svc.session._started and svc.warming_up  # read from the start, analysed after the warm-up
        time.sleep(3.0)
        assert svc.cycles_ok == 0 and svc.backlog()["dropped_records"] > 0  # the queue's 1 s held, the rest counted
        release.set()
        assert svc.session.wait_results(3, timeout=600)
        holes = svc.holes
        assert holes and holes[0]["reason"] == "dropped_while_behind" and holes[0]["dropped_records"] > 0
    finally:
        release.set()
        svc.stop()


class FastBoard(Source):
    """A board's stand-in that has given its whole stream by the time a slow warm-up ends: ``records`` in reads of
    BOARD_BATCH as fast as they are asked for, then nothing, for ever (a board does not end); ``speed`` set and no
    ``reanchor``: real time that cannot wait, to the session (service.live.is_realtime, is_replay_paced)."""

    speed = 1.0

    def __init__(self, records: list, info, engine_toml: str | None) -> None:
        super().__init__()
        self.records, self.info, self.engine_toml = records, info, engine_toml
        self.given = threading.Event()  # every record handed out
        self._i = 0

    def _read_internal(self, timeout: float | None) -> list:
        if self._i >= len(self.records):
            self.given.set()
            time.sleep(timeout or 0.0)
            return []
        out = self.records[self._i:self._i + BOARD_BATCH]
        self._i += BOARD_BATCH
        return out


BOARD_BATCH = 12  # records a read (~40 ms of a genset's stream, as a paced replay reads them)


def one_pass(log: str) -> tuple[list, object, str | None]:
    """The records of one pass of a bundled replay log (no seam), its acquisition and its engine."""
    from frictionwatch.drivers.errors import EndOfStream
    from frictionwatch.drivers.logs.mcap_replay import McapSource

    src = McapSource(ROOT / "replay_logs" / log, speed=None)
    records: list = []
    try:
        while True:
            records += src.read(0.1)
    except EndOfStream:
        pass
    finally:
        src.close()
    return records, src.info, src.engine_toml


def test_a_board_loses_nothing_while_the_warm_up_runs_past_its_queue(monkeypatch):
    """A cold start's warm-up outlasting the queue's span (1 s of acquisition here, the board's stream ~2.8 s, all
    given before the warm-up ends): the queue holds it (LiveSession.hold, design note 136), nothing is dropped, and
    every cycle is analysed after the warm-up, in order, numbered without a gap -- the same cycles, with the same
    figures, as the stream read offline."""
    from frictionwatch.service import warmup
    from frictionwatch.service.engine_service import EngineService
    from frictionwatch.service.pipeline import EnginePipeline, resolve_model

    records, info, toml = one_pass("deutz-1cyl.mcap")
    board = FastBoard(records, info, toml)
    model = resolve_model(toml, None, "deutz", info)

    def slow_warm_up(model, info, config, alerts, progress):  # the compile's stand-in: over once all was read
        progress.started_s = time.monotonic()
        assert board.given.wait(30)
        time.sleep(0.5)
        progress.step, progress.ended_s = progress.steps, time.monotonic()
        return progress.seconds

    monkeypatch.setattr(warmup, "warm_up", slow_warm_up)
    offline = EnginePipeline(model, info)
    want = [r for rec in records for r in offline.feed(rec)]
    assert len(want) > 25
    svc = EngineService("board", model, info, {"board": board}, warm=True, max_queue_s=1.0).start()
    try:
        assert board.given.wait(30) and svc.warming_up
        assert svc.backlog()["holding"] and svc.backlog()["dropped_records"] == 0
        assert svc.session.wait_results(len(want), timeout=600), svc.cycles_ok
        lag = svc.backlog()
        assert lag["dropped_records"] == 0 and not lag["holding"]  # caught up: the hold is over
        assert lag["held_s"] > 2.0 and lag["held_records"] == len(records) and lag["held_bytes"] > 0
        got = svc.session.results
        assert [r.index for r in got] == [r.index for r in want] == list(range(want[0].index, want[-1].index + 1))
        assert_allclose([r.rpm_mean for r in got], [r.rpm_mean for r in want], rtol=1e-12)
        assert_allclose([r.imep[0] for r in got], [r.imep[0] for r in want], rtol=1e-9)
        assert svc.holes == [] and "dropped_while_behind" not in svc.restarts and svc.skipped == {}
    finally:
        svc.stop()
    line = stop_summary(svc)
    assert "held while the kernels warmed up: up to" in line and "nothing dropped" in line
    assert "dropped while" not in line


def test_the_warm_up_alone_from_the_command_line(capsys):
    """``python -m frictionwatch.service.warmup LOG`` (the image's build, Dockerfile): the log's engine warmed up, or
    one line and exit status 2 for a log it cannot read."""
    from frictionwatch.service import warmup

    assert warmup.main([str(ROOT / "replay_logs" / "demo.mcap")]) == 0
    assert capsys.readouterr().out.startswith("warm-up of genset-v20: ")
    assert warmup.main([str(ROOT / "README.md")]) == 2
    out = capsys.readouterr().out
    assert out.startswith("warm-up: ") and "not an MCAP file" in out and out.count("\n") == 1


def test_the_warm_point_is_inside_the_engines_speed_range_away_from_its_edge():
    """Half the rated speed, or a fifth into the speed range where that is higher (genset-v20's half, 750 rpm, is
    below its 1,100-1,650 range; at the edge itself cycles skipped speed_out_of_range)."""
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.model.engine_model import EngineModel
    from frictionwatch.service.warmup import warm_point

    for name, rpm in (("genset-v20", 1210.0), ("k9k-4cyl", 2000.0), ("deutz-1cyl", 1500.0), ("maruti-3cyl", 3000.0)):
        got, _ = warm_point(EngineModel.from_spec(load_engine(name)))
        assert abs(got - rpm) < 1e-9, (name, got)


def test_the_warm_up_s_sensor_fault_is_flagged_and_corrected():
    """core.monitor.warmup.sensor_fault_state, as the warm-up's second pass sets it where the sensor-health stage is
    on: the next cycle runs with cylinder 1's pressure and the wheel corrected (the fault's branch) and flags the
    gain. (The wheel's flag on four cylinders comes from the accumulated normal equations, which the faulty state
    leaves as they were: it is corrected, not flagged, there.)"""
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.model.engine_model import EngineModel
    from frictionwatch.core.monitor.checks.sensor_health import SensorHealthConfig
    from frictionwatch.core.monitor.state import MonitorConfig
    from frictionwatch.core.monitor.warmup import FAULT_GAIN, FAULT_WHEEL_RAD, sensor_fault_state
    from frictionwatch.core.plant.simulate import simulate
    from frictionwatch.service.pipeline import EnginePipeline
    from frictionwatch.service.warmup import warm_point

    model = EngineModel.from_spec(load_engine("k9k-4cyl"))
    sim = simulate(model, *warm_point(model), 8, 1)
    pipe = EnginePipeline(model, sim.info, MonitorConfig(sensor_health=SensorHealthConfig()))
    results = []
    for record in sim.records:
        if len(results) == 2 and pipe.cycles.state is not None and not pipe.cycles.state.sensor.count > 50:
            pipe.cycles.state = sensor_fault_state(pipe.cycles.state)
        results += pipe.feed(record)
    assert len(results) >= 4
    assert not any(f.startswith("sensor_") for r in results[:2] for f in r.flags)
    after = results[2]  # the first cycle after the faulty state: run with its corrections
    assert "sensor_pressure_gain_cyl1" in after.flags, after.flags
    assert_allclose(after.sensor_health.applied_gain, [1.0 + FAULT_GAIN, 1.0, 1.0, 1.0], rtol=1e-12)
    assert_allclose(after.sensor_health.applied_tdc, FAULT_WHEEL_RAD, rtol=1e-12)
