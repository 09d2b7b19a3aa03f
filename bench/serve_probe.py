"""`frictionwatch serve` with timing probes, for bench_service_plant's ``mix --probe FILE`` (bench only, never the
product): where a slow request's time goes, as a timeline on the machine's one monotonic clock (CLOCK_MONOTONIC:
the same in the client's process, so a request's client and server times line up).

    python -m bench.serve_probe FILE serve --port 0 --source ...   # the serve arguments after FILE
    python -m bench.serve_probe FILE --switch-interval 0.001 serve ...  # CPython's GIL switch interval set first
    python -m bench.serve_probe FILE --api-default-policy serve ...  # the event loop and the request threads under
                                  # SCHED_OTHER once the engines started (theirs stay SCHED_BATCH, design note 107)

At exit FILE gets JSON lists of:
- ``req``: each HTTP request (id from the client's ``x-bench-id`` header, route, ASGI entry, exit): the server's
  own time, the same span the /metrics histogram times;
- ``gc``: each garbage collection (start, seconds, generation, objects collected): a gen-2 pass over a large heap
  holds the GIL for all of its length;
- ``heap``: every 5 s the objects frozen (service/app_gc.py), the collector's generation counts and all the
  objects it tracks (without a leak they stop growing once the histories are full);
- ``window_documents``: window requests and the documents made for them (the rest were shared: design note 146);
- ``losses_now``: the plain /losses route's computations (its cache's misses) and their thread CPU;
- ``window_replies``: window requests and the replies made for them (the rest were a reply made this cycle for a
  window of the same length: design note 154);
- ``wake``: a thread that sleeps 2 ms in a loop records each wake-up later than 3 ms past due (due, seconds late,
  and the innermost frames of the other threads then): how long a thread that waits on nothing but the GIL (and
  the scheduler) waits, and what the others ran meanwhile.
"""

from __future__ import annotations

import atexit
import gc
import json
import sys
import threading
import time
import traceback

SLEEP_S, LATE_S = 0.002, 0.003


def install(out_path: str) -> None:
    from frictionwatch.service import metrics

    rec: dict[str, list] = {"req": [], "gc": [], "wake": [], "switch_interval_s": sys.getswitchinterval()}
    started: list[float] = [0.0]

    def on_gc(phase: str, info: dict) -> None:
        if phase == "start":
            started[0] = time.monotonic()
        else:
            rec["gc"].append((started[0], time.monotonic() - started[0], info["generation"], info["collected"]))

    gc.callbacks.append(on_gc)
    timed = metrics.RequestTimer.__call__

    async def probed(self, scope, receive, send):  # noqa: ANN001 - an ASGI app's call
        t0 = time.monotonic()
        try:
            await timed(self, scope, receive, send)
        finally:
            rid = dict(scope.get("headers") or []).get(b"x-bench-id", b"-1")
            rec["req"].append((int(rid), getattr(scope.get("endpoint"), "__name__", "other"), t0, time.monotonic()))

    metrics.RequestTimer.__call__ = probed

    def waker() -> None:
        me = threading.get_ident()
        names = {}
        while True:
            due = time.monotonic() + SLEEP_S
            time.sleep(SLEEP_S)
            late = time.monotonic() - due
            if late > LATE_S:
                names.update({t.ident: t.name for t in threading.enumerate()})
                frames = {names.get(k, str(k)): [f"{f.name}:{f.lineno}" for f in traceback.extract_stack(v)[-3:]]
                          for k, v in sys._current_frames().items() if k != me}
                rec["wake"].append((due, late, frames))

    threading.Thread(target=waker, name="probe-wake", daemon=True).start()
    # every 5 s: (time, objects frozen, gc.get_count(), objects tracked in all: frozen or not, a walk of the heap)
    rec["heap"] = []

    def heap() -> None:
        while True:
            rec["heap"].append((time.monotonic(), gc.get_freeze_count(), gc.get_count(),
                                gc.get_freeze_count() + len(gc.get_objects())))
            time.sleep(5.0)

    threading.Thread(target=heap, name="probe-heap", daemon=True).start()

    def dump() -> None:
        with open(out_path, "w") as fh:
            json.dump(rec, fh)

    try:  # the window routes' shared documents (design note 146): how many requests found theirs made
        from frictionwatch.service.api_views import OwnEstimateDocuments
    except ImportError:  # a checkout before them
        OwnEstimateDocuments = None  # noqa: N806
    if OwnEstimateDocuments is not None:
        rec["window_documents"] = {"asked": 0, "made": 0}
        got = OwnEstimateDocuments.get

        def counted(self, last, active):  # noqa: ANN001 - OwnEstimateDocuments.get's
            before = self.made
            doc = got(self, last, active)
            rec["window_documents"]["asked"] += 1
            rec["window_documents"]["made"] += self.made - before
            return doc

        OwnEstimateDocuments.get = counted
    # the plain /losses route's misses: each call of losses_smoothed (losses_now before it) is one (a new cycle's
    # smoothing), with its thread CPU
    from frictionwatch.service import api_views

    rec["losses_now"] = {"calls": 0, "thread_cpu_s": 0.0}
    name = "losses_smoothed" if hasattr(api_views, "losses_smoothed") else "losses_now"
    smoothed = getattr(api_views, name)

    def timed_losses(*args, **kwargs):  # noqa: ANN002, ANN003 - losses_smoothed's
        t = time.thread_time()
        try:
            return smoothed(*args, **kwargs)
        finally:
            rec["losses_now"]["calls"] += 1
            rec["losses_now"]["thread_cpu_s"] += time.thread_time() - t

    setattr(api_views, name, timed_losses)
    # the window replies made once a cycle and window length (design note 154): how many requests found theirs made
    if hasattr(api_views.NewestReplies, "window"):
        rec["window_replies"] = {"asked": 0, "made": 0}
        window = api_views.NewestReplies.window

        def counted_window(self, version, cycles, make):  # noqa: ANN001 - NewestReplies.window's
            before = self.windows_made
            got = window(self, version, cycles, make)
            rec["window_replies"]["asked"] += 1
            rec["window_replies"]["made"] += self.windows_made - before
            return got

        api_views.NewestReplies.window = counted_window
    atexit.register(dump)


if __name__ == "__main__":
    rest = sys.argv[2:]
    if rest[:1] == ["--switch-interval"]:  # an experiment: what a shorter hand-over of the GIL does to the tail
        sys.setswitchinterval(float(rest[1]))
        rest = rest[2:]
    if rest[:1] == ["--api-default-policy"]:  # an experiment: requests' threads woken at once, not after a slice
        import os

        import uvicorn

        started = uvicorn.Server.startup

        async def startup(self, sockets=None):  # noqa: ANN001 - uvicorn's; after the lifespan started the engines
            await started(self, sockets=sockets)
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))  # the loop's thread; workers inherit it

        uvicorn.Server.startup = startup
        rest = rest[1:]
    install(sys.argv[1])
    from frictionwatch.service.cli import main

    sys.exit(main(rest))
