"""serve's heap policy (service/app_gc.py): each step collects what is not frozen and freezes the survivors; a full
step (the first, then every full_every_s) collects the whole heap. On a fake clock; no timing asserted."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator

import pytest
from frictionwatch.service.app_gc import FrozenHeap


class Node:
    """An object in a reference cycle with itself: only the cyclic collector frees it."""

    def __init__(self) -> None:
        self.me = self


@pytest.fixture
def heap() -> Iterator[tuple[FrozenHeap, list[float]]]:
    now = [0.0]
    policy = FrozenHeap(every_s=10.0, full_every_s=100.0, clock=lambda: now[0])
    try:
        yield policy, now
    finally:
        gc.unfreeze()  # the rest of the test session keeps the collector's defaults


def cycle_garbage() -> weakref.ref:
    """A weak reference to a reference cycle that nothing else holds."""
    return weakref.ref(Node())


def test_a_step_collects_young_garbage_and_freezes_the_survivors(heap) -> None:
    policy, now = heap
    assert policy.step() is True  # the first step is a full one
    held, dropped = Node(), cycle_garbage()
    now[0] = 10.0
    assert policy.step() is False
    assert dropped() is None  # not frozen: garbage found before the freeze
    assert not any(o is held for o in gc.get_objects())  # frozen: no collection walks it
    assert gc.get_freeze_count() > 0 and policy.steps == 2 and policy.full_passes == 1


def test_a_frozen_cycle_that_becomes_garbage_waits_for_the_full_step(heap) -> None:
    policy, now = heap
    policy.step()
    ref = weakref.ref(Node())
    held = ref()
    now[0] = 10.0
    policy.step()  # frozen while held
    del held
    now[0] = 20.0
    policy.step()
    gc.collect()  # the collector's own passes skip it too
    assert ref() is not None  # the policy's stated cost: kept until the next full step
    now[0] = 110.0
    assert policy.step() is True
    assert ref() is None and policy.full_passes == 2


def test_stop_gives_the_heap_back(heap) -> None:
    policy, _ = heap
    policy.start()
    policy.stop()
    assert policy.steps >= 1
    assert gc.get_freeze_count() == 0


def test_bad_periods_are_refused() -> None:
    for every, full in ((0.0, 10.0), (20.0, 10.0), (float("nan"), 10.0)):
        with pytest.raises(ValueError, match="every_s"):
            FrozenHeap(every_s=every, full_every_s=full)


def test_one_more_full_step_when_settled(heap) -> None:
    _, now = heap
    settled = [False]
    policy = FrozenHeap(every_s=10.0, full_every_s=100.0, clock=lambda: now[0], settled=lambda: settled[0])
    assert policy.step() is True
    now[0] = 10.0
    assert policy.step() is False
    settled[0] = True
    now[0] = 20.0
    assert policy.step() is True  # the warm-up's leftovers collected once the engines run
    now[0] = 30.0
    assert policy.step() is False and policy.full_passes == 2
