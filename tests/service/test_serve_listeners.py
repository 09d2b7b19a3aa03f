"""The fan-out (service/listeners.py): the publisher never waits, a slow listener drops and counts alone, a failing
one is counted and keeps receiving, stop delivers what is queued; a publisher that can wait (``until``) loses
nothing to a slow listener and is let go at its deadline, what it left counted; the SSE broadcaster drops per slow
client."""

from __future__ import annotations

import asyncio
import threading
import time

from frictionwatch.service.listeners import Fanout, Listener, ServiceEvent, SseBroadcaster


def event(i: int, engine_id: str = "e1") -> ServiceEvent:
    return ServiceEvent(engine_id, None, float(i), alerts=({"alert_id": i},))


class Blocked(Listener):
    """Holds its thread until released: a consumer that stopped consuming."""

    name = "blocked"

    def __init__(self) -> None:
        self.release = threading.Event()
        self.got: list[int] = []

    def on_message_received(self, ev: ServiceEvent) -> None:
        self.release.wait(10)
        self.got.append(ev.alerts[0]["alert_id"])


class Failing(Listener):
    name = "failing"

    def __init__(self) -> None:
        self.errors: list[BaseException] = []
        self.seen = 0

    def on_message_received(self, ev: ServiceEvent) -> None:
        self.seen += 1
        if ev.alerts[0]["alert_id"] % 2:
            raise RuntimeError("odd")

    def on_error(self, exc: BaseException) -> None:
        self.errors.append(exc)


def test_a_blocked_listener_never_holds_the_publisher_nor_the_others() -> None:
    slow, bad, got = Blocked(), Failing(), []
    stopped = []
    fan = Fanout([slow, bad, got.append], queue_size=20)
    slow.stop = lambda: stopped.append("blocked")
    fan.start()
    worst = 0.0
    for i in range(200):  # paced like results (a healthy listener keeps up), while one listener is stuck
        t0 = time.perf_counter()
        fan.publish(event(i))
        worst = max(worst, time.perf_counter() - t0)
        time.sleep(0.002)
    assert worst < 0.05  # the publisher never waited for the stuck listener
    deadline = time.monotonic() + 5
    while len(got) < 200 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert [e.alerts[0]["alert_id"] for e in got] == list(range(200))  # the healthy one got all, in order
    # the stuck one: 1 taken off its queue + 20 queued, the other 179 dropped and counted
    assert fan.drops == {"blocked": 179, "failing": 0, "append": 0}
    slow.release.set()
    fan.stop()
    assert slow.got == list(range(21)) and stopped == ["blocked"]  # stop delivered what was queued, then stop()
    assert bad.seen == 200 and fan.errors["failing"] == 100 and len(bad.errors) == 100


def test_listener_names_stay_distinct() -> None:
    fan = Fanout([Failing(), Failing()])
    assert fan.names == ["failing", "failing-2"]


def test_sse_slow_client_drops_alone() -> None:
    async def scenario() -> tuple[int, int, int, int]:
        sse = SseBroadcaster(lambda ev: [("alert", str(ev.alerts[0]["alert_id"]))], client_queue=3)
        slow, fast, other = sse.subscribe(None), sse.subscribe("e1"), sse.subscribe("e2")
        got = []
        for i in range(10):
            await asyncio.to_thread(sse.on_message_received, event(i))  # from a listener thread
            await asyncio.sleep(0)
            got.append(fast.queue.get_nowait()[1])
        await asyncio.sleep(0.05)
        sse.unsubscribe(slow)
        return len(got), slow.queue.qsize(), sse.dropped, other.queue.qsize()

    n_fast, slow_held, dropped, other = asyncio.run(scenario())
    assert (n_fast, slow_held, dropped, other) == (10, 3, 7, 0)  # e2's client sees none of e1's events


def test_the_sse_listener_is_handed_nothing_while_no_client_listens() -> None:
    """``wants``: no queue hand-off (no thread woken) for a broadcaster without clients; with one, every event again."""

    async def scenario() -> tuple[int, int, int, list[str]]:
        sse = SseBroadcaster(lambda ev: [("alert", str(ev.alerts[0]["alert_id"]))], client_queue=16)
        fanout = Fanout([sse])
        fanout.start()
        for i in range(5):
            fanout.publish(event(i))
        await asyncio.sleep(0.2)
        before = fanout._workers[0].delivered
        client = sse.subscribe("e1")
        for i in range(5, 8):
            fanout.publish(event(i))
        got = [(await asyncio.wait_for(client.queue.get(), 5.0))[1] for _ in range(3)]
        fanout.stop()  # joins the worker: its count is bumped after the hand-off the client may already have seen
        after = fanout._workers[0].delivered
        return before, after, fanout.drops["sse"], got

    before, after, drops, got = asyncio.run(scenario())
    assert (before, after, drops) == (0, 3, 0)
    assert got == ["5", "6", "7"]


class Slow(Listener):
    """Keeps up, but slower than the publisher: a store under a log read as fast as possible."""

    name = "slow"

    def __init__(self) -> None:
        self.got: list[int] = []

    def on_message_received(self, ev: ServiceEvent) -> None:
        time.sleep(0.002)
        self.got.append(ev.alerts[0]["alert_id"])


