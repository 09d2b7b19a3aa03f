"""Wiring of one engine: stream records -> cycle assembler -> monitor core -> per-cycle results.

No physics here: the pipeline counts and logs what it skips and never dies of bad input (design.md §3).
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from core.engine import EngineSpec, load_engine, spec_from_toml_text
from core.monitor import CycleRejected, initial_state, process_cycle
from core.results import CycleResult
from core.types import AcquisitionInfo, Cycle, StreamRecord
from drivers.cycles import CycleAssembler

log = logging.getLogger(__name__)


class EnginePipeline:
    """Feeds records of one engine through assembly and the monitor; ``skipped`` counts lost cycles by reason."""

    def __init__(self, spec: EngineSpec, info: AcquisitionInfo):
        self.spec = spec
        self.assembler = CycleAssembler(
            info, spec.n_cyl, spec.firing_angles, speed_range_rpm=spec.speed_range_rpm
        )
        self.state = initial_state(spec)
        self.monitor_skipped: Counter[str] = Counter()
        self.cycles_ok = 0

    @property
    def skipped(self) -> Counter[str]:
        return Counter(self.assembler.skipped) + self.monitor_skipped

    def feed(self, record: StreamRecord) -> list[CycleResult]:
        return [r for c in self.assembler.feed(record) if (r := self._process(c)) is not None]

    def flush(self) -> list[CycleResult]:
        return [r for c in self.assembler.flush() if (r := self._process(c)) is not None]

    def _process(self, cycle: Cycle) -> CycleResult | None:
        try:
            self.state, result = process_cycle(self.spec, self.state, cycle)
        except CycleRejected as exc:
            reason = exc.reason
        except (ValueError, FloatingPointError, ArithmeticError) as exc:
            # an unexpected numeric failure: counted and logged with its text, the stream goes on
            reason = f"monitor_error: {type(exc).__name__}"
            log.warning("cycle %d: %s", cycle.index, exc)
        else:
            self.cycles_ok += 1
            return result
        if self.monitor_skipped[reason] == 0:
            log.warning("cycle %d skipped: %s", cycle.index, reason)
        self.monitor_skipped[reason] += 1
        return None


@dataclass
class LogAnalysis:
    spec: EngineSpec
    results: list[CycleResult]
    skipped: Counter[str]
    damage: Counter[str] = field(default_factory=Counter)

    @property
    def last(self) -> CycleResult | None:
        return self.results[-1] if self.results else None


def resolve_spec(engine_toml: str | None, engine: str | None, origin: str) -> EngineSpec:
    """The engine named on the command line wins; else the spec the log carries."""
    if engine:
        return load_engine(engine)
    if not engine_toml:
        raise ValueError(f"{origin} carries no engine spec; name one with --engine")
    return spec_from_toml_text(engine_toml, origin=origin)


def analyze_records(
    spec: EngineSpec, info: AcquisitionInfo, records: Iterable[StreamRecord],
    on_result: Callable[[CycleResult], None] | None = None,
) -> LogAnalysis:
    pipe = EnginePipeline(spec, info)
    results: list[CycleResult] = []
    for record in records:
        for r in pipe.feed(record):
            results.append(r)
            if on_result:
                on_result(r)
    for r in pipe.flush():
        results.append(r)
        if on_result:
            on_result(r)
    return LogAnalysis(spec, results, pipe.skipped)


def analyze_log(path: Path, engine: str | None = None,
                on_result: Callable[[CycleResult], None] | None = None) -> LogAnalysis:
    from drivers.mcap_log import LogReader

    with LogReader(path) as reader:  # closes the file (and its mmap) even when the analysis raises
        spec = resolve_spec(reader.engine_toml, engine, Path(path).name)
        if reader.info is None:
            raise ValueError(f"{Path(path).name} has no acquisition metadata; is it a frictionwatch log?")
        analysis = analyze_records(spec, reader.info, reader.records(), on_result)
        analysis.damage = Counter(reader.damage)
    return analysis
