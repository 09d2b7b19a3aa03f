"""Stand-ins for a discrepancy job's child process (service/discrepancy_jobs.py ``run_job(target=...)``). A spawned
child imports the module that holds its target: this one imports nothing heavy, so a stand-in starts in ~1 s rather
than the ~10 s a test module's imports (FastAPI, the service) take."""

from __future__ import annotations

import os


def ends_without_a_word(send, *args) -> None:
    """A child that dies (killed, out of memory) before it reports."""
    os._exit(3)


def reports_a_bug(send, *args) -> None:
    send.send(("error", "Traceback (most recent call last):\n  ...\nKeyError: 'odd'\n"))


def reports_its_policy(send, *args) -> None:
    send.send(("done", {"policy": os.sched_getscheduler(0)}))


def reports_a_report(send, *args) -> None:
    """A child that finishes at once with a report of its own (a test of the jobs' bookkeeping, not the workflow)."""
    send.send(("done", {"verdict": "a stand-in's report"}))
