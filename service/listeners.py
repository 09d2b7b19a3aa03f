"""Fan-out of an engine's results to its consumers, after python-can's Notifier / Listener.

    fanout = Fanout([state, sse, metrics, store_listener])   # each listener gets its own bounded queue and thread
    fanout.publish(event)        # never blocks: a full queue drops the event and counts it
    fanout.publish(event, until=deadline)  # a source that can wait: waits for room until deadline() (a stop's)
    fanout.publish(event, past_bound=True)  # a person's action: never waits, queued past a full queue's bound
    fanout.drops, fanout.errors  # per listener name
    fanout.stop(timeout)         # each thread delivers what is queued within timeout, then the listener's stop()
    fanout.left                  # per listener: events given up at a stop (not queued by its deadline, or still queued)
    fanout.waited_s, fanout.waiting_for  # seconds a waiting publisher spent on each listener; whom it waits for now

A listener is any object with ``on_message_received(event)`` (python-can's name), optionally ``on_error(exc)``,
``stop()``, ``name`` and ``wants(event)``; a plain callable works too. ``wants`` is asked on the publishing thread
(keep it a field read): False and the event is not queued for that listener at all, neither delivered nor counted
as dropped; a queue hand-off wakes the listener's thread, ~50 us of CPU on a loaded 2-core box, every cycle of
every engine (the SSE broadcaster wants nothing while no client listens; design notes 34). An exception in a
listener is counted (``errors``), passed to its ``on_error`` and logged once; the listener keeps receiving. The
events are ``ServiceEvent``: one per analysed cycle (``result`` set, with the alert changes that cycle caused) and
one per state change made through the API (``result`` None: an acknowledged alert, a new baseline).

The listeners of the API live here: ``LatestState`` (what the routes read) and ``SseBroadcaster`` (the stream).
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import queue
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.core.monitor.report.run_summary import active_flags
from frictionwatch.service.stream_holes import MAX_HOLES
from frictionwatch.service.window_figures import WindowFigures, active_from_counts, left_out
from frictionwatch.service.window_sums import WindowSums

log = logging.getLogger(__name__)
# how often a publisher waiting for room looks at its deadline and the listener's thread (a stop moves the deadline)
WAIT_POLL_S = 0.05
# what a stop gives a listener's event in hand once its time is up, before its stop() (a store's commit: ~50 ms)
IN_HAND_S = 0.5
_WAKE = object()  # put by a stop into a listener's queue: wakes its thread, is not an event


@dataclass(frozen=True)
class ServiceEvent:
    """What the fan-out carries. ``arrived_s``: monotonic time the reader got the record that completed the cycle
    (None when not known); ``result_s``: when the result reached the fan-out. ``alerts``: Alert dicts (contract
    shape, with engine_id) raised, updated, cleared or acknowledged; ``baseline``: a new alert baseline (to_dict);
    ``hole``: the stretch dropped while behind just before this result (service/stream_holes.py), else None."""

    engine_id: str
    result: CycleResult | None
    result_s: float
    arrived_s: float | None = None
    alerts: tuple[dict, ...] = ()
    baseline: dict | None = None
    term_names: tuple[str, ...] = field(default=())
    hole: dict | None = None  # the result is the first after a hole dropped while behind: the hole (Hole.to_dict)


class Listener:
    """Base of the fan-out's listeners (python-can's can.Listener): override ``on_message_received``."""

    name = "listener"

    def on_message_received(self, event: ServiceEvent) -> None:
        raise NotImplementedError

    def on_error(self, exc: BaseException) -> None:  # noqa: B027 - optional hook
        pass

    def stop(self) -> None:  # noqa: B027 - optional hook
        pass


class _Callback(Listener):
    def __init__(self, fn: Callable[[ServiceEvent], None]) -> None:
        self.fn, self.name = fn, getattr(fn, "__name__", "callback")

    def on_message_received(self, event: ServiceEvent) -> None:
        self.fn(event)


class _EventQueue(queue.Queue):
    """A listener's queue: ``maxsize`` events, and as many again for ``put_past_bound`` (after the standard
    library's own subclasses, through Queue's ``_put`` / ``_qsize`` hooks)."""

    def put_past_bound(self, event: ServiceEvent) -> bool:
        """Queue ``event`` without waiting even when the queue is full, up to twice ``maxsize``; False past that.
        For a person's actions (an acknowledgement, a re-baseline): few, and not to be lost to a busy store."""
        with self.not_full:  # the queue's mutex
            if self._qsize() >= 2 * self.maxsize:
                return False
            self._put(event)
            self.unfinished_tasks += 1
            self.not_empty.notify()
            return True


