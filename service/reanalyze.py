"""Re-analysis of an archive of replay logs after a model change (`frictionwatch reanalyze`, docs/reanalyze.md).

Each log is one Dask task (``analyze_one``: the analysis `frictionwatch analyze --json` prints, same functions); the
client writes the per-log results and the index, so the workers only need to read the logs (a real cluster's
workers must see the archive at the same path and have frictionwatch installed). Dask is imported only here and
only when a run starts: `frictionwatch analyze` does not load it.

Workers are processes with one thread each: the numba kernels are compiled without ``nogil``, so two threads in one
process would take turns on the GIL for most of a cycle.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from frictionwatch.core.model.engine import PRESET_DIR, SpecError
from frictionwatch.core.model.engine_model import load_model
from frictionwatch.drivers.errors import DriverError

log = logging.getLogger(__name__)

LOG_SUFFIX = ".mcap"
INDEX_NAME = "index.json"
INDEX_VERSION = "1.1"  # major: a key renamed, removed or its meaning changed; minor: keys added
WARM_CANDIDATES = 5  # logs a worker tries, smallest first, until one gives a cycle to warm its kernels on
EXPECTED_ERRORS = (SpecError, DriverError, ValueError, OSError, EOFError)


@dataclass(frozen=True)
class ModelChoice:
    """The model every log is analysed with. ``arg``: what `analyze --engine` would be given (None: the spec each
    log carries); ``sha256`` of its TOML (``EngineModel.to_toml``) and ``mtime`` of its file decide whether an
    earlier result is still this model's; ``sensor_health``: the speed-based sensor-health stage on (`analyze
    --sensor-health`), which an earlier result must have had the same way to be kept."""

    arg: str | None
    label: str
    sha256: str | None
    mtime: float | None
    sensor_health: bool = False

    @classmethod
    def stored(cls) -> ModelChoice:
        return cls(None, "the engine spec stored in each log", None, None)

    @classmethod
    def load(cls, name_or_path: str) -> ModelChoice:
        """Read and check the model now (a bad file is one error before any work, not one per log)."""
        model = load_model(name_or_path)
        path = Path(name_or_path)
        if path.suffix and path.exists():
            arg, source = str(path.resolve()), path
        else:
            arg, source = name_or_path, PRESET_DIR / f"{name_or_path}.toml"
        digest = hashlib.sha256(model.to_toml().encode()).hexdigest()
        return cls(arg, str(name_or_path), digest, source.stat().st_mtime)


def find_logs(root: Path, skip: Path | None = None) -> list[Path]:
    """Every ``*.mcap`` file under ``root`` (any depth, any case of the suffix), sorted; nothing under ``skip``
    (the output folder when it lies inside the archive). Truth files and other sidecars are never read."""
    skip = skip.resolve() if skip is not None else None
    logs = []
    for folder, dirs, files in os.walk(root):
        here = Path(folder)
        dirs[:] = sorted(d for d in dirs if skip is None or (here / d).resolve() != skip)
        logs += [here / f for f in files if f.lower().endswith(LOG_SUFFIX) and (here / f).is_file()]
    return sorted(logs)


def result_path(out: Path, root: Path, log_file: Path) -> Path:
    """``out`` / the log's path relative to the archive + ``.json``: logs of one name in two folders stay apart."""
    rel = log_file.relative_to(root)
    return out / rel.parent / (rel.name + ".json")


def analyze_one(log_file: str, engine: str | None, sensor_health: bool = False) -> dict:
    """One log through `analyze --json [--sensor-health]` (service.pipeline.analyze_log, cmd_analyze.document): a row
    with status "ok" and the document, or "failed" with a one-line reason for what `analyze` refuses. Runs on a
    worker."""
    from frictionwatch.service.cmd_analyze import document, monitor_config, no_cycle_reason
    from frictionwatch.service.pipeline import analyze_log

    t = time.perf_counter()
    try:
        analysis = analyze_log(Path(log_file), engine, config=monitor_config(sensor_health))
    except EXPECTED_ERRORS as exc:
        return failed_row(f"{type(exc).__name__}: {exc}", time.perf_counter() - t)
    if not analysis.results:
        return failed_row(no_cycle_reason(analysis, Path(log_file).name), time.perf_counter() - t)
    doc = document(analysis)
    return {"status": "ok", "reason": None, "doc": doc, "elapsed_s": time.perf_counter() - t}


def failed_row(reason: str, elapsed_s: float | None) -> dict:
    line = " ".join(str(reason).split())  # one line, whatever the exception's text
    return {"status": "failed", "reason": line, "doc": None, "elapsed_s": elapsed_s}


def warm_kernels(candidates: list[str], engine: str | None, sensor_health: bool = False) -> float:
    """Load (or compile, on an empty cache) the monitor's numba kernels in this process by running the pipeline
    over the first cycles of the first candidate log that has any; the seconds it took. Nothing is written."""
    from frictionwatch.drivers.logs.mcap_log import LogReader
    from frictionwatch.service.cmd_analyze import monitor_config
    from frictionwatch.service.pipeline import EnginePipeline, resolve_model

    t = time.perf_counter()
    for name in candidates:
        try:
            with LogReader(Path(name)) as reader:
                if reader.info is None:
                    continue
                pipe = EnginePipeline(resolve_model(reader.engine_toml, engine, Path(name).name, reader.info),
                                      reader.info, monitor_config(sensor_health))
                done = 0
                for record in reader.records():
                    done += len(pipe.feed(record))
                    if done >= 2:
                        return time.perf_counter() - t
        except EXPECTED_ERRORS:
            continue
    return time.perf_counter() - t


@contextmanager
def start_client(scheduler: str | None, workers: int | None, processes: bool = True) -> Iterator:
    """A Dask client: of the scheduler at ``scheduler`` (a running cluster), else of a new LocalCluster of
    ``workers`` (default: the cores) single-threaded worker processes, closed on exit."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        client = Client(scheduler, timeout="30s")
        try:
            yield client
        finally:
            client.close()
        return
    n = workers or os.cpu_count() or 1
    with LocalCluster(n_workers=n, threads_per_worker=1, processes=processes, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        yield client


def warm_workers(client, logs: list[Path], engine: str | None = None, sensor_health: bool = False) -> None:
    """One warm-up task pinned to each worker (in its task thread: its event loop keeps answering the scheduler
    during a long first compile). The kernels' on-disk cache (numba: NUMBA_CACHE_DIR, else beside the sources) is
    shared by the processes of one machine, so only the first process on an empty cache compiles each kernel."""
    candidates = [str(p) for p in sorted(logs, key=_size)[:WARM_CANDIDATES]]
    futures = [client.submit(warm_kernels, candidates, engine, sensor_health, workers=[w], allow_other_workers=False,
                             pure=False)
               for w in client.scheduler_info()["workers"]]
    client.gather(futures)


def run_on_dask(client, logs: list[Path], model: ModelChoice) -> Iterator[tuple[Path, dict]]:
    """(log, row) for each log as its task ends, in completion order. A task that raised (a bug, a worker lost
    while reading that log) is a failed row with the error's name, never the end of the run. The largest logs are
    submitted first (Dask runs earlier submissions first): a long log started last would leave the other workers
    idle at the end."""
    from dask.distributed import as_completed

    logs = sorted(logs, key=_size, reverse=True)
    futures = client.map(analyze_one, [str(p) for p in logs], engine=model.arg, sensor_health=model.sensor_health,
                         pure=False)
    which = {f.key: p for f, p in zip(futures, logs)}
    for future in as_completed(futures):
        path = which[future.key]
        if future.status == "error":
            exc = future.exception()
            row = failed_row(f"unexpected {type(exc).__name__}: {exc}", None)
        else:
            row = future.result()
        future.release()
        yield path, row


def up_to_date(result: Path, log_file: Path, model: ModelChoice, previous: dict | None) -> bool:
    """An earlier result is kept when the index says it was this model's (same TOML digest, the speed-based stage on
    or off the same way) and the file is newer than both the log and the model file."""
    if previous is None or previous.get("status") != "ok" or previous.get("model_sha256") != model.sha256:
        return False
    if bool(previous.get("sensor_health", False)) != model.sensor_health:  # an index before 1.1: the stage was off
        return False
    try:
        written = result.stat().st_mtime
    except OSError:
        return False
    return written > log_file.stat().st_mtime and (model.mtime is None or written > model.mtime)


def read_index(path: Path) -> dict[str, dict]:
    """The rows of an earlier index by log, empty when there is none or it cannot be read (then all is redone)."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        return {row["log"]: row for row in doc["logs"]}
    except FileNotFoundError:
        return {}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        log.warning("%s cannot be read (%s): every log is analysed again", path, exc)
        return {}


def index_row(rel: str, result_rel: str | None, row: dict, model: ModelChoice) -> dict:
    """A log's line in the index: status and reason, cycles, the engine's FMEP ± 1 sigma with its status."""
    doc = row["doc"] or {}
    friction = doc.get("friction") or {}
    return {
        "log": rel, "status": row["status"], "reason": row["reason"],
        "result": result_rel if row["status"] == "ok" else None,
        "engine": doc.get("engine"), "cycles": doc.get("cycles_ok"),
        "cycles_skipped": sum(doc.get("cycles_skipped", {}).values()) if doc else None,
        "log_damage": doc.get("log_damage"),
        "fmep_bar": friction.get("fmep_bar"), "fmep_sigma_bar": friction.get("fmep_sigma_bar"),
        "friction_status": friction.get("status"),
        "elapsed_s": None if row["elapsed_s"] is None else round(row["elapsed_s"], 3),
        "model_sha256": model.sha256, "sensor_health": model.sensor_health, "this_run": True,
    }


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0
