"""StoreListener: batches by count and by time, estimates at a cadence and on change, a failed write retried once
then counted as lost without reaching the caller, and a writer killed with SIGKILL losing nothing it reported
committed (the file passing SQLite's integrity check)."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import threading
import time
from types import SimpleNamespace

import pytest
from frictionwatch.service.store import StoreListener, open_store

from tests.service.store_samples import TOML, alert, losses, summary

ENG = "eng-1"


@pytest.fixture
def store(tmp_path):
    s = open_store(str(tmp_path / "fw.db"))
    s.register_engine(ENG, TOML)
    yield s
    s.close()


class Commits:
    def __init__(self) -> None:
        self.batches: list[list[int]] = []
        self.event = threading.Event()

    def __call__(self, cycles: list[int]) -> None:
        self.batches.append(cycles)
        self.event.set()


def test_batches_by_count_then_stop_flushes_the_rest(store):
    commits = Commits()
    listener = StoreListener(store, ENG, batch_cycles=10, max_delay_s=60.0, on_commit=commits)
    for i in range(25):
        listener.on_cycle(summary(i))
    assert commits.batches == [list(range(10)), list(range(10, 20))]
    assert store.latest_cycle(ENG) == 19
    listener.stop()
    assert commits.batches[-1] == list(range(20, 25)) and store.latest_cycle(ENG) == 24
    assert listener.stats["batches"] == 3 and listener.stats["cycles_written"] == 25
    assert listener.stats["write_errors"] == 0


def test_a_quiet_stream_is_committed_within_max_delay(store):
    commits = Commits()
    listener = StoreListener(store, ENG, batch_cycles=1000, max_delay_s=0.2, on_commit=commits)
    t0 = time.monotonic()
    for i in range(3):
        listener.on_cycle(summary(i))
    listener.on_alert(alert(1))
    assert commits.event.wait(5.0)
    waited = time.monotonic() - t0
    assert 0.2 <= waited < 2.0, waited
    assert commits.batches == [[0, 1, 2]] and [a["alert_id"] for a in store.load_alerts(ENG)] == [1]
    listener.stop()


def test_estimates_are_kept_at_a_cadence_and_whenever_a_status_changes(store):
    listener = StoreListener(store, ENG, batch_cycles=100, estimate_every=5)
    for i in range(16):
        listener.on_cycle(summary(i), losses(i, status="share" if 7 <= i < 9 else "measured"))
    listener.stop()
    kept = sorted({r["cycle_index"] for r in store.estimates(ENG, 0, 100)})
    assert kept == [0, 5, 7, 9, 14]  # 7: share from measured; 9: back to measured; then every 5
    assert listener.stats["estimates_written"] == 5


def test_only_the_newest_state_of_an_alert_in_a_batch_is_written(store):
    listener = StoreListener(store, ENG, batch_cycles=100)
    listener.on_alert(alert(1))
    listener.on_alert(dict(alert(1), state="cleared", cleared_cycle=300))
    listener.stop()
    assert [(a["alert_id"], a["state"]) for a in store.load_alerts(ENG)] == [(1, "cleared")]


class FailingStore:
    """The real store, with write_batch failing the first ``failures`` times."""

    def __init__(self, store, failures: int) -> None:
        self.store, self.failures = store, failures

    def write_batch(self, *args, **kwargs):
        if self.failures > 0:
            self.failures -= 1
            raise sqlite3.OperationalError("disk I/O error")
        return self.store.write_batch(*args, **kwargs)


def test_a_failed_write_is_retried_once(store):
    listener = StoreListener(FailingStore(store, 1), ENG, batch_cycles=5, retry_delay_s=0.0)
    for i in range(5):
        listener.on_cycle(summary(i))
    assert listener.stats["write_errors"] == 1 and listener.stats["lost_batches"] == 0
    assert store.latest_cycle(ENG) == 4
    listener.stop()


def test_a_batch_failing_twice_is_counted_lost_and_the_listener_goes_on(store, caplog):
    listener = StoreListener(FailingStore(store, 2), ENG, batch_cycles=5, retry_delay_s=0.0)
    for i in range(10):
        listener.on_cycle(summary(i))  # never raises
    listener.stop()
    assert listener.stats["write_errors"] == 2
    assert listener.stats["lost_batches"] == 1 and listener.stats["lost_cycles"] == 5
    assert [r["cycle_index"] for r in store.cycles(ENG, 0, 100)] == list(range(5, 10))
    assert sum("disk I/O error" in r.getMessage() for r in caplog.records) == 2


CHILD = textwrap.dedent("""
    import itertools, sys
    from frictionwatch.service.store import StoreListener, open_store
    from tests.service.store_samples import TOML, losses, summary

    store = open_store(sys.argv[1])
    store.register_engine("eng-1", TOML)
    first = (store.latest_cycle("eng-1") or -1) + 1
    # a commit may hold no cycle (estimates only): print nothing then, not an empty line
    report = lambda cycles: cycles and print(*cycles, sep="\\n", flush=True)
    listener = StoreListener(store, "eng-1", batch_cycles=7, max_delay_s=0.05, estimate_every=3, on_commit=report)
    for i in itertools.count(first):
        listener.on_cycle(summary(i, z=20), losses(i, z=20))