class _Worker:
    """One listener's queue and thread."""

    def __init__(self, listener: Any, name: str, queue_size: int) -> None:
        self.listener, self.name = listener, name
        self.wants: Callable[[ServiceEvent], bool] | None = getattr(listener, "wants", None)
        self.queue = _EventQueue(maxsize=queue_size)
        self.drops = 0
        self.left = 0  # events given up at a stop (Fanout.left)
        # a waiting publisher's time on this listener's full queue (a replay paced by it), and when its current wait
        # began (None: not waiting): written by the one publishing thread, read at a scrape
        self.waited_s = 0.0
        self.waiting_since: float | None = None
        self.errors: Counter[str] = Counter()
        self.delivered = 0
        self._stopping = threading.Event()
        self._abandon = threading.Event()  # the stop's time is up: deliver nothing more
        self.thread = threading.Thread(target=self._run, name=f"listener-{name}", daemon=True)

    def put(self, event: ServiceEvent, until: Callable[[], float] | None) -> bool:
        """Queue ``event``: at once, or with ``until`` waiting for room while ``time.monotonic() < until()`` and the
        thread runs. False: not queued."""
        try:
            self.queue.put_nowait(event)
            return True
        except queue.Full:
            if until is None:
                return False
        start = self.waiting_since = time.monotonic()
        try:
            while self.thread.is_alive() and not self._abandon.is_set():
                wait = min(WAIT_POLL_S, until() - time.monotonic())
                if wait <= 0:
                    return False
                try:
                    self.queue.put(event, timeout=wait)
                    return True
                except queue.Full:
                    continue
            return False
        finally:
            self.waiting_since = None
            self.waited_s += time.monotonic() - start

    def discard(self) -> int:
        """Empty the queue (nothing of it delivered); how many events it held (the stop's wake-up not counted)."""
        n = 0
        while True:
            try:
                item = self.queue.get_nowait()
            except queue.Empty:
                return n
            n += item is not _WAKE

    def stopping(self) -> None:
        """Deliver what is queued, then end: a thread asleep on its empty queue is woken to see it."""
        self._stopping.set()
        self.queue.put_past_bound(_WAKE)  # a full queue needs none: its thread is busy and looks before it sleeps

    def _run(self) -> None:
        # Asleep until an event comes, not polling: a poll every 0.1 s woke each listener's thread 10 times a second,
        # each wake-up needing the GIL an ingest thread holds (serve of 8 gensets: 2-4 fewer context switches a
        # genset-v20 cycle without it, design notes 70). Once stopping, what is queued is delivered, then it ends.
        while not self._abandon.is_set():
            try:
                event = self.queue.get(block=not self._stopping.is_set())
            except queue.Empty:
                return
            if event is _WAKE:
                continue
            try:
                self.listener.on_message_received(event)
                self.delivered += 1
            except Exception as exc:  # noqa: BLE001 - a consumer's bug must not stop the others or the monitor
                reason = type(exc).__name__
                if not self.errors:
                    log.error("listener %s failed: %s", self.name, exc, exc_info=exc)
                self.errors[reason] += 1
                on_error = getattr(self.listener, "on_error", None)
                if on_error is not None:
                    try:
                        on_error(exc)
                    except Exception:  # noqa: BLE001 - its error hook failing is logged, nothing more
                        log.exception("listener %s: on_error failed", self.name)


