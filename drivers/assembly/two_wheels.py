"""Cycle assembly with a second (free-end) wheel: the flywheel's cycles, each carrying the second wheel's edges.

``TwoWheelAssembler`` is a ``CycleAssembler`` (the flywheel defines the cycles, exactly as without a second wheel)
that files ``FreeEndToothBatch`` records into a ``SecondWheelCut`` and holds each finished cycle until the second
wheel's edges have reached past it: then the cycle leaves with ``wheel2`` set, or, when they do not come within
``max_wait_s`` of stream time or do not cover it, with ``wheel2 = None`` and the flag ``no_second_wheel``, the
reason counted in ``wheel2_missing`` (second_wheel_absent, second_wheel_sync, second_wheel_angle). A cycle without
the second wheel is still a cycle of the flywheel: the monitor analyses it on one wheel. Cycles leave in order.
"""

from __future__ import annotations

import dataclasses
from collections import Counter, deque

import numpy as np
from frictionwatch.core.types import AcquisitionInfo, Cycle, FreeEndToothBatch, StreamRecord
from frictionwatch.drivers.assembly.cycles import CycleAssembler
from frictionwatch.drivers.assembly.wheel2_cut import SecondWheelCut

NO_SECOND_WHEEL = "no_second_wheel"


class TwoWheelAssembler(CycleAssembler):
    """``CycleAssembler`` for an acquisition with ``info.second_wheel`` (same parameters)."""

    def __init__(self, info: AcquisitionInfo, n_cyl: int, firing_angles: np.ndarray, **kwargs) -> None:
        if info.second_wheel is None:
            raise ValueError("TwoWheelAssembler needs info.second_wheel (use CycleAssembler for one wheel)")
        super().__init__(info, n_cyl, firing_angles, **kwargs)
        self.cut = SecondWheelCut(info.second_wheel)
        self.wheel2_missing: Counter[str] = Counter()
        self._held: deque[Cycle] = deque()
        self._newest2 = 0  # newest stream time seen [ticks] (the flywheel's and the second wheel's)

    def feed(self, record: StreamRecord) -> list[Cycle]:
        if isinstance(record, FreeEndToothBatch):
            self.cut.add(record.ticks)
            if self.cut.newest is not None:
                self._newest2 = max(self._newest2, self.cut.newest)
            return self._release(final=False)
        out = super().feed(record)
        self._held.extend(out)
        return self._release(final=False) if self._held else []

    def flush(self, count_tail: bool = True) -> list[Cycle]:
        self._held.extend(super().flush(count_tail))
        return self._release(final=True)

    def restart_second_wheel(self) -> list[Cycle]:
        """The second wheel's edges start again (a hole in their source alone; the flywheel's went on): the cycles
        held for its edges leave with what the cut holds (their edges in the hole will not come), then a fresh cut
        syncs on what follows. The flywheel's assembly goes on untouched."""
        out = self._release(final=True)
        self.cut = SecondWheelCut(self.info.second_wheel)
        return out

    def _release(self, final: bool) -> list[Cycle]:
        out: list[Cycle] = []
        now = max(self._now, self._newest2)
        while self._held:
            c = self._held[0]
            timed_out = now - int(c.tooth_ticks[-1]) > self.wait_ticks
            got = self.cut.cut(c.tooth_ticks, c.tooth_angle, final=final or timed_out)
            if got == "wait":
                break
            self._held.popleft()
            if isinstance(got, str):
                self.wheel2_missing[got] += 1
                out.append(dataclasses.replace(c, flags=(*c.flags, NO_SECOND_WHEEL)))
            else:
                out.append(dataclasses.replace(c, wheel2=got))
        if out:
            self.cut.discard_before(int(out[-1].tooth_ticks[0]))
        return out