""")


@pytest.mark.parametrize("synchronous", ["full", "normal"])
def test_kill_9_mid_run_loses_nothing_reported_committed(tmp_path, synchronous):
    """Three runs of a writer, each SIGKILLed mid-run after a different number of commits, each starting after
    the last cycle the file holds: every cycle a run printed as committed is in the file, the cycles form one
    unbroken run from 0, and the file passes PRAGMA integrity_check."""
    url = f"sqlite:{tmp_path / 'fw.db'}?synchronous={synchronous}"
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    reported: set[int] = set()
    for stop_after in (200, 600, 1500):
        child = subprocess.Popen([sys.executable, "-c", CHILD, url], stdout=subprocess.PIPE, text=True, cwd=root)
        got = 0
        deadline = time.monotonic() + 120.0
        while got < stop_after and time.monotonic() < deadline:
            line = child.stdout.readline()
            if not line:
                break
            reported.add(int(line))
            got += 1
        child.send_signal(signal.SIGKILL)
        # read the rest through the same buffered pipe object: communicate(timeout=...) reads the raw descriptor
        # and would skip what readline had already buffered, starting the tail mid-line
        tail = child.stdout.read()
        child.stdout.close()
        child.wait(timeout=30)
        reported.update(int(x) for x in tail.split("\n")[:-1])  # the text after the last newline may be cut
        assert child.returncode == -signal.SIGKILL
        assert got == stop_after, f"the writer reported only {got} cycles"
        store = open_store(url)
        latest = store.latest_cycle(ENG)
        stored = [r["cycle_index"] for r in store.cycles(ENG, 0, latest)]
        store.close()
        assert stored == list(range(latest + 1))
        assert reported <= set(stored), sorted(reported - set(stored))[:10]
        assert sqlite3.connect(tmp_path / "fw.db").execute("PRAGMA integrity_check").fetchone()[0] == "ok"


def test_cylinder_rows_given_as_a_function_are_built_only_for_the_estimates_kept(store):
    built: list[int] = []

    def rows(i: int):
        def build():
            built.append(i)
            return losses(i)
        return build

    listener = StoreListener(store, ENG, batch_cycles=100, estimate_every=5)
    for i in range(16):
        s = summary(i)
        s["flags"] = ["misfire_cyl2"] if i in (7, 8) else []
        listener.on_cycle(s, rows(i))
    listener.stop()
    assert built == [0, 5, 7, 9, 14]  # the cadence, the flag raised at 7 and gone at 9
    assert sorted({r["cycle_index"] for r in store.estimates(ENG, 0, 100)}) == built


def event(result=None, alerts=(), baseline=None):
    """The fields of service.listeners.ServiceEvent the store reads."""
    return SimpleNamespace(engine_id=ENG, result=result, alerts=tuple(alerts), baseline=baseline,
                           term_names=("a0", "a1"))


def test_service_events_become_cycles_estimates_alerts_and_baselines(store):
    built: list[tuple[int, tuple]] = []

    def losses_of(result, names):
        built.append((result, tuple(names)))
        return losses(result)

    listener = StoreListener(store, ENG, batch_cycles=100, estimate_every=10,
                             summary_of=lambda engine_id, i: summary(i, engine_id=engine_id), losses_of=losses_of)
    for i in range(12):
        listener.on_message_received(event(i, alerts=[alert(1)] if i == 3 else ()))
    listener.on_message_received(event(None, alerts=[dict(alert(1), state="acknowledged", acknowledged_by="op")]))
    listener.on_message_received(event(None, baseline={"fmep_bar": [1.0, 1.1]}))
    # the baseline is saved at once, after the cycles pending before it
    assert store.latest_cycle(ENG) == 11 and store.load_baseline(ENG) == {"fmep_bar": [1.0, 1.1]}
    listener.stop()
    assert [(a["alert_id"], a["state"]) for a in store.load_alerts(ENG)] == [(1, "acknowledged")]
    # the first cycle, cycle 1 (its flag no_previous_cycle gone), then 10 cycles on
    assert built == [(0, ("a0", "a1")), (1, ("a0", "a1")), (11, ("a0", "a1"))]
    assert sorted({r["cycle_index"] for r in store.estimates(ENG, 0, 100)}) == [0, 1, 11]
    assert listener.stats["write_errors"] == 0 and listener.name == "store"
