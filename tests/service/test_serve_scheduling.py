"""serve's threads under Linux's SCHED_BATCH (service/serve.py ``batch_scheduling``, design note 107): the calling
thread and the threads it starts within the block, the default policy back after it (an in-process caller keeps its
own); a thread started under another policy keeps it. Each case in a fresh interpreter, so the test process's own
scheduling is left as it was. (The served process's threads: test_serve_process.)"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(not hasattr(os, "SCHED_BATCH"), reason="SCHED_BATCH is Linux's")

CASE = """
import json, os, sys, threading
from frictionwatch.service.serve import batch_scheduling
if sys.argv[1] != "default":
    os.sched_setscheduler(0, getattr(os, sys.argv[1]), os.sched_param(0))
inside = []
with batch_scheduling() as done:
    t = threading.Thread(target=lambda: inside.append(os.sched_getscheduler(0)))
    t.start(); t.join()
    caller = os.sched_getscheduler(0)
after = os.sched_getscheduler(0)
try:  # back to the default before the answer and the exit: under SCHED_IDLE on a busy box (the suite's other worker)
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))  # a CPU share of ~0.3 % made this case 112 s
except OSError:
    pass
print(json.dumps([done, caller, inside[0], after]), flush=True)
os._exit(0)  # no interpreter teardown (numpy's, numba's) at whatever policy is left
"""


def run_case(start: str) -> list:
    out = subprocess.run([sys.executable, "-c", CASE, start], capture_output=True, text=True, check=True).stdout
    return json.loads(out.splitlines()[-1])


def test_batch_for_the_caller_and_the_threads_it_starts_then_the_default_back() -> None:
    assert run_case("default") == [True, os.SCHED_BATCH, os.SCHED_BATCH, os.SCHED_OTHER]


def test_a_policy_chosen_at_the_start_is_kept() -> None:
    assert run_case("SCHED_IDLE") == [False, os.SCHED_IDLE, os.SCHED_IDLE, os.SCHED_IDLE]
