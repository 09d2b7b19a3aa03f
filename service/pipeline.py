"""Wiring of one engine: stream records -> cycle assembler -> monitor core -> per-cycle results.

No physics here: the pipeline counts and logs what it skips and never dies of bad input (design.md §3).
"""

from __future__ import annotations

import dataclasses
import logging
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from frictionwatch.core.model.engine import EngineSpec, spec_from_toml_text
from frictionwatch.core.model.engine_model import EngineModel, as_model, load_model
from frictionwatch.core.model.view import MonitorView
from frictionwatch.core.monitor.calibration.gain_watch import GainWatchState
from frictionwatch.core.monitor.calibration.tdc_watch import TdcWatchState
from frictionwatch.core.monitor.pipeline import STAGES, CycleOutcome, CyclePipeline, Stage
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.core.monitor.state import MonitorConfig, MonitorState
from frictionwatch.core.types import AcquisitionInfo, Cycle, StreamRecord, ToothBatch
from frictionwatch.drivers.assembly.cycles import CycleAssembler
from frictionwatch.drivers.assembly.two_wheels import TwoWheelAssembler
from frictionwatch.drivers.source import StreamRestart
from frictionwatch.service.stream_holes import MAX_HOLES, Hole

log = logging.getLogger(__name__)


class EnginePipeline:
    """Records of one engine through the cycle assembler and the monitor's one pipeline
    (core.monitor.pipeline.CyclePipeline: the model's view, the monitor, the running calibration watches).

    ``outcomes(record)`` gives every cycle's ``CycleOutcome``: a result, a monitor refusal with its reason, or a cycle
    the assembler lost (stage 'assembly', one outcome per lost cycle); ``feed`` keeps the results only. ``skipped``
    counts lost cycles by reason over both. The cycles are assembled at the phases the wheel states (the model's
    spec).

    A ``StreamRestart`` mark (a looped replay's seam, drivers/source.py) flushes the assembler and starts a fresh one
    that continues the cycle numbering; ``restarts`` counts them by reason. The monitor's state goes on (the same
    engine); the first cycle after the mark has no cycle before it (flagged ``no_previous_cycle``, as after a real
    stop). A mark of a hole (a live session dropped data while behind, or a recording of one) numbers on over the
    cycles the engine turned in the hole, from the tooth clock, so the indices show it; ``holes`` keeps the newest
    ``MAX_HOLES`` as ``Hole``s. A hole in the second wheel's edges alone restarts only their cut, one in no wheel's
    edges nothing (design note 124). ``stages``: the one pipeline's stages (a warm-up's, service/warmup.py)."""

    def __init__(self, engine: EngineModel | EngineSpec, info: AcquisitionInfo, config: MonitorConfig | None = None,
                 on_cycle: Callable[[Cycle], None] | None = None, stages: tuple[Stage, ...] = STAGES):
        if config is not None and config.second_wheel and (info.second_wheel is None or
                                                           as_model(engine).spec.sensors.second_wheel is None):
            # the joint fit asked for without a second wheel in the log or its node in the engine file: one wheel
            config = dataclasses.replace(config, second_wheel=False)
        self.cycles = CyclePipeline(engine, config, on_cycle=on_cycle, stages=stages)
        self.model, self.spec, self.config = self.cycles.model, self.cycles.spec, self.cycles.config
        self.info = info
        self.assembler = cycle_assembler(self.spec, info)
        self._given: Counter[str] = Counter()  # the assembler's losses already given out as outcomes, by reason
        self._retired: Counter[str] = Counter()  # the losses of assemblers replaced at a restart
        self._lost_at = 0  # the assembler's ``lost`` when its losses were last given out
        self.restarts: Counter[str] = Counter()  # StreamRestart marks met, by reason
        self.holes: deque[Hole] = deque(maxlen=MAX_HOLES)  # the newest holes met (marks of dropped records)
        self.holes_met = 0  # all of them
        self._open_hole: Hole | None = None  # the newest hole whose next cycle has not come yet
        self._last_cycle: Cycle | None = None  # the newest cycle assembled: the tooth clock a hole is numbered by
        self._clock_at: tuple[float, float] | None = None  # (index, cycle ticks) at the first edge after a hole

    @property
    def state(self) -> MonitorState | None:
        return self.cycles.state

    @property
    def view(self) -> MonitorView | None:
        """The model as the monitor runs it (None until a friction shape has its operating point)."""
        return self.cycles.view

    @property
    def cycles_ok(self) -> int:
        return self.cycles.cycles_ok

    @property
    def tdc_watch(self) -> TdcWatchState:
        return self.cycles.stages["tdc_watch"]

    @property
    def tdc_window_cycle(self) -> int | None:
        """The cycle that closed the TDC watch's newest window."""
        return self.cycles.stage_cycle.get("tdc_watch")

    @property
    def gain_watch(self) -> GainWatchState:
        return self.cycles.stages["gain_watch"]

    def cylinder_twist(self) -> np.ndarray:
        return self.cycles.cylinder_twist()

    def _assembler_lost(self) -> Counter[str]:
        return self._retired + Counter(self.assembler.skipped) + self.assembler.truncated

    @property
    def skipped(self) -> Counter[str]:
        return self._assembler_lost() + self.cycles.skipped

    def outcomes(self, record: StreamRecord | StreamRestart | None) -> list[CycleOutcome]:
        """The outcomes of the cycles ``record`` completes (None: the end of the stream, flushing the assembler;
        a ``StreamRestart``: the cycles complete before it, then a fresh assembler), each cycle the assembler lost on
        the way first."""
        if isinstance(record, StreamRestart):
            return self._marked(record)
        if self._clock_at is not None and type(record) is ToothBatch:  # the first edge after a hole: the clock
            index_at, period = self._clock_at
            self._clock_at = None
            self.assembler.number_by_clock(index_at, int(record.ticks[0]), period)
        cycles = self.assembler.feed(record) if record is not None else self.assembler.flush()
        out = self._losses()
        if cycles:  # most records complete none (~19 a genset cycle): no generator to make for them
            self._met(cycles)
            out.extend(self.cycles.process(c) for c in cycles)
        return out

    def _met(self, cycles: list[Cycle]) -> None:
        self._last_cycle = cycles[-1]
        if self._open_hole is not None:
            self._open_hole.next_cycle = int(cycles[0].index)
            self._open_hole = None

    def _marked(self, mark: StreamRestart) -> list[CycleOutcome]:
        """A restart mark: the assembly it names starts again (a hole's also numbered over it); a hole is kept."""
        first_missing = self.assembler.next_index
        if mark.assembly == "all" or not mark.is_hole:
            out = self.restart(mark.reason, mark)
        else:
            self.restarts[mark.reason] += 1
            again = getattr(self.assembler, "restart_second_wheel", None) if mark.assembly == "second_wheel" else None
            cycles = again() if again is not None else []
            out = self._losses()
            if cycles:
                self._met(cycles)
                out.extend(self.cycles.process(c) for c in cycles)
            log.info("stream restart (%s): %s only", mark.reason, mark.assembly.replace("_", " "))
        open_hole = self._open_hole
        if mark.is_hole and mark.assembly == "all" and open_hole is not None \
                and open_hole.first_missing == first_missing:  # another before any cycle after the last: one hole
            open_hole.to_ticks, open_hole.records = mark.ticks, open_hole.records + mark.dropped_records
            open_hole.cycles += mark.dropped_cycles
        elif mark.is_hole:
            hole = Hole(mark.reason, mark.dropped_from_ticks, mark.ticks, mark.dropped_records, mark.dropped_cycles,
                        mark.assembly, first_missing if mark.assembly == "all" else None)
            self.holes.append(hole)
            self.holes_met += 1
            self._open_hole = hole if mark.assembly == "all" else open_hole
        return out

    def restart(self, reason: str, mark: StreamRestart | None = None) -> list[CycleOutcome]:
        """The stream starts again (drivers/source.py StreamRestart): the cycles complete so far, then a fresh
        assembler numbering on from the old one. The partial cycle the old stream ends in is dropped uncounted: at a
        loop seam it is the log's end (``analyze`` counts it once, as ``log_ends_mid_cycle``), not a cycle of the
        engine's run that went missing; counted per pass it would make every loop cost a lost cycle again. Where a
        live session dropped data while behind (service.stream_holes.DROPPED_WHILE_BEHIND) it is one of the dropped
        cycles, counted there."""
        old = self.assembler
        out = self.cut_off()
        self._retired += Counter(old.skipped)
        self.assembler = cycle_assembler(self.spec, self.info, first_index=old.next_index)
        if mark is not None and mark.is_hole:
            self._number_over(old, mark)
        self._lost_at = 0
        self.restarts[reason] += 1
        log.info("stream restart (%s): the cycle assembler starts again at cycle %d%s", reason, old.next_index,
                 f" + the ~{mark.dropped_cycles:.0f} cycles dropped" if mark is not None and mark.is_hole else "")
        return out

    def _number_over(self, old: CycleAssembler, mark: StreamRestart) -> None:
        """The fresh assembler numbers its first cycle by the tooth clock of the newest cycle met before the hole:
        that cycle's length, the edges the old assembler met after it and the cycles the hole's dropped flywheel
        edges held, at the first edge after the hole (a silence between the hole and that edge -- a replay's seam
        -- is not cycles; a mark without them: the clock runs across the hole, a replay's silences counted)."""
        last = self._last_cycle
        if last is None:  # no cycle yet: nothing to number from, the numbering goes on
            return
        t0, t1 = int(last.tooth_ticks[0]), int(last.tooth_ticks[-1])
        period = float(t1 - t0)
        newest = old.buf.teeth.last("t")
        seen = 0.0 if newest is None or newest <= t1 else (int(newest) - t1) / period
        self._clock_at = None
        if mark.dropped_cycles > 0:
            self._clock_at = (last.index + 1 + seen + mark.dropped_cycles, period)
        else:
            self.assembler.number_by_clock(last.index + 1 + seen, t1 if newest is None else int(newest), period)

    def cut_off(self) -> list[CycleOutcome]:
        """The stream stops here without having ended (a restart mark; a live session's stop while its sources still
        deliver): the outcomes of the cycles complete so far. The cycle it stops in is not counted as
        ``log_ends_mid_cycle``: the stop cut it, the engine's stream lost nothing (a finite log that ends is flushed
        with ``outcomes(None)``, which counts it)."""
        cycles = self.assembler.flush(count_tail=False)
        out = self._losses()
        if cycles:
            self._met(cycles)
            out.extend(self.cycles.process(c) for c in cycles)
        return out

    def _losses(self) -> list[CycleOutcome]:
        """One outcome per cycle the assembler lost since the last call (its counters only grow)."""
        asm = self.assembler
        if asm.lost == self._lost_at:  # nothing lost since (an int compare per record, not three counter sums)
            return []
        self._lost_at = asm.lost
        lost = self._assembler_lost()
        out = [CycleOutcome(None, skipped=reason, stage="assembly")
               for reason, n in sorted(lost.items()) for _ in range(n - self._given[reason])]
        self._given = lost
        return out

    def feed(self, record: StreamRecord | StreamRestart) -> list[CycleResult]:
        return [o.result for o in self.outcomes(record) if o.result is not None]

    def flush(self) -> list[CycleResult]:
        return [o.result for o in self.outcomes(None) if o.result is not None]


