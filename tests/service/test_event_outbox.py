"""service/event_outbox.py: the API's events keep their place among the cycles' and are never waited for nor lost
to a full queue; only the ingest thread waits (design note 57)."""

from __future__ import annotations

import threading
import time

from frictionwatch.service.event_outbox import EventOutbox
from frictionwatch.service.listeners import Fanout, ServiceEvent

from tests.service.test_serve_listeners import Blocked, wait_until_true

CYCLE = object()  # stands for a CycleResult: the outbox only asks whether an event has one


def cycle(i: int) -> ServiceEvent:
    return ServiceEvent("e1", CYCLE, float(i), alerts=({"alert_id": i},))  # type: ignore[arg-type]


def action(i: int) -> ServiceEvent:
    return ServiceEvent("e1", None, float(i), alerts=({"alert_id": i},))


def test_an_api_event_behind_a_cycles_waits_for_the_ingest_thread_to_send_both_in_order() -> None:
    got: list[ServiceEvent] = []
    fan = Fanout([got.append])
    fan.start()
    outbox = EventOutbox(fan)
    outbox.put(cycle(1))  # made under the session's lock, not yet sent
    outbox.put(action(2))  # an acknowledgement made meanwhile
    outbox.send_own()  # the API thread leaves both: the cycle's is the ingest thread's to send
    assert len(outbox) == 2
    outbox.send()  # the ingest thread, its lock released
    fan.stop()
    assert [e.alerts[0]["alert_id"] for e in got] == [1, 2] and len(outbox) == 0


def test_an_api_event_never_waits_for_a_waiting_ingest_thread_nor_is_lost_to_a_full_queue() -> None:
    stuck = Blocked()
    fan = Fanout([stuck], queue_size=1)
    fan.start()
    outbox = EventOutbox(fan)
    outbox.put(cycle(0))
    outbox.send()  # taken by the listener's thread, which holds it
    assert wait_until_true(lambda: fan.queued["blocked"] == 0)
    outbox.put(cycle(1))
    outbox.send()  # fills the queue of 1
    # the queue full and nobody sending: the API's event goes past the bound at once
    outbox.put(action(2))
    t0 = time.monotonic()
    outbox.send_own()
    assert time.monotonic() - t0 < 0.05 and len(outbox) == 0
    # the ingest thread waiting for room (a replay that can wait): the API's next event stays for it to send
    outbox.put(cycle(3))
    ingest = threading.Thread(target=outbox.send, args=(lambda: float("inf"),))
    ingest.start()
    assert wait_until_true(lambda: len(outbox) == 0)  # cycle 3 taken, its publish waiting
    outbox.put(action(4))
    t0 = time.monotonic()
    outbox.send_own()
    assert time.monotonic() - t0 < 0.05 and len(outbox) == 1
    stuck.release.set()
    ingest.join(5.0)
    fan.stop()
    assert not ingest.is_alive() and len(outbox) == 0
    assert stuck.got == [0, 1, 2, 3, 4] and fan.drops["blocked"] == 0
