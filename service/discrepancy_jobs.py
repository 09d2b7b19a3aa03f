"""The discrepancy workflow on an engine's recorded window, as a background job of the service (issue 18 item 5).

    jobs = DiscrepancyJobs()
    job = jobs.start(svc, cycles=120, baseline="default", max_steps=1)   # BusyError while another job runs
    jobs.get(job.job_id).to_dict()   # {"state": "running" | "done" | "failed", "reason", "report", ...}

One job at a time over all engines. The workflow runs the monitor over the window dozens of times (its bench: 200
k9k cycles in under 30 s on one core; a genset-v20's 120 cycles take minutes), so it runs in a child process of its
own (``run_job``: spawned, then made ``lowest_priority``), not on a thread of serve: a thread takes its share of
serve's GIL from the live engines' ingest threads for as long as it runs, whatever the cores, and compiled its
loss-term kernels there (seven, counted as "compiled after the warm-up" on every engine's stop line). The child runs
under Linux's SCHED_IDLE: only on a core nothing else wants (on a 2-core box, the one serve's GIL leaves free), so
a box with no core to spare runs the job late rather than the engines. Measured (looped genset-v20 replays, serve and
the job pinned to one core, the worst case; quiet box but for the runs themselves, session 39), cycles/s analysed
before -> during a job: 12 engines, thread 145.0 -> 144.5, child at nice 10 145.0 -> 145.3; 16 engines (near that
core's capacity), thread 193.5 -> 193.7, nice 10 188.2 -> 39.8 (it fell behind and dropped data); 14 engines,
thread 166.1 -> 124.5 (118 records dropped), SCHED_IDLE 167.0 -> 146.5 and 161.6 -> 130.6 (none dropped). On one
core near capacity the runs scatter more than the ways differ (the thread cost nothing at 16 and the most at 14);
what the child's process does promise is the other core on a 2-core box, which a thread cannot use. A worker
thread of serve waits for the child's report. The window is
the engine's newest raw records (``EngineService.recent``) spanning ``cycles`` cycles at the newest mean speed plus
one to get in sync; it is assembled and analysed by ``service.cmd_discrepancy.run_discrepancy``, exactly as
`frictionwatch discrepancy` does a log. A job that cannot run (too few cycles recorded, a monitor that analyses too
few) fails with the workflow's own one-line reason. Finished jobs are kept, the newest ``KEPT`` of them.
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import os
import secrets
import threading
import time
import traceback
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

from frictionwatch.core.discrepancy import Options
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.service.cmd_discrepancy import run_discrepancy, with_baseline

log = logging.getLogger(__name__)

KEPT = 32  # finished jobs remembered (their reports are a few tens of kB each)


class BusyError(RuntimeError):
    """Another job is running."""


@dataclass
class Job:
    job_id: str
    engine_id: str
    cycles: int
    baseline: str
    max_steps: int
    started_s: float = field(default_factory=time.monotonic)
    state: str = "running"
    reason: str | None = None
    report: dict | None = None
    finished_s: float | None = None
    records: int = 0

    def to_dict(self) -> dict:
        end = self.finished_s if self.finished_s is not None else time.monotonic()
        return {"job_id": self.job_id, "engine_id": self.engine_id, "state": self.state, "reason": self.reason,
                "cycles_requested": self.cycles, "baseline": self.baseline, "max_steps": self.max_steps,
                "records": self.records, "elapsed_s": end - self.started_s, "report": self.report}


class DiscrepancyJobs:
    """See the module docstring. Thread-safe: the API's threads start and read jobs, the worker finishes them."""

    def __init__(self) -> None:
        self._jobs: OrderedDict[str, Job] = OrderedDict()
        self._lock = threading.Lock()
        self._running: Job | None = None

    def start(self, svc: Any, cycles: int, baseline: str, max_steps: int) -> Job:
        """A new job on ``svc`` (an EngineService). Raises ValueError for a baseline the engine's model cannot take
        (an effect it does not have), BusyError while a job runs."""
        model = with_baseline(svc.model, baseline)  # checked here: a bad request is the caller's 422, not a job
        with self._lock:
            if self._running is not None:
                r = self._running
                raise BusyError(f"discrepancy job {r.job_id} on engine '{r.engine_id}' is running (one at a time); "
                                f"retry when GET .../discrepancy/{r.job_id} says it is done")
            job = self._running = Job(secrets.token_hex(8), svc.engine_id, cycles, baseline, max_steps)
            self._jobs[job.job_id] = job
            while len(self._jobs) > KEPT + 1:
                self._jobs.popitem(last=False)
        newest, _ = svc.state.snapshot(1)
        rpm = newest.rpm_mean if newest is not None and newest.rpm_mean > 0 else None
        # the newest `cycles` cycles at the newest speed, plus one to get in sync; all that is held before a result
        records = svc.recent.window((cycles + 1) * 120.0 / rpm if rpm else None)
        job.records = len(records)
        worker = threading.Thread(target=self._run, args=(job, svc.info, records, model), daemon=True,
                                  name=f"discrepancy-{job.job_id}")
        worker.start()
        return job

    def _run(self, job: Job, info: Any, records: list, model: Any) -> None:
        try:
            report = run_job(info, records, model, job.max_steps)
            report["baseline"] = job.baseline
        except ValueError as exc:  # the workflow's own refusal: too few cycles, none analysed
            self._finish(job, "failed", reason=str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        except JobProcessError as exc:  # the child's own error (its traceback logged), or its end without a report
            self._finish(job, "failed", reason=f"internal error: {exc}")
        except Exception as exc:  # noqa: BLE001 - a bug met on odd data: the job fails, the service goes on
            log.error("discrepancy job %s on %s failed: %s", job.job_id, job.engine_id, exc, exc_info=exc)
            self._finish(job, "failed", reason=f"internal error: {type(exc).__name__}: {str(exc).splitlines()[0]}"
                         if str(exc) else f"internal error: {type(exc).__name__}")
        else:
            self._finish(job, "done", report=report)

    def _finish(self, job: Job, state: str, reason: str | None = None, report: dict | None = None) -> None:
        with self._lock:
            job.state, job.reason, job.report, job.finished_s = state, reason, report, time.monotonic()
            self._running = None

    def get(self, job_id: str) -> Job | None:
        with self._lock:
            return self._jobs.get(job_id)

    @property
    def running(self) -> Job | None:
        return self._running


class JobProcessError(RuntimeError):
    """The job's process failed: an error it reported (with its traceback), or it ended without a report."""


def run_job(info: Any, records: list, model: Any, max_steps: int, target: Any = None) -> dict:
    """The workflow on ``records`` with ``model`` (the baseline already applied: run_discrepancy gets 'default') in
    a spawned child process of the lowest priority (``lowest_priority``), as plain JSON values. Raises ValueError
    with the workflow's own refusal (too few cycles, none analysed), JobProcessError for anything else. The child is a
    daemon: it ends with serve. ``target``: the child's function (default ``_job_process``; a test's stand-in)."""
    ctx = multiprocessing.get_context("spawn")  # not fork: serve's threads and locks are not the child's
    receive, send = ctx.Pipe(duplex=False)
    # the model goes as its TOML (EngineModel.to_toml: read back equal; the object itself does not pickle)
    text = model.to_toml() if model is not None else None
    proc = ctx.Process(target=target or _job_process, args=(send, info, records, text, max_steps), daemon=True,
                       name="frictionwatch-discrepancy")
    proc.start()
    lowest_priority(proc.pid)  # at once: the child's imports and unpickling already run at it
    send.close()  # the child holds the only sending end: its end (or death) is this end's EOF
    try:
        kind, value = receive.recv()
    except EOFError:
        proc.join(5.0)
        raise JobProcessError(f"the job's process ended without a report (exit code {proc.exitcode})") from None
    finally:
        receive.close()
    proc.join(5.0)
    if kind == "refused":
        raise ValueError(value)
    if kind == "error":
        log.error("discrepancy job's process: %s", value)
        raise JobProcessError(value.strip().splitlines()[-1])
    return value


def lowest_priority(pid: int) -> str:
    """Give process ``pid`` the CPU only where nothing else wants it: Linux's SCHED_IDLE (its threads inherit it),
    else nice +19. Returns which."""
    try:
        os.sched_setscheduler(pid, os.SCHED_IDLE, os.sched_param(0))
        return "SCHED_IDLE"
    except (AttributeError, OSError):  # not Linux, or not allowed: the weakest nice
        os.setpriority(os.PRIO_PROCESS, pid, 19)
        return "nice 19"


def _job_process(send: Any, info: Any, records: list, model_toml: str, max_steps: int) -> None:
    """The child's side of run_job: one message, ("done", report) | ("refused", reason) | ("error", traceback)."""
    try:
        model = EngineModel.from_toml(model_toml, "the engine's model")
        report = run_discrepancy((info, records), model, Options(max_steps=max_steps), "default")
        message = ("done", plain(report))
    except ValueError as exc:  # the workflow's own refusal
        message = ("refused", str(exc))
    except Exception:  # noqa: BLE001 - said to the parent, which fails the job with it
        message = ("error", traceback.format_exc())
    send.send(message)
    send.close()


def plain(value: Any) -> Any:
    """The report as plain JSON values: numpy scalars and arrays as numbers and lists, a non-finite number as None
    (JSON has no NaN), anything else unknown as its text."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if hasattr(value, "tolist"):
        return plain(value.tolist())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, (bool, int, str)):
        return value
    return str(value)


__all__ = ["KEPT", "BusyError", "DiscrepancyJobs", "Job", "JobProcessError", "lowest_priority", "plain", "run_job"]