def run(engine: EngineModel | EngineSpec, info: AcquisitionInfo, records: Iterable[StreamRecord],
        config: MonitorConfig | None = None, on_cycle: Callable[[Cycle], None] | None = None
        ) -> Iterator[CycleOutcome]:
    """The one pipeline from records: every cycle's outcome in order (``EnginePipeline``), the stream's end
    flushed. analyze, serve, reanalyze, commission and the benches run this (or ``EnginePipeline`` record by
    record)."""
    pipe = EnginePipeline(engine, info, config, on_cycle)
    for record in records:
        yield from pipe.outcomes(record)
    yield from pipe.outcomes(None)


def cycle_assembler(spec: EngineSpec, info: AcquisitionInfo, first_index: int = 0) -> CycleAssembler:
    """The assembler of an engine's records into cycles, at the phases its wheel states (the pipeline's own);
    ``first_index``: the first cycle's index (a restart within one stream numbers on)."""
    kind = CycleAssembler if info.second_wheel is None else TwoWheelAssembler  # a second wheel: its edges cut too
    return kind(info, spec.n_cyl, spec.firing_angles, speed_range_rpm=spec.speed_range_rpm, first_index=first_index)


def assembled_cycles(engine: EngineModel | EngineSpec, info: AcquisitionInfo,
                     records: Iterable[StreamRecord]) -> tuple[list[Cycle], Counter[str]]:
    """Every cycle the pipeline's assembler completes from ``records``, without the monitor, and what it skipped, by
    reason (the coast-down inertia's input: core.monitor.calibration.inertia.coastdown_record)."""
    spec = as_model(engine).spec
    asm = cycle_assembler(spec, info)
    cycles: list[Cycle] = []
    retired: Counter[str] = Counter()
    for record in records:
        if type(record) is not StreamRestart:
            cycles += asm.feed(record)
        elif record.assembly == "all" or not record.is_hole:  # a recorded restart (EnginePipeline.outcomes)
            cycles += asm.flush(count_tail=False)
            retired += Counter(asm.skipped)
            asm = cycle_assembler(spec, info, first_index=asm.next_index)
        elif record.assembly == "second_wheel" and isinstance(asm, TwoWheelAssembler):
            cycles += asm.restart_second_wheel()
    cycles += asm.flush()
    return cycles, retired + Counter(asm.skipped) + asm.truncated  # counted as EnginePipeline.skipped counts them


