"""Holes in an engine's stream: where a live session dropped data while the analysis was behind (service/live.py,
``DROPPED_WHILE_BEHIND``), as the engine pipeline met their restart marks (drivers/source.py ``StreamRestart``) --
live, or reading a recording of such a run (docs/replay-format.md, ``restarts``) -- and what a reader of the cycle
indices is told about them (design note 124).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

from frictionwatch.core.types import AcquisitionInfo, FreeEndToothBatch, ToothBatch
from frictionwatch.drivers.source import StreamRestart
from frictionwatch.service.ingest_queue import Dropped

DROPPED_WHILE_BEHIND = "dropped_while_behind"  # the restart reason where the queue dropped a source's batches


def batch_contents(batch) -> Counter:
    """What a batch the queue drops (a service.live.KeyedBatch) holds, IngestQueue's ``measure``: the flywheel's
    tooth edges (``teeth``), the second wheel's (``wheel2``), other records (``other``) and restart marks
    (``marks``)."""
    held: Counter = Counter()
    for r in batch.records:
        kind = type(r)
        if kind is ToothBatch:
            held["teeth"] += len(r.ticks)
        elif kind is FreeEndToothBatch:
            held["wheel2"] += len(r.ticks)
        elif kind is StreamRestart:
            held["marks"] += 1
        else:
            held["other"] += 1
    return held


RECORD_BYTES = 200  # a record's own Python objects beside its arrays' data (the dataclass, its dict, the array headers)


def batch_bytes(batch) -> int:
    """The bytes a queued batch (a service.live.KeyedBatch) holds, IngestQueue's ``size`` (the hold's bound): each
    record's arrays' data (``ticks``, ``values``) plus RECORD_BYTES, and its key (8 bytes). An estimate of the
    memory it keeps alive, not an exact one."""
    total = 0
    for r in batch.records:
        arr = getattr(r, "values", None)
        if arr is None:
            arr = getattr(r, "ticks", None)
        total += RECORD_BYTES + 8 + (arr.nbytes if hasattr(arr, "nbytes") else 0)
    return total


def hole_mark(hole: Dropped, info: AcquisitionInfo) -> tuple[list[StreamRestart], list[float]]:
    """The restart mark where the queue dropped a run of a source's batches (service/ingest_queue.py): just after
    the newest tick dropped, so before every record the source still delivers. The pipeline restarts its cycle
    assembly there, as at a replay's loop seam: the cycle the hole cuts is one of the dropped ones, counted in
    ``lag().dropped_*``, not a ``data_gap`` of the engine (design note 119). The mark carries the hole: its span,
    records and the cycles its flywheel edges held (the pipeline numbers on over them, design note 124), and what
    restarts: the cycle assembly where the flywheel's edges (or a seam's mark) went, the second wheel's cut where only
    its edges did, nothing where no wheel's did (a pressure or load source of its own)."""
    held = hole.contents
    # a restart mark it swallowed (a replay's seam, read alone in its batch) restarts the assembly as the seam would
    assembly = "all" if held["teeth"] or held["marks"] else "second_wheel" if held["wheel2"] else "none"
    mark = StreamRestart(ticks=math.floor(hole.last_key) + 1, reason=DROPPED_WHILE_BEHIND,
                         dropped_from_ticks=math.floor(hole.first_key if hole.after_key is None else
                                                       min(hole.first_key, hole.after_key + 1)),
                         dropped_records=max(1, hole.records),
                         dropped_cycles=edges_to_cycles(held["teeth"], info),
                         assembly=assembly)
    return [mark], [float(mark.ticks)]


def edges_to_cycles(edges: float, info: AcquisitionInfo) -> float:
    """Crank cycles that many flywheel tooth edges span (two revolutions of the wheel's present teeth)."""
    return edges / (2.0 * (info.wheel_teeth - info.wheel_missing))


MAX_HOLES = 1000  # holes an EnginePipeline keeps (each a few numbers): a year of a box that falls behind daily


@dataclass
class Hole:
    """A stretch a live session dropped while behind, as the pipeline met its mark (drivers/source.py StreamRestart):
    ``from_ticks`` .. ``to_ticks`` the dropped span on the timer, ``records`` dropped, ``cycles`` the crank cycles
    their flywheel edges held, ``assembly`` what restarted; ``first_missing`` the first cycle index not analysed
    there and ``next_cycle`` the first assembled after it (None: not yet; both None where the flywheel's assembly
    went on)."""

    reason: str
    from_ticks: int | None
    to_ticks: int
    records: int
    cycles: float
    assembly: str
    first_missing: int | None
    next_cycle: int | None = None

    @property
    def missing(self) -> int | None:
        """Cycle indices not analysed across the hole (its own cycles and those its cut lost at either side)."""
        if self.first_missing is None or self.next_cycle is None:
            return None
        return self.next_cycle - self.first_missing

    def to_dict(self, tick_hz: float) -> dict:
        span = None if self.from_ticks is None else (self.to_ticks - self.from_ticks) / tick_hz
        return {"reason": self.reason, "first_cycle": self.first_missing,
                "last_cycle": None if self.next_cycle is None else self.next_cycle - 1, "cycles": self.missing,
                "dropped_cycles": round(self.cycles, 1), "dropped_s": span, "dropped_records": self.records,
                "restarted": self.assembly}