class Fanout:
    """Delivers each published event to every listener on the listener's own thread (see the module docstring)."""

    def __init__(self, listeners: Iterable[Any] = (), queue_size: int = 256) -> None:
        if queue_size < 1:
            raise ValueError(f"queue_size must be >= 1, got {queue_size}")
        self.queue_size = queue_size
        self._workers: list[_Worker] = []
        self._started = False
        for listener in listeners:
            self.add(listener)

    def add(self, listener: Any) -> None:
        if not hasattr(listener, "on_message_received"):
            if not callable(listener):
                raise TypeError(f"a listener needs on_message_received(event) or to be callable: {listener!r}")
            listener = _Callback(listener)
        name = str(getattr(listener, "name", type(listener).__name__))
        taken = {w.name for w in self._workers}
        unique, i = name, 2
        while unique in taken:
            unique, i = f"{name}-{i}", i + 1
        worker = _Worker(listener, unique, self.queue_size)
        self._workers.append(worker)
        if self._started:
            worker.thread.start()

    def start(self) -> None:
        if not self._started:
            self._started = True
            for w in self._workers:
                w.thread.start()

    def publish(self, event: ServiceEvent, until: Callable[[], float] | None = None,
                past_bound: bool = False) -> None:
        """Without ``until`` never blocks: a listener whose queue is full loses this event (counted in ``drops``).
        With ``until`` (a source that can wait: a log read as fast as possible, never an engine nor the API) a full
        queue is waited for until the monotonic time ``until()`` (read again while waiting: a stop sets it), so that a
        replay faster than its slowest listener loses nothing; an event not queued by then is counted in ``left``
        (so is one published after ``stop``). ``past_bound`` (the API's events: a person's action) never waits
        either, and a full queue takes it anyway, up to twice its size (``_EventQueue``)."""
        for w in self._workers:
            if w.wants is not None and not w.wants(event):
                continue
            if w._abandon.is_set():
                w.left += 1  # after the stop: nobody would deliver it
            elif w.queue.put_past_bound(event) if past_bound else w.put(event, until):
                continue
            elif w._stopping.is_set() or (until is not None and time.monotonic() >= until()):
                w.left += 1  # a stop's deadline ended the wait (EngineService.stop says how many)
            else:
                if w.drops == 0:
                    log.warning("listener %s is behind: its queue of %d is full, events dropped", w.name,
                                self.queue_size)
                w.drops += 1

    def stop(self, timeout: float = 5.0) -> None:
        """Deliver what is queued within ``timeout`` s, then stop each listener (its ``stop()``). What a listener
        still holds then is not delivered: counted in ``left``, its event in hand given ``IN_HAND_S`` more, so that
        a stop takes at most ``timeout + IN_HAND_S``."""
        for w in self._workers:
            w.stopping()
        deadline = time.monotonic() + timeout
        for w in self._workers:
            if w.thread.is_alive():
                w.thread.join(max(0.0, deadline - time.monotonic()))
        late = [w for w in self._workers if w.thread.is_alive()]
        for w in self._workers:
            w._abandon.set()  # a late thread stops after its event in hand
            w.left += w.discard()  # a late thread's queue (or a publish's racing the stop)
        in_hand = time.monotonic() + IN_HAND_S
        for w in late:
            w.thread.join(max(0.0, in_hand - time.monotonic()))
        for w in self._workers:
            stop = getattr(w.listener, "stop", None)
            if stop is not None:
                try:
                    stop()
                except Exception:  # noqa: BLE001 - one listener failing to stop must not keep the others
                    log.exception("listener %s: stop failed", w.name)

    @property
    def names(self) -> list[str]:
        return [w.name for w in self._workers]

    def listener(self, name: str) -> Any | None:
        """The listener added under ``name`` (e.g. 'store'), or None."""
        return next((w.listener for w in self._workers if w.name == name), None)

    @property
    def drops(self) -> dict[str, int]:
        return {w.name: w.drops for w in self._workers}

    @property
    def left(self) -> dict[str, int]:
        """Events each listener was not given because of a stop: a waiting publish's deadline passed, its queue
        still held them when the stop's time was up, or they came after it."""
        return {w.name: w.left for w in self._workers}

    @property
    def waited_s(self) -> dict[str, float]:
        """Seconds a publisher that can wait (a replay faster than real time) has spent on each listener's full
        queue: the replay ran at that listener's pace for so long (nothing lost: see ``publish``)."""
        now = time.monotonic()
        return {w.name: w.waited_s + (0.0 if (since := w.waiting_since) is None else now - since)
                for w in self._workers}

    @property
    def waiting_for(self) -> str | None:
        """The listener a publisher is waiting for now (its queue full), or None."""
        return next((w.name for w in self._workers if w.waiting_since is not None), None)

    @property
    def errors(self) -> dict[str, int]:
        return {w.name: sum(w.errors.values()) for w in self._workers}

    @property
    def queued(self) -> dict[str, int]:
        return {w.name: w.queue.qsize() for w in self._workers}


