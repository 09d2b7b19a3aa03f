"""What the service is doing before an engine's first cycle, for the terminal and the dashboard (issue 28 item 5).

A fresh install compiles its numba kernels before each engine's first record, in serve's warm-up (service/warmup.py;
1-2 minutes on a small machine; cached on disk, so later starts load them in seconds). Until the first cycle the API
has no result to show (its routes answer 503); ``GET /api/v1/startup`` says why instead ("compiling kernels: k of
N", the warm-up's steps), the dashboard shows that in place of the panels, and ``serve`` prints a line every few
seconds (``StartupTicker``).

numba announces each compilation as a "numba:compile" event (numba.core.event) and none for a kernel loaded from
its cache, so counting them tells a cold start ("compiling") from a warm one ("starting"). numba's event registry
is process-wide, so the count is too: ``STARTUP``, one per process.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any, TextIO

from numba.core import event

COMPILING_WORDS = "compiling the numerical kernels (first run only)"
STARTING_WORDS = "waiting for the first cycle"
LOADING_WORDS = "loading the numerical kernels from the cache"
TICK_S = 5.0  # the terminal's progress line while an engine waits for its first cycle
OURS = "frictionwatch."  # the modules whose kernels are counted and named (numba's own overloads are not)
POLL_S = 0.25  # how soon the end of the start is noticed (and its time printed)


class KernelCompiles(event.Listener):
    """Counts numba's compilations as they end: ``total`` every one (numba's own overloads too), ``done`` our
    kernels' (each signature once; what the terminal and the dashboard count), ``last`` the newest of ours."""

    def __init__(self, ours: str = OURS) -> None:
        self.ours = ours
        self._lock = threading.Lock()
        self.total = 0
        self.done = 0
        self.active = 0
        self.last = ""  # module.name, without the frictionwatch. prefix

    def on_start(self, ev: event.Event) -> None:
        with self._lock:
            self.active += 1

    def on_end(self, ev: event.Event) -> None:
        func = getattr(ev.data.get("dispatcher"), "py_func", None) if isinstance(ev.data, dict) else None
        ours = func is not None and str(func.__module__).startswith(self.ours)
        with self._lock:
            self.active -= 1
            self.total += 1
            if ours:
                self.done += 1
                self.last = f"{func.__module__.removeprefix(self.ours)}.{func.__qualname__}"


class StartupState:
    """The start of this process: when it began and the kernels compiled since (``compiles``; ``ours``: the
    module prefix of the kernels counted by name)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic, ours: str = OURS) -> None:
        self.clock = clock
        self.started_s = clock()
        self.compiles = KernelCompiles(ours)
        event.register("numba:compile", self.compiles)

    def close(self) -> None:
        """Stop counting (a test's own state; the process's ``STARTUP`` counts for the life of the process)."""
        event.unregister("numba:compile", self.compiles)

    def engine_state(self, cycles_ok: int) -> str:
        """'running' once the engine has a result; before: 'compiling' once this process has compiled a kernel
        (a cold cache: the first cycle waits for the rest), else 'starting'."""
        if cycles_ok > 0:
            return "running"
        return "compiling" if self.compiles.total or self.compiles.active else "starting"

    def document(self, engines: Iterable[Any]) -> dict:
        """The Startup contract (service/api_models.py) for engines with ``engine_id`` and ``cycles_ok`` (and, where
        serve warms it up, ``warming_up`` and ``warmup``: service/warmup.py's progress)."""
        engines = list(engines)
        rows = [{"engine_id": e.engine_id, "state": self.engine_state(int(e.cycles_ok)), "cycles_ok": int(e.cycles_ok),
                 "warm_up": warm_up_words(e, self)} for e in engines]
        states = {r["state"] for r in rows}
        state = "compiling" if "compiling" in states else "starting" if "starting" in states else "running"
        message = {"compiling": COMPILING_WORDS, "starting": STARTING_WORDS}.get(state)
        warming = [e.warmup for e in engines if warm_up_words(e, self)]
        if warming and state != "running":  # serve's warm-up (service/warmup.py): how far it is
            words = COMPILING_WORDS if state == "compiling" else LOADING_WORDS
            message = f"{words}: {warming[0].step} of {warming[0].steps} warm-up steps"
        return {"state": state, "message": message, "kernels_compiled": self.compiles.done,
                "elapsed_s": round(self.clock() - self.started_s, 1), "engines": rows}


STARTUP = StartupState()


def warm_up_words(engine: Any, state: StartupState = STARTUP) -> str | None:
    """"compiling kernels: k of N" (or "loading", nothing compiled in this process: a warm cache) while the engine's
    warm-up runs (service/warmup.py: its steps), else None."""
    warm = getattr(engine, "warmup", None)
    if warm is None or not getattr(engine, "warming_up", False):
        return None
    verb = "compiling" if state.compiles.total or state.compiles.active else "loading"
    return f"{verb} kernels: {warm.step} of {warm.steps}"


class StartupTicker:
    """A thread that prints, every ``every_s`` until every engine has its first cycle, what the service waits for
    (kernels compiled so far, the last one, seconds), then once when the first cycles are in."""

    def __init__(self, engines: Callable[[], Iterable[Any]], state: StartupState = STARTUP, every_s: float = TICK_S,
                 out: TextIO | None = None, prefix: str = "frictionwatch serve") -> None:
        self.engines, self.state, self.every_s = engines, state, every_s
        self.out, self.prefix = out, prefix
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="startup-ticker", daemon=True)

    def start(self) -> StartupTicker:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)

    def line(self) -> tuple[str, bool]:
        """The line to print now and whether the start is over."""
        doc = self.state.document(self.engines())
        n, t = doc["kernels_compiled"], doc["elapsed_s"]
        if doc["state"] == "running":
            compiled = f"{n} kernels compiled, cached for the next start" if n else "kernels loaded from the cache"
            return f"{self.prefix}: first cycle analysed after {t:.0f} s ({compiled})", True
        if doc["state"] == "compiling":
            last = self.state.compiles.last
            return f"{self.prefix}: {doc['message']}: {n} compiled in {t:.0f} s" + (f", last {last}" if last else ""), \
                False
        return f"{self.prefix}: {doc['message']} ({t:.0f} s)", False

    def _run(self) -> None:
        printed = time.monotonic()
        while not self._stop.wait(min(POLL_S, self.every_s)):
            text, done = self.line()
            if done or time.monotonic() - printed >= self.every_s:
                print(text, file=self.out or sys.stderr, flush=True)
                printed = time.monotonic()
            if done:
                return
