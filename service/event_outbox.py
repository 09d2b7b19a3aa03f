"""One engine's events handed to its fan-out in the order they were made, by the ingest thread and by the API's
threads, with only the ingest thread ever waiting (issue 28, design note 57).

    outbox = EventOutbox(fanout)
    outbox.put(event)        # under the lock that orders the events (EngineService: the alert engine's lock)
    outbox.send(until)       # the ingest thread, the session's lock released: every queued event, in order, each
                             # waiting for its listeners' room until until() when given (Fanout.publish)
    outbox.send_own()        # an API thread: never waits, never drops for a full queue (see its docstring)

Why not publish where the event is made: a cycle's event is made under the session's lock, and a publish that waits
for a listener there would hold the monitor (checkpoints, the API's counters, a stop's drain: design note 55). Why
one queue for both kinds: an acknowledgement published while the ingest thread waits with the cycle that raised the
alert would reach the store first, and the raise would then overwrite it there.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable

from frictionwatch.service.listeners import Fanout, ServiceEvent


class EventOutbox:
    """See the module docstring."""

    def __init__(self, fanout: Fanout) -> None:
        self.fanout = fanout
        self._events: deque[ServiceEvent] = deque()
        self._sending = threading.Lock()  # whoever holds it hands on; only the ingest thread waits holding it

    def put(self, event: ServiceEvent) -> None:
        self._events.append(event)

    def send(self, until: Callable[[], float] | None = None) -> None:
        """The ingest thread: hand on every queued event in order (with ``until``, waiting for room until
        ``until()``)."""
        self._drain(until, ingest=True)

    def send_own(self) -> None:
        """An API thread: hand on the queued events before the first cycle's, never waiting; a full listener queue
        takes an API event past its bound (Fanout.publish ``past_bound``: a person's actions are few, and a replay
        that waits for its store keeps that queue full). A cycle's event is left to the ingest thread, which sends
        it right after making it (it is queued only between the two); so is every event while the ingest thread
        sends (it looks again once it lets go)."""
        self._drain(None, ingest=False)

    def __len__(self) -> int:
        return len(self._events)

    def _drain(self, until: Callable[[], float] | None, ingest: bool) -> None:
        while self._events:
            if not self._sending.acquire(blocking=ingest):  # an API thread never waits for the lock either
                return
            try:
                while self._events:
                    if not ingest and self._events[0].result is not None:
                        return
                    event = self._events.popleft()
                    # an API event (no result: a person's action) is never lost to a full queue, nor waited for
                    self.fanout.publish(event, until, past_bound=event.result is None)
            finally:
                self._sending.release()
