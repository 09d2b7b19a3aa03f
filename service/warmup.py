"""Before an engine's first record: every kernel its live pipeline will call compiled, or loaded from numba's cache.

    progress = WarmUpProgress()
    warm_up(model, info, config, alerts, progress)     # seconds; progress.step of progress.steps meanwhile
    WarmStart(engine_id, model, info, session, alerts).start()   # serve's: the warm-up, then the session

Why (design note 126): numba compiles a kernel when it is first called with new argument types. On a fresh install
serve compiled ~300 of them at its first cycle and six more mid-run (the TDC watch's fit near cycle 100, the ring
condition at the first alert update, ...: 15-30 s in all), on the ingest thread, while a real-time source went on:
its queue overran and input was dropped (design note 124). Here the engine's own pipeline -- the cycle assembler,
the monitor with its stages (core.monitor.warmup: their counts shortened) and the alert engine
(``AlertEngine.warm_up``: its learning counts shortened) -- runs ``WARM_CYCLES`` cycles of the engine simulated
(core.plant.simulate: the engine's model, its wheels and cylinders; the records a replay of it carries) with a loop
seam, a dropped stretch and the identification's bounds active in the second pass, so that every kernel a live run
reaches is compiled before the live run starts; and a result's trace that is computed only when asked for (the
API's friction-torque view: ``warm_traces``), so that a dashboard's first request compiles nothing either.
The warm-up's pipeline and alert engine are thrown away: nothing of it reaches the engine's results.

What it costs: on an empty cache the compile it moves before the first cycle, plus the simulator's own kernels; on a
warm cache the kernels load as they would have at the first cycle, plus the simulation and ~30 monitor cycles: a
few seconds (figures: design note 126).

What it cannot see: a kernel reached only by input the simulated stream does not have (a source's own record kinds,
a sensor fault's path). ``STARTUP.compiles`` counts what still compiles after it, and serve's stop line says so.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.monitor.warmup import (
    WARM_CYCLES,
    bound_state,
    sensor_fault_state,
    warm_config,
    warm_stages,
)
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.core.types import AcquisitionInfo, PressureFrame
from frictionwatch.drivers.assembly.pressure_ring import frame_blocks
from frictionwatch.drivers.logs.mcap_replay import shifted
from frictionwatch.drivers.source import StreamRestart
from frictionwatch.service.ingest_queue import Dropped
from frictionwatch.service.live import KeyedBatch, is_realtime, is_replay_paced
from frictionwatch.service.pipeline import EnginePipeline
from frictionwatch.service.record_merge import record_key
from frictionwatch.service.startup import STARTUP
from frictionwatch.service.stream_holes import batch_contents, hole_mark

log = logging.getLogger(__name__)

WARM_LOAD = 0.75  # fraction of full load of the simulated stream (a firing point; the types do not depend on it)
WARM_SEED = 1
SEAM_S = 0.5  # the silence between the two passes (a replay's seam; its own LOOP_GAP_S is alike)
# the third pass's cycles of the stream (its pressure as PressureBlock records): enough for the assembler to cut
# cycles from them (the first two are its sync); design note 136
BLOCK_CYCLES = 5
STEPS = 1 + 2 * WARM_CYCLES + BLOCK_CYCLES - 2  # the simulation, then each cycle of the three passes
# what a board's queue holds while the warm-up runs (WarmStart; serve --hold-mb): genset-v20's stream is ~3.2 MB/s
# of pressure (service/live.py), so ~160 s of it: a cold start's compile here (~55 s) or on a slower box (~146 s)
HOLD_BYTES = 512 * 2**20


@dataclass
class WarmUpProgress:
    """How far a warm-up is, for the terminal, /health and /startup (read from other threads: plain fields, each
    written whole). ``step`` of ``steps``: the simulation, then each warm-up cycle analysed."""

    steps: int = STEPS
    step: int = 0
    started_s: float | None = None
    ended_s: float | None = None
    error: str | None = None
    stop: threading.Event = field(default_factory=threading.Event)  # a stop during the warm-up: it ends early

    @property
    def running(self) -> bool:
        return self.started_s is not None and self.ended_s is None

    @property
    def seconds(self) -> float | None:
        if self.started_s is None:
            return None
        return (self.ended_s if self.ended_s is not None else time.monotonic()) - self.started_s


class WarmStart:
    """An engine's warm-up, then its live session's start (service/engine_service.py). A session whose every source
    can wait (a replay) starts after the warm-up, on a thread of its own, so its clock starts then and it drops
    nothing; one with a serial or CAN board starts at once, its ingest thread warming up before its first record
    (``before_ingest``): the board's input is read meanwhile and the session's queue holds it beyond its
    ``max_queue_s`` (``LiveSession.hold``, service/ingest_queue.py: in memory, up to ``hold_bytes`` -- serve
    --hold-mb, HOLD_BYTES by default --, past which the oldest is dropped and counted as any stretch dropped while
    behind, design note 124); the hold is released after the warm-up and ends once the monitor has caught up (it runs
    ~30-60x real time), so a cold start of a board loses nothing it could keep (design note 136). ``hold_bytes`` 0:
    no hold (what the queue's span cannot hold is dropped, counted). ``cancel`` (a stop): a session not started yet
    never starts; a compile in progress runs to its end on its daemon thread."""

    def __init__(self, engine_id: str, model: EngineModel, info: AcquisitionInfo, session: Any, alerts: Any,
                 hold_bytes: int = 0) -> None:
        self.engine_id, self.model, self.info, self.session, self.alerts = engine_id, model, info, session, alerts
        self.hold_bytes = int(hold_bytes)
        self.progress = WarmUpProgress()
        self.compiled_after: int | None = None  # kernels compiled in this process from the warm-up's end to cancel
        self._compiled_at_end = 0
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()  # cancel against the session's start after the warm-up
        self._cancelled = False

    @property
    def boards(self) -> list[str]:
        """The sources that run at the engine's pace and cannot be made to wait (serial, CAN): not a replay."""
        return [name for name, s in self.session.sources.items() if is_realtime(s) and not is_replay_paced(s)]

    def start(self) -> None:
        if self.boards:
            load = self.session.before_ingest

            def warm_then_load() -> None:
                try:
                    self._warm()
                    if load is not None:
                        load()
                finally:
                    if self.hold_bytes > 0:
                        self.session.release_hold()

            self.session.before_ingest = warm_then_load
            if self.hold_bytes > 0:
                self.session.hold(self.hold_bytes)
            self.session.start()
            return
        self._thread = threading.Thread(target=self._warm_then_start, name="warm-up", daemon=True)
        self._thread.start()

    @property
    def warming_up(self) -> bool:
        return self.progress.ended_s is None and not self._cancelled

    @property
    def thread_alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def cancel(self) -> None:
        with self._lock:
            self._cancelled = True
        self.progress.stop.set()
        if self.progress.ended_s is not None:
            self.compiled_after = STARTUP.compiles.done - self._compiled_at_end

    def _warm(self) -> None:
        seconds = warm_up(self.model, self.info, self.session.pipeline.config, self.alerts, self.progress)
        self._compiled_at_end = STARTUP.compiles.done
        log.info("%s: warm-up %.1f s (%d kernels compiled in this process so far)", self.engine_id, seconds,
                 self._compiled_at_end)

    def _warm_then_start(self) -> None:
        self._warm()
        with self._lock:
            if not self._cancelled:
                self.session.start()


def warm_point(model: EngineModel) -> tuple[float, float]:
    """(rpm, load) of the simulated stream: half the engine's rated speed, or a fifth into its speed range where that
    is higher (genset-v20: half its rated 1,500 rpm is below its 1,100-1,650 range, and at the range's edge the
    stream's speed dips made cycles skip speed_out_of_range, logged before the live run's first), WARM_LOAD. Not the
    rated speed: the pressure comes in frames of a fixed number of samples, and at k9k-4cyl's rated 4,000 rpm the
    first pass held too few of them for the frame store's trim (``frame_store._drop_front``, 32 frames) to run: the
    test met it mid-run (design note 126)."""
    spec = model.spec
    low, high = (float(v) for v in spec.speed_range_rpm)
    return max(low + 0.2 * (high - low), 0.5 * float(spec.rated_speed_rpm)), WARM_LOAD


def warm_up(model: EngineModel, info: AcquisitionInfo, config: MonitorConfig | None = None, alerts: Any = None,
            progress: WarmUpProgress | None = None) -> float:
    """Run the engine's pipeline (and ``alerts.warm_up()``'s alert engine, where ``alerts`` has one) over a short
    simulated stream of it, twice with a loop seam and a dropped stretch between: every kernel compiled or loaded.
    Returns the seconds it took. ``info``: the live source's acquisition (its second wheel decides the stream's)."""
    progress = progress or WarmUpProgress()
    progress.started_s = time.monotonic()
    try:
        rpm, load = warm_point(model)
        second = info.second_wheel is not None and model.spec.sensors.second_wheel is not None
        sim = simulate(model, rpm, load, WARM_CYCLES, WARM_SEED, second_wheel=second)
        progress.step = 1
        pipe = EnginePipeline(model, sim.info, warm_config(config), stages=warm_stages())
        warm_alerts = alerts.warm_up() if hasattr(alerts, "warm_up") else None
        last = None
        # the first pass as a healthy run takes it; the second with the identification's bounds active (a data
        # branch a short stream need not reach: core.monitor.warmup.bound_state), a sensor fault flagged and
        # corrected (where the sensor-health stage is on: sensor_fault_state), a loop seam and a hole
        for n, records in enumerate((sim.records, second_pass(sim.records, sim.info))):
            if n and pipe.cycles.state is not None:
                pipe.cycles.state = sensor_fault_state(bound_state(pipe.cycles.state))
            for record in records:
                if progress.stop.is_set():
                    break
                for result in pipe.feed(record):
                    progress.step = min(progress.step + 1, progress.steps - 1)
                    if warm_alerts is not None:
                        warm_alerts.update(result)
                    last = result
        for result in pipe.flush():
            if warm_alerts is not None:
                warm_alerts.update(result)
        if last is not None:
            warm_traces(last)
        # the third: a fresh pipeline over the stream's first cycles with its pressure as one PressureBlock per
        # cylinder, as a CAN, DAQ or serial source delivers it (the assembler's block paths, design note 136)
        blocks = EnginePipeline(model, sim.info, warm_config(config), stages=warm_stages())
        for record in block_pass(sim.records, rpm, sim.info):
            if progress.stop.is_set():
                break
            for _ in blocks.feed(record):
                progress.step = min(progress.step + 1, progress.steps - 1)
        progress.step = progress.steps
    except Exception as exc:  # noqa: BLE001 - a warm-up that fails leaves the kernels to compile when first called
        progress.error = f"{type(exc).__name__}: {exc}"
        log.error("warm-up failed (kernels compile when first called instead): %s", progress.error, exc_info=exc)
    finally:
        progress.ended_s = time.monotonic()
    return progress.seconds or 0.0


def warm_traces(result: Any) -> None:
    """A result's traces that are computed only when asked for (CycleResult's cached properties): the API's
    friction-torque view asks for ``friction_torque_cyl``, which puts each cylinder's torque onto the crank-angle
    grid with core's ``rows_on_grid`` kernel that nothing else in serve calls. Found compiling at a fresh install's
    first dashboard view (session 39): a compile holds the GIL, so the ingest thread waited meanwhile."""
    _ = result.friction_torque_cyl


def second_pass(records: list, info: AcquisitionInfo) -> list:
    """The stream once more after it, as a looped replay plays it (a seam's restart mark, the records moved on:
    drivers/logs/mcap_replay.py), with a stretch of it dropped as a live queue drops one (the mark ``hole_mark``
    makes of it, service/stream_holes.py): the assembly's restart and the numbering over a hole are paths of their
    own."""
    keys = [record_key(r) for r in records]
    last = math.floor(max(keys))
    shift = last - math.floor(min(keys)) + round(SEAM_S * info.tick_hz)
    moved = [shifted(r, shift) for r in records]
    cut = len(moved) // 3  # the pass's second sixth dropped
    gone = moved[cut // 2:cut]
    gone_keys = [record_key(r) for r in gone]
    dropped = Dropped(gone_keys[0], gone_keys[-1], len(gone), batch_contents(KeyedBatch(gone, gone_keys)),
                      after_key=record_key(moved[cut // 2 - 1]))
    marks, _ = hole_mark(dropped, info)
    return [StreamRestart(ticks=last + 1), *moved[:cut // 2], *marks, *moved[cut:]]


def block_pass(records: list, rpm: float, info: AcquisitionInfo) -> list:
    """The stream's first BLOCK_CYCLES cycles (at ``rpm``) with each PressureFrame as one PressureBlock per cylinder
    (drivers/assembly/pressure_ring.py ``frame_blocks``: the same samples), as a source that carries one cylinder per
    record makes them (drivers/can, the DAQ import, the logs' PressureBlock records); the assembler keeps those in
    rings of their own, with kernels of their own (``write_block``, ``pressure_rows`` and ``search_sorted`` on 1-D
    arrays), which a frame stream never reaches."""
    keys = [record_key(r) for r in records]
    end = min(keys) + BLOCK_CYCLES * 120.0 / rpm * info.tick_hz
    out: list = []
    for r, k in zip(records, keys, strict=True):
        if k <= end:
            out.extend(frame_blocks(r) if isinstance(r, PressureFrame) else (r,))
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m frictionwatch.service.warmup LOG.mcap``: serve's warm-up of the log's engine, nothing served, so
    that the numba cache holds every kernel serve's pipeline and alerts will call (the image's build: Dockerfile)."""
    import argparse

    from frictionwatch.drivers.errors import DriverError
    from frictionwatch.drivers.logs.mcap_replay import McapSource
    from frictionwatch.service.alerts import AlertEngine
    from frictionwatch.service.pipeline import resolve_model

    ap = argparse.ArgumentParser(prog="python -m frictionwatch.service.warmup", description=main.__doc__)
    ap.add_argument("log", help="a replay log (MCAP) whose engine and acquisition the warm-up takes")
    args = ap.parse_args(argv)
    try:
        source = McapSource(args.log, speed=None)
        try:
            model = resolve_model(source.engine_toml, None, args.log, source.info)
        finally:
            source.close()
    except (OSError, ValueError, DriverError) as exc:  # no such log, not a replay log, no engine in it: one line
        print(f"warm-up: {exc}")
        return 2
    alerts = AlertEngine(model.spec)
    alerts.load_kernels()
    progress = WarmUpProgress()
    seconds = warm_up(model, source.info, None, alerts, progress)
    if progress.error:
        print(f"warm-up of {model.spec.name} failed: {progress.error}")
        return 1
    print(f"warm-up of {model.spec.name}: {seconds:.1f} s, {STARTUP.compiles.done} kernels compiled")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