KEEP_TRACES = 64  # the newest results keep their traces (plots, a dashboard's recent cycles)


class ResultHistory:
    """The per-cycle results of a run in arrival order, light in memory: the newest ``keep_traces`` whole, older
    ones as slim copies (``CycleResult.slim``: every value and estimate, no traces; a whole genset-v20 result is
    ~100 kB, a slim one ~10 kB), at most ``max_len`` of them (None: all, for a finite log; a live session bounds
    it and counts what fell off the front in ``dropped``)."""

    def __init__(self, keep_traces: int = KEEP_TRACES, max_len: int | None = None):
        if keep_traces < 1 or (max_len is not None and max_len < keep_traces):
            raise ValueError(f"need 1 <= keep_traces <= max_len, got {keep_traces}, {max_len}")
        self.keep_traces = keep_traces
        self._items: deque[CycleResult] = deque(maxlen=max_len)
        self.dropped = 0

    def append(self, result: CycleResult) -> None:
        items = self._items
        if len(items) == items.maxlen:
            self.dropped += 1
        items.append(result)
        if len(items) > self.keep_traces:
            i = -self.keep_traces - 1
            items[i] = items[i].slim()

    @property
    def count(self) -> int:
        """Results appended so far (kept and dropped)."""
        return len(self._items) + self.dropped

    def __len__(self) -> int:
        return len(self._items)

    def __iter__(self) -> Iterator[CycleResult]:
        return iter(self._items)

    def to_list(self) -> list[CycleResult]:
        return list(self._items)