def test_a_publisher_that_can_wait_loses_nothing_to_a_slow_listener() -> None:
    """``until``: a replay faster than its slowest listener waits for room (every event delivered, in order, none
    dropped); without it the same burst overflows the queue of 4 (what an engine's source keeps doing)."""
    outcomes = {}
    for until in (None, lambda: float("inf")):
        slow = Slow()
        fan = Fanout([slow], queue_size=4)
        fan.start()
        for i in range(60):
            fan.publish(event(i), until)
        fan.stop()
        outcomes[until is None] = (slow.got, fan.drops["slow"], fan.left["slow"])
    assert outcomes[False] == (list(range(60)), 0, 0)
    got, dropped, left = outcomes[True]
    assert dropped > 0 and len(got) + dropped == 60 and left == 0


def test_a_waiting_publisher_is_let_go_at_its_deadline_and_what_it_left_is_counted() -> None:
    """A listener that never frees its queue holds a waiting publisher until ``until()`` (moved by a stop while it
    waits), not longer; the event is counted in ``left``, not ``drops``. The stop's own time being up, what is
    still queued is counted too, and the listener's stop() is still called."""
    stuck = Blocked()
    stopped = []
    stuck.stop = lambda: stopped.append(True)
    fan = Fanout([stuck], queue_size=1)
    fan.start()
    fan.publish(event(0))  # taken by the thread, which now holds it
    assert wait_until_true(lambda: fan.queued["blocked"] == 0)
    fan.publish(event(1))  # fills the queue
    deadline = [float("inf")]
    done = threading.Event()
    threading.Thread(target=lambda: (fan.publish(event(2), lambda: deadline[0]), done.set())).start()
    assert not done.wait(0.3)  # waits while the deadline is far
    t0 = time.monotonic()
    deadline[0] = t0 + 0.2  # a stop sets it
    assert done.wait(2.0)
    assert 0.15 < time.monotonic() - t0 < 1.0
    assert (fan.left["blocked"], fan.drops["blocked"]) == (1, 0)
    t0 = time.monotonic()
    fan.stop(timeout=0.2)  # event 1 still queued, event 0 in hand: the time is up
    assert time.monotonic() - t0 < 0.2 + 0.5 + 0.3  # the listeners' time and IN_HAND_S
    assert fan.left["blocked"] == 2 and stopped == [True]
    fan.publish(event(3))  # after the stop: nobody delivers it
    assert fan.left["blocked"] == 3 and fan.drops["blocked"] == 0
    stuck.release.set()


def wait_until_true(pred, timeout: float = 5.0) -> bool:
    end = time.monotonic() + timeout
    while not pred() and time.monotonic() < end:
        time.sleep(0.01)
    return pred()


def test_a_persons_action_is_queued_past_a_full_queue_without_waiting() -> None:
    """``past_bound`` (the API's acknowledge and re-baseline): a full queue takes it at once, in order after what it
    holds, up to twice its size; past that it is dropped and counted like any event."""
    stuck = Blocked()
    fan = Fanout([stuck], queue_size=2)
    fan.start()
    fan.publish(event(0))  # in hand
    assert wait_until_true(lambda: fan.queued["blocked"] == 0)
    fan.publish(event(1))
    fan.publish(event(2))  # the queue full
    t0 = time.monotonic()
    fan.publish(event(3), past_bound=True)
    fan.publish(event(4), past_bound=True)
    assert time.monotonic() - t0 < 0.05 and fan.drops["blocked"] == 0
    fan.publish(event(5), past_bound=True)  # twice the bound held
    fan.publish(event(6))  # and an ordinary event on a full queue
    assert fan.drops["blocked"] == 2
    stuck.release.set()
    fan.stop()
    assert stuck.got == [0, 1, 2, 3, 4]


class Counting(Listener):
    name = "counting"

    def __init__(self) -> None:
        self.got: list[int] = []
        self.stopped = False

    def on_message_received(self, ev: ServiceEvent) -> None:
        self.got.append(ev.alerts[0]["alert_id"])

    def stop(self) -> None:
        self.stopped = True


def test_an_idle_listener_sleeps_until_an_event_and_a_stop_wakes_it() -> None:
    """A listener's thread waits on its empty queue without polling (design notes 70): it is woken by an event, and
    by a stop, which ends it with everything queued delivered; the stop's wake-up is neither delivered nor counted
    as an event left. Before ``start`` a stop leaves exactly the events published."""
    listener = Counting()
    fan = Fanout([listener], queue_size=8)
    worker = fan._workers[0]
    gets = []
    queue_get = worker.queue.get
    worker.queue.get = lambda *a, **k: (gets.append(1), queue_get(*a, **k))[1]
    fan.start()
    for i in range(3):
        fan.publish(event(i))
    assert wait_until_true(lambda: listener.got == [0, 1, 2])
    asleep = len(gets)
    time.sleep(0.35)  # idle on its empty queue: still in the one get (a loop that looked every 0.1 s made 3 more)
    assert len(gets) == asleep
    fan.publish(event(3))
    assert wait_until_true(lambda: listener.got == [0, 1, 2, 3])
    fan.stop(timeout=5.0)
    assert not worker.thread.is_alive() and listener.stopped
    assert (fan.left["counting"], fan.drops["counting"], listener.got) == (0, 0, [0, 1, 2, 3])

    never = Counting()
    fan = Fanout([never], queue_size=8)
    fan.publish(event(0))
    fan.publish(event(1))
    fan.stop(timeout=0.1)
    assert (fan.left["counting"], never.got, never.stopped) == (2, [], True)