class LatestState(Listener):
    """What the API reads of one engine: the newest whole result, a bounded ring of recent results (slim: no
    traces), the running sums of window means (service/window_sums.py). Thread-safe; ``snapshot`` copies under the
    lock only the results asked for, ``window`` reads the sums in O(1): a request never holds this listener's
    thread for longer than that (an engine's ingest thread never waits for it; a replay that can wait does so only
    once its queue of ``Fanout.queue_size`` events is full, far longer than a request holds the lock)."""

    name = "api-state"

    def __init__(self, max_results: int = 5000) -> None:
        if max_results < 2:
            raise ValueError(f"max_results must be >= 2, got {max_results}")
        self._lock = threading.Lock()
        self._ring: deque[CycleResult] = deque(maxlen=max_results)
        self.sums = WindowSums(max_results)  # windows up to the ring's length
        # each held result's cycle index and smoothed weight, in arrays beside the ring (position: count mod its
        # length): the smoothed estimate's window reads them without walking 5000 results a request (``smoothed``)
        self._index = np.zeros(max_results, dtype=np.int64)
        self._weight = np.zeros(max_results, dtype=np.float64)
        self._count = 0
        self.newest: CycleResult | None = None
        # the newest result with a cycle before it: a window's figures take their statuses from it, as its means
        # leave out the cycles without one (service/window_figures.py)
        self.newest_counted: CycleResult | None = None
        self.newest_s: float | None = None  # monotonic time the newest result became visible here
        self.holes: deque[dict] = deque(maxlen=MAX_HOLES)  # the holes before results held (index ranges)
        self.updated = threading.Condition(self._lock)
        # gets each event with its result -> visible here [s], on this thread (the metrics' per-cycle histograms)
        self.on_visible: Callable[[ServiceEvent, float], None] | None = None

    def on_message_received(self, event: ServiceEvent) -> None:
        if event.result is None:
            return
        row = self.sums.row_for(event.result)  # the per-cycle cost, outside the lock
        with self._lock:
            self.sums.append(int(event.result.index), row)
            if self._ring and self.newest is not None:
                self._ring[-1] = self.newest.slim()  # only the newest keeps its traces
            self._ring.append(event.result)
            pos = self._count % self._index.shape[0]
            self._index[pos], self._weight[pos] = int(event.result.index), event.result.smoothed.weight
            self._count += 1
            self.newest, self.newest_s = event.result, time.monotonic()
            if event.hole is not None:
                self.holes.append(event.hole)
            if not left_out(event.result.flags):
                self.newest_counted = event.result
            self.updated.notify_all()
        if self.on_visible is not None:
            self.on_visible(event, self.newest_s - event.result_s)

    def snapshot(self, last: int | None = None) -> tuple[CycleResult | None, list[CycleResult]]:
        """The newest whole result and the last ``last`` results held (all when None), oldest first."""
        with self._lock:
            if last is None or last >= len(self._ring):
                return self.newest, list(self._ring)
            newest_first = list(itertools.islice(reversed(self._ring), max(0, last)))
            return self.newest, newest_first[::-1]

    def smoothed(self) -> tuple[CycleResult | None, np.ndarray, np.ndarray, frozenset[str]]:
        """What the smoothed estimate's window is read from (api_views.losses_smoothed): the newest whole result,
        every held result's cycle index and smoothed weight (oldest first, copies) and the flags that apply to it
        (run_summary.active_flags over the newest round(newest weight) results, its reach), read together. The flags
        come from the window sums' running flag counts (O(flags), where walking the reach's results and counting
        their flags cost ~0.35 ms a request with 1000 held, ~1.7 ms with 5000); from the results themselves only
        where the sums do not cover the reach (they started again on a change of the result's shape)."""
        with self._lock:
            held = min(self._count, self._index.shape[0])
            pos = self._count % self._index.shape[0]
            order = np.r_[pos:held, 0:pos] if held == self._index.shape[0] else np.arange(held)
            index, weight = self._index[order], self._weight[order]
            if not held:
                return self.newest, index, weight, frozenset()
            reach = max(1, min(held, round(weight[-1])))
            counts = self.sums.flag_counts(reach)
            if counts is not None:
                active = active_from_counts(self.newest.flags, counts, reach)
            else:
                active = active_flags([r.flags for r in itertools.islice(reversed(self._ring), reach)][::-1], reach)
            return self.newest, index, weight, active

    def window(self, cycles: int) -> tuple[CycleResult | None, WindowFigures | None]:
        """The result a window's statuses are read from (the newest with a previous cycle; the newest when none has
        one) and the figures of the newest ``cycles`` cycles, read together."""
        return self.versioned_window(cycles)[:2]

    def versioned_window(self, cycles: int) -> tuple[CycleResult | None, WindowFigures | None, int]:
        """``window`` and the count of results this state has taken in so far (every result moves it, whatever
        its index: two reads with the same count and the same window length read the same figures, holes and
        result; what the API's per-cycle cache of window replies is keyed by)."""
        with self._lock:
            return self.newest_counted or self.newest, self.sums.figures(cycles), self._count

    def holes_in(self, first: int, last: int) -> list[dict]:
        """The holes dropped while behind whose missing cycles lie (partly) within ``first`` .. ``last``."""
        with self._lock:
            return [h for h in self.holes if h["first_cycle"] is not None and h["last_cycle"] is not None
                    and h["first_cycle"] <= last and h["last_cycle"] >= first]

    def wait_index(self, index: int, timeout: float) -> bool:
        with self._lock:
            return self.updated.wait_for(lambda: self.newest is not None and self.newest.index >= index, timeout)


