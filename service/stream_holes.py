"""Holes in an engine's stream: where a live session dropped data while the analysis was behind (service/live.py,
``DROPPED_WHILE_BEHIND``), as the engine pipeline met their restart marks (drivers/source.py ``StreamRestart``) --
live, or reading a recording of such a run (docs/replay-format.md, ``restarts``) -- and what a reader of the cycle
indices is told about them (design note 124).
"""

from __future__ import annotations

from dataclasses import dataclass

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