@dataclass
class LogAnalysis:
    """``results``: the analysed cycles in order (older ones slim, see ``ResultHistory``); ``dropped``: analysed
    cycles no longer held (a live session's bounded history), counted in ``cycles_ok``; ``tdc_watch``: the TDC
    found from the pressure at the end (core.monitor.calibration.tdc_watch; its newest window's estimates);
    ``cylinder_twist`` (z,) [rad] the throws' static twist ahead of the flywheel in the newest cycle's model;
    ``gain_watch``: the channels' gains and pegging against their siblings at the end
    (core.monitor.calibration.gain_watch)."""

    spec: EngineSpec
    results: list[CycleResult]
    skipped: Counter[str]
    damage: Counter[str] = field(default_factory=Counter)
    dropped: int = 0
    tdc_watch: TdcWatchState | None = None
    cylinder_twist: np.ndarray | None = None
    gain_watch: GainWatchState | None = None
    restarts: Counter[str] = field(default_factory=Counter)  # the stream's restart marks met, by reason
    holes: list[dict] = field(default_factory=list)  # the stretches dropped while behind (stream_holes.Hole.to_dict)

    @property
    def last(self) -> CycleResult | None:
        return self.results[-1] if self.results else None

    @property
    def cycles_ok(self) -> int:
        return len(self.results) + self.dropped


def resolve_model(engine_toml: str | None, engine: str | None, origin: str,
                  info: AcquisitionInfo | None = None) -> EngineModel:
    """The engine or model file named on the command line wins (a model file, ``EngineModel.to_toml``, brings its
    loss terms, coefficients and effects: ``EnginePipeline`` applies them); else the default model of the spec the log carries. A named engine that cannot
    be the one recorded is refused (``engine_mismatch``)."""
    if engine:
        model = load_model(engine)
        problems = engine_mismatch(model.spec, engine_toml, info, origin)
        if problems:
            raise ValueError(f"--engine {engine} does not match {origin}: {'; '.join(problems)}")
        return model
    if not engine_toml:
        raise ValueError(f"{origin} carries no engine spec; name one with --engine")
    spec = spec_from_toml_text(engine_toml, origin=origin)
    problems = engine_mismatch(spec, None, info, origin)  # the log's engine record against its own acquisition
    if problems:
        raise ValueError(f"{origin} is inconsistent: {'; '.join(problems)} (its engine record against its "
                         "acquisition); name the engine with --engine")
    return EngineModel.from_spec(spec)


