"""Time-ordered merge of a live session's record streams (service/live.py's ingest thread calls it).

Merge (``RecordMerge``). Each record is keyed by the tick of its last element (the replay log's time,
docs/replay-format.md §2). Within one source records come nearly in order (a serial CAM frame can overtake the TEETH
frame still being filled, by at most 2 ms; see drivers/bridge.py), so a source vouches for "nothing older will come"
only up to ``slack`` ticks behind the newest key it gave. A held record is released once every source vouches for
its key, except sources that have ended or gone quiet: a source that gave no record for ``quiet_s`` of wall time (an
engine at rest sends no teeth, a port is lost) stops holding the others back until it speaks again. Whatever the
vouches, a record is released once it is ``window`` ticks older than the newest key seen (memory stays bounded when
one source lags). A record older than one already released is still fed (the cycle assembler tolerates streams that
run a little apart) and counted as ``late_record`` for its source. ``merge.stats`` counts records released without
every vouch (by quiet sources, the window, or the final flush).

Keys. Each record's key is worked out once, by its reader (``record_key``), and travels with it: ``push`` takes the
batch's keys beside its records and every method returns (key, record) pairs, which the ingest thread hands on to
``on_records`` (the recorded window) — the key was worked out four times on its way before (design note 100).

Choosing the window: it bounds how long a source that lags (not a silent one) holds the others, in acquisition time.
Within it the order is kept whatever the lag, at the cost of memory (1 s of genset-v20 pressure is 3.2 MB) and of
latency only while a source lags. Beyond it, teeth released more than the assembler's pressure wait (0.5 s) ahead of
their pressure lose their cycle ('pressure_missing'). The default is 1 s.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
from collections import Counter
from collections.abc import Iterable, Sequence

from frictionwatch.core.types import (
    CamBatch,
    FreeEndToothBatch,
    LoadSample,
    PressureBlock,
    PressureFrame,
    StreamRecord,
    ToothBatch,
)
from frictionwatch.drivers.source import StreamRestart

log = logging.getLogger(__name__)

# ties: the simulator's order; a restart mark before the records it precedes
_RANK = {StreamRestart: -1, ToothBatch: 0, CamBatch: 1, PressureBlock: 2, PressureFrame: 2, LoadSample: 3,
         FreeEndToothBatch: 4}


Keyed = list[tuple[float, StreamRecord]]  # (record_key, record) pairs, as the merge releases them


def _first(pair: tuple[float, StreamRecord]) -> float:
    return pair[0]


def record_key(record: StreamRecord | StreamRestart) -> float:
    """Tick of the record's last element (when it was complete): drivers.logs.mcap_schema.last_tick as a float; a
    restart mark's own tick."""
    if isinstance(record, ToothBatch | CamBatch | FreeEndToothBatch):
        return float(record.ticks[-1])
    if isinstance(record, PressureBlock):
        return float(record.t0_ticks) + (len(record.values) - 1) * float(record.period_ticks)
    if isinstance(record, PressureFrame):
        return float(record.t0_ticks) + (record.values.shape[-1] - 1) * float(record.period_ticks)
    if isinstance(record, LoadSample | StreamRestart):
        return float(record.ticks)
    raise TypeError(f"not a stream record: {type(record).__name__}")


class RecordMerge:
    """Time-ordered merge of named record streams with a bounded reorder window (no threads, no clock).

    Parameters
    ----------
    sources : names of the streams.
    window_ticks : a held record is released at the latest when it is this much older than the newest key seen.
    slack_ticks : how far behind its own newest key a source may still deliver (its internal disorder).
    """

    def __init__(self, sources: Iterable[str], window_ticks: float, slack_ticks: float = 0.0) -> None:
        names = list(sources)
        if not names or len(set(names)) != len(names):
            raise ValueError(f"need one or more distinct source names, got {names}")
        if not (window_ticks > 0 and slack_ticks >= 0):
            raise ValueError("need window_ticks > 0 and slack_ticks >= 0")
        self.window, self.slack = float(window_ticks), float(slack_ticks)
        self.progress: dict[str, float] = {n: -math.inf for n in names}  # newest key per source
        self.ended: set[str] = set()
        self.quiet: set[str] = set()
        self.counts: dict[str, Counter[str]] = {n: Counter() for n in names}
        self.stats: Counter[str] = Counter()  # released_by_quiet / _window / _flush: records not vouched for
        self.released_key = -math.inf
        self._heap: list[tuple[float, int, int, StreamRecord]] = []
        self._order = itertools.count()

    @property
    def held(self) -> int:
        return len(self._heap)

    def push(self, source: str, records: Sequence[StreamRecord], keys: Sequence[float] | None = None) -> Keyed:
        """File the records of one source (``keys``: each one's ``record_key``, worked out here when None); returns
        those now released, (key, record) in key order."""
        if source not in self.progress:
            raise ValueError(f"unknown source {source!r}; known: {sorted(self.progress)}")
        self.quiet.discard(source)
        late: Keyed = []
        if keys is None:
            keys = [record_key(r) for r in records]
        newest = self.progress[source]
        for key, r in zip(keys, records, strict=True):
            newest = max(newest, key)
            if key < self.released_key:
                if not self.counts[source]["late_record"]:
                    log.warning("%s: a record %.0f ticks older than what was released (%s)", source,
                                self.released_key - key, dict(self.stats))
                self.counts[source]["late_record"] += 1
                late.append((key, r))
            else:
                heapq.heappush(self._heap, (key, _RANK[type(r)], next(self._order), r))
        self.progress[source] = newest
        late.sort(key=_first)  # a CAN batch comes ordered by first sample, the streams meet by last
        return late + self._release()

    def end(self, source: str) -> Keyed:
        """The source has ended: it no longer holds the others back."""
        self.ended.add(source)
        return self._release()

    def set_quiet(self, sources: Iterable[str]) -> Keyed:
        """These sources are silent (wall clock): they stop holding the others back until they deliver again."""
        self.quiet = set(sources) & set(self.progress)
        return self._release()

    def flush(self) -> Keyed:
        """Release everything held, in key order."""
        return self._release(flushing=True)

    def _release(self, flushing: bool = False) -> Keyed:
        all_live = [p - self.slack for n, p in self.progress.items() if n not in self.ended]
        voiced = [p - self.slack for n, p in self.progress.items() if n not in self.ended and n not in self.quiet]
        strict, vouched = min(all_live, default=math.inf), min(voiced, default=math.inf)
        window = max(self.progress.values()) - self.window
        limit = math.inf if flushing else max(vouched, window)
        out: Keyed = []
        while self._heap and self._heap[0][0] <= limit:
            key, _, _, r = heapq.heappop(self._heap)
            if key > strict:
                why = "flush" if flushing else ("window" if key > vouched else "quiet")
                self.stats[f"released_by_{why}"] += 1
            self.released_key = max(self.released_key, key)
            out.append((key, r))
        return out
