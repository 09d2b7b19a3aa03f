"""A log read as fast as possible waits for its slowest listener (service/listeners.py ``publish(wait=True)``): a
store slower than the replay keeps every analysed cycle; a real-time source never waits (tests/service/
test_serve_listeners.py: the blocked listener there is dropped on, the publisher never held)."""

from __future__ import annotations

import time

from frictionwatch.service.listeners import Listener, ServiceEvent

from tests.service.serve_helpers import DEMO, demo_service, wait_until


class SlowStore(Listener):
    """A store whose every write takes 20 ms: far slower than the monitor on a replay read as fast as possible."""

    name = "store"

    def __init__(self) -> None:
        self.cycles: list[int] = []

    def on_message_received(self, ev: ServiceEvent) -> None:
        if ev.result is not None:
            time.sleep(0.02)
            self.cycles.append(int(ev.result.index))


def test_a_fast_replay_loses_no_cycle_to_a_slow_store() -> None:
    store = SlowStore()
    svc = demo_service("fast", f"mcap:{DEMO}", listeners=[store], queue_size=2)
    assert not svc.session.realtime
    svc.start()
    try:
        assert wait_until(lambda: svc.sources_ended and svc.session.cycles_ok > 0, timeout=120.0)
    finally:
        svc.stop()
    assert svc.fanout.drops["store"] == 0
    assert len(store.cycles) == svc.cycles_ok > 20
    assert store.cycles == sorted(set(store.cycles))  # each once, in order
