"""The garbage collector's pauses out of serve's request path: what survives is frozen every few seconds, so an
automatic full collection walks only what came since (design note 140).

Why: a full (generation-2) collection holds the GIL while it walks every object the collector tracks. In serve that
is ~250,000 objects of imported code (numba, numpy, scipy, pydantic, FastAPI) plus each engine's history of results
(~7 tracked objects a cycle, 5000 cycles an engine): one pass took 590-610 ms with four gensets, and CPython starts
one whenever a quarter more objects have survived than the last pass found, every ~45 s here. Every request in
flight waits for it: in the 60 s mix bench at 200 req/s one such pass alone is ~120 requests past 100 ms, the whole
of the 1 % tail. ``gc.freeze()`` moves every tracked object to a permanent generation the collector skips (reference
counting still frees them: a result that leaves the history is freed as before).

The policy (``step``, run by a thread every ``every_s``): collect what is not frozen (young objects and what
survived since the last step: a pass of a few ms), then freeze the survivors. What that leaves uncollected: a
reference cycle made of objects frozen earlier that becomes garbage later (serve's steady state makes few: the full
passes of a run without this found 10 objects each); every ``full_every_s`` the whole heap is unfrozen, collected and
frozen again, one full pass (the ~0.6 s above) that frees such cycles, so memory stays bounded. One more full pass
comes when ``settled`` first says so (serve: every engine has its first result): the warm-up's numba compiles make
reference cycles that live a few seconds, longer than a step.
"""

from __future__ import annotations

import gc
import logging
import threading
import time
from collections.abc import Callable

log = logging.getLogger(__name__)
EVERY_S = 2.0  # between freezes: each collection walks what survived since; 20 gensets make ~5x four's
FULL_EVERY_S = 3600.0  # between full passes over the whole heap (cycles of frozen objects that became garbage)


class FrozenHeap:
    """Freeze the survivors every ``every_s``, a full pass every ``full_every_s`` (the first ``step`` is one) and
    at the first step that finds ``settled()`` true. ``clock`` is injectable for tests; ``start``/``stop`` run
    ``step`` on a daemon thread."""

    def __init__(self, every_s: float = EVERY_S, full_every_s: float = FULL_EVERY_S,
                 clock: Callable[[], float] = time.monotonic, settled: Callable[[], bool] | None = None) -> None:
        if not 0 < every_s <= full_every_s:
            raise ValueError(f"need 0 < every_s <= full_every_s, got {every_s:g} and {full_every_s:g}")
        self.every_s, self.full_every_s, self.clock = every_s, full_every_s, clock
        self.settled = settled  # None once it has said so (or never given)
        self.last_full: float | None = None
        self.full_passes = self.steps = 0
        self.last_pass_s = 0.0  # how long the last step's collection held the GIL
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="gc-freeze", daemon=True)

    def step(self) -> bool:
        """Collect and freeze now; a full pass (the whole heap unfrozen first) when one is due. True if it was."""
        now = self.clock()
        full = self.last_full is None or now - self.last_full >= self.full_every_s
        if self.settled is not None and self.settled():
            full, self.settled = True, None
        t = time.perf_counter()
        if full:
            gc.unfreeze()  # back into the oldest generation: the collection below walks everything
        gc.collect()  # only what is not frozen: after a freeze, what came since
        gc.freeze()
        self.last_pass_s = time.perf_counter() - t
        self.steps += 1
        if full:
            self.last_full, self.full_passes = now, self.full_passes + 1
            log.info("serve: full garbage collection, %.0f ms, %d objects frozen", 1e3 * self.last_pass_s,
                     gc.get_freeze_count())
        return full

    def start(self) -> FrozenHeap:
        self._thread.start()
        return self

    def stop(self) -> None:
        """End the thread and give the collector the whole heap back (an in-process caller, a test, goes on with
        the defaults)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        gc.unfreeze()

    def _run(self) -> None:
        while True:
            try:
                self.step()
            except Exception:  # noqa: BLE001 - never let the collector's policy end serve; the default gc goes on
                log.exception("serve: freezing the heap failed; the collector's defaults apply")
                return
            if self._stop.wait(self.every_s):
                return