class SseClient:
    """One stream client: an asyncio queue filled from listener threads through its event loop."""

    def __init__(self, loop: asyncio.AbstractEventLoop, engine_id: str | None, queue_size: int) -> None:
        self.loop, self.engine_id = loop, engine_id
        self.queue: asyncio.Queue = asyncio.Queue(maxsize=queue_size)
        self.dropped = 0

    def offer(self, item: tuple[str, str]) -> None:  # on the client's event loop
        try:
            self.queue.put_nowait(item)
        except asyncio.QueueFull:
            self.dropped += 1


class SseBroadcaster(Listener):
    """Turns events into ("cycle" | "alert", json) and offers them to every subscribed client; a slow client's
    full queue drops (counted per client and in ``dropped``), never the others'."""

    name = "sse"

    def __init__(self, encode: Callable[[ServiceEvent], list[tuple[str, str]]], client_queue: int = 64) -> None:
        self.encode, self.client_queue = encode, client_queue
        self._clients: set[SseClient] = set()
        self._lock = threading.Lock()
        self.dropped = 0  # events lost to slow clients, all clients together

    def subscribe(self, engine_id: str | None) -> SseClient:
        client = SseClient(asyncio.get_running_loop(), engine_id, self.client_queue)
        with self._lock:
            self._clients.add(client)
        return client

    def unsubscribe(self, client: SseClient) -> None:
        with self._lock:
            self._clients.discard(client)
            self.dropped += client.dropped
            client.dropped = 0

    @property
    def clients(self) -> int:
        with self._lock:
            return len(self._clients)

    def wants(self, event: ServiceEvent) -> bool:
        """Whether any client listens (the fan-out's check, on the ingest thread: a set's length, read without the
        lock). An event published before a client subscribes is not that client's either way."""
        return len(self._clients) > 0

    def on_message_received(self, event: ServiceEvent) -> None:
        with self._lock:
            clients = [c for c in self._clients if c.engine_id in (None, event.engine_id)]
        if not clients:
            return
        items = self.encode(event)
        for client in clients:
            for item in items:
                try:
                    client.loop.call_soon_threadsafe(client.offer, item)
                except RuntimeError:  # its loop has closed: the client is gone
                    self.unsubscribe(client)
                    break