def engine_mismatch(spec: EngineSpec, engine_toml: str | None, info: AcquisitionInfo | None,
                    origin: str) -> list[str]:
    """What makes ``spec`` impossible for a log that stores ``engine_toml`` and ``info``, in words (empty: none).

    Refused rather than warned: each of these makes every figure wrong, not just less accurate: the cylinder count
    and the firing order place the pressure traces, the wheel places every tooth. Other differences (masses,
    friction, shaft line) are what --engine is for and pass. A stored spec that cannot be read is not compared."""
    problems = []
    if info is not None and (info.wheel_teeth, info.wheel_missing) != (spec.sensors.wheel_teeth,
                                                                        spec.sensors.wheel_missing):
        problems.append(f"the log's wheel is {info.wheel_teeth}-{info.wheel_missing}, the engine's "
                        f"{spec.sensors.wheel_teeth}-{spec.sensors.wheel_missing}")
    if info is not None and info.pressure_cylinders and max(info.pressure_cylinders) > spec.n_cyl:
        problems.append(f"the log has pressure of cylinder {max(info.pressure_cylinders)}, the engine "
                        f"{spec.n_cyl} cylinders")
    if not engine_toml:
        return problems
    try:
        stored = spec_from_toml_text(engine_toml, origin=origin)
    except ValueError as exc:
        log.warning("%s: the stored engine spec cannot be read, not compared with --engine: %s", origin, exc)
        return problems
    if stored.n_cyl != spec.n_cyl:
        problems.append(f"it was recorded on {stored.name} with {stored.n_cyl} cylinders, the engine has {spec.n_cyl}")
    elif not np.allclose(stored.firing_angles, spec.firing_angles, atol=1e-9):
        problems.append(f"firing angles {_degrees(stored.firing_angles)} deg recorded ({stored.name}), "
                        f"{_degrees(spec.firing_angles)} deg in the engine")
    if info is None and (stored.sensors.wheel_teeth, stored.sensors.wheel_missing) != (
            spec.sensors.wheel_teeth, spec.sensors.wheel_missing):
        problems.append(f"wheel {stored.sensors.wheel_teeth}-{stored.sensors.wheel_missing} recorded, "
                        f"{spec.sensors.wheel_teeth}-{spec.sensors.wheel_missing} in the engine")
    return problems


def _degrees(angles: np.ndarray) -> str:
    return "[" + ", ".join(f"{a:g}" for a in np.round(np.degrees(angles), 3)) + "]"


def analyze_records(
    engine: EngineModel | EngineSpec, info: AcquisitionInfo, records: Iterable[StreamRecord],
    on_result: Callable[[CycleResult], None] | None = None, config: MonitorConfig | None = None,
    on_cycle: Callable[[Cycle], None] | None = None,
    on_twist: Callable[[CycleResult, np.ndarray], None] | None = None,
) -> LogAnalysis:
    """Every record through one ``EnginePipeline``; ``on_result`` sees each result, ``on_twist`` each result with
    the throws' static twist ahead of the flywheel (z,) [rad] in the monitor's model once it is made (commissioning:
    a fired and a motored cycle differ by it, service.cmd_commission)."""
    pipe = EnginePipeline(engine, info, config, on_cycle)
    history = ResultHistory()
    for record in [*records, None]:
        for r in pipe.feed(record) if record is not None else pipe.flush():
            history.append(r)
            if on_result:
                on_result(r)
            if on_twist:
                on_twist(r, pipe.cylinder_twist())
    return LogAnalysis(pipe.spec, history.to_list(), pipe.skipped, tdc_watch=pipe.tdc_watch,
                       cylinder_twist=pipe.cylinder_twist(), gain_watch=pipe.gain_watch,
                       restarts=Counter(pipe.restarts), holes=[h.to_dict(info.tick_hz) for h in pipe.holes])


BENCH_EXPORTS = {".mf4": "an MDF4 bus log", ".mdf": "an MDF4 bus log", ".csv": "a table",
                 ".xlsx": "a spreadsheet"}  # what `trace` reads (service/cmd_trace.py)


def analyze_log(path: Path, engine: str | None = None,
                on_result: Callable[[CycleResult], None] | None = None, config: MonitorConfig | None = None,
                on_cycle: Callable[[Cycle], None] | None = None) -> LogAnalysis:
    from frictionwatch.drivers.logs.mcap_log import LogReader

    if Path(path).suffix.lower() in BENCH_EXPORTS:
        raise ValueError(f"{Path(path).name} is {BENCH_EXPORTS[Path(path).suffix.lower()]}, not a replay log; "
                         f"`frictionwatch trace {Path(path).name}` says what it measures")
    with LogReader(path) as reader:  # closes the file (and its mmap) even when the analysis raises
        model = resolve_model(reader.engine_toml, engine, Path(path).name, reader.info)
        if reader.info is None:
            raise ValueError(f"{Path(path).name} has no acquisition metadata; is it a frictionwatch log?")
        analysis = analyze_records(model, reader.info, reader.records(), on_result, config, on_cycle)
        analysis.damage = Counter(reader.damage)
    return analysis
