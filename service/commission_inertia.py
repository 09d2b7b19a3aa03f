"""Wiring for the inertia commissioning step (core.monitor.calibration.inertia): stream records of coast-down
recordings -> assembled cycles -> one CoastdownRecord each -> J, its sigma and the friction law. No numerics here."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Sequence

from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.engine_model import EngineModel, as_model
from frictionwatch.core.monitor.calibration.inertia import (
    CoastdownRecord,
    InertiaCalibration,
    coastdown_record,
    commission_inertia,
)
from frictionwatch.core.types import AcquisitionInfo, Cycle, StreamRecord
from frictionwatch.drivers.assembly.cycles import CycleAssembler


def assembled_cycles(engine: EngineModel | EngineSpec, info: AcquisitionInfo,
                     records: Iterable[StreamRecord]) -> tuple[list[Cycle], Counter[str]]:
    """Every cycle the assembler completes from ``records`` (no monitor), and what it skipped, by reason."""
    spec = as_model(engine).spec
    asm = CycleAssembler(info, spec.n_cyl, spec.firing_angles, speed_range_rpm=spec.speed_range_rpm)
    cycles: list[Cycle] = []
    for record in records:
        cycles += asm.feed(record)
    cycles += asm.flush()
    return cycles, Counter(asm.skipped)


def record_from_stream(name: str, engine: EngineModel | EngineSpec, info: AcquisitionInfo,
                       records: Iterable[StreamRecord]) -> CoastdownRecord | None:
    """One coast-down recording as a CoastdownRecord of its motored cycles (None: no usable cycle)."""
    cycles, _ = assembled_cycles(engine, info, records)
    return coastdown_record(name, cycles, as_model(engine))


def calibrate_inertia(records: Sequence[CoastdownRecord], gain_rel_std: float = 0.0,
                      n_friction: int = 2) -> InertiaCalibration:
    """J and the friction law pooled over ``records`` (those that are None are the caller's to report)."""
    return commission_inertia(list(records), n_friction=n_friction, gain_rel_std=gain_rel_std)
