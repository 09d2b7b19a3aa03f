"""`frictionwatch reanalyze DIR`: every replay log of an archive analysed again (after a model change) on Dask.

Writes OUT/<the log's path under DIR>.json (the document `analyze --json` prints for that log) and OUT/index.json
(one row per log: ok or failed with the reason, cycles, FMEP ± 1 sigma, seconds). docs/reanalyze.md says more.
Exit 0 when every log was analysed, 1 when some failed (their rows say why), 2 for a usage error.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

from frictionwatch.service.output_files import atomic_write_text, check_output_path
from frictionwatch.service.progress import progress_bar
from frictionwatch.service.reanalyze import (
    INDEX_NAME,
    INDEX_VERSION,
    ModelChoice,
    find_logs,
    index_row,
    read_index,
    result_path,
    run_on_dask,
    start_client,
    up_to_date,
    warm_workers,
)

STARTING_NOTE = ("starting the workers; each loads the numerical kernels (numba: compiled once after an install, "
                 "about a minute on a small machine)")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reanalyze", help="analyse every *.mcap log under a folder again, on Dask")
    p.add_argument("archive", type=Path, metavar="DIR", help="folder searched for *.mcap logs at any depth")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--model", metavar="FILE", help="model TOML (EngineModel.to_toml) or engine TOML")
    which.add_argument("--engine", metavar="NAME", help="engine preset; neither: the spec each log carries")
    p.add_argument("--out", type=Path, metavar="DIR", help="results folder (default: DIR/reanalysis)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler (tcp://host:port); default: a "
                   "local cluster")
    p.add_argument("--workers", type=int, metavar="N", help="local cluster worker processes (default: the cores)")
    p.add_argument("--force", action="store_true", help="analyse logs whose result is up to date too")
    p.add_argument("--json", action="store_true", help="print the index document instead of the table")
    p.add_argument("--sensor-health", action="store_true", help="switch on the speed-based sensor-health stage, as "
                   "`analyze --sensor-health` does (off by default: unreliable where the model is not the engine); a "
                   "result made with it off is not up to date for a run with it on, and the other way round")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    root = args.archive
    if not root.is_dir():
        raise NotADirectoryError(f"{root} is not a folder")
    if args.workers is not None and (args.workers < 1 or args.scheduler):
        raise ValueError("--workers must be >= 1, and is for the local cluster only (not with --scheduler)")
    out = args.out if args.out is not None else root / "reanalysis"
    check_output_path(out / INDEX_NAME)
    name = args.model or args.engine
    model = replace(ModelChoice.load(name) if name else ModelChoice.stored(), sensor_health=args.sensor_health)
    logs = find_logs(root, skip=out)
    if not logs:
        raise FileNotFoundError(f"no *.mcap log under {root}")
    previous = read_index(out / INDEX_NAME)
    rows: dict[str, dict] = {}
    todo = []
    for path in logs:
        rel = path.relative_to(root).as_posix()
        before = previous.get(rel)
        if not args.force and up_to_date(result_path(out, root, path), path, model, before):
            rows[rel] = {**before, "this_run": False}
        else:
            todo.append(path)
    if not args.verbose:  # Dask's own INFO lines (scheduler address, connections) only with -v; its import sets
        import distributed  # noqa: F401  (the level of its logger, so quiet it after)

        logging.getLogger("distributed").setLevel(logging.ERROR)
    t = time.perf_counter()
    where = args.scheduler or f"local cluster, {args.workers or os.cpu_count()} worker processes"
    startup: dict = {"s": None}
    try:
        if todo:
            _analyse(todo, root, out, model, args, rows, startup)
    finally:  # an interrupted run still indexes what it finished (and keeps the earlier rows of the rest)
        rows = {**{k: {**v, "this_run": False} for k, v in previous.items() if (root / k).is_file() and k not in rows},
                **rows}
        index = _index(root, model, where, logs, rows, len(todo), time.perf_counter() - t, startup["s"])
        atomic_write_text(out / INDEX_NAME, json.dumps(index, indent=1) + "\n")
    if args.json:
        print(json.dumps(index, indent=1))
    else:
        _print_table(index, out)
    return 0 if index["failed"] == 0 else 1


def _analyse(todo: list[Path], root: Path, out: Path, model: ModelChoice, args: argparse.Namespace,
             rows: dict[str, dict], startup: dict) -> None:
    """Run the logs on the cluster, write each result as it arrives (a log that failed now loses its old result:
    a result file is always the current model's analysis of the current log); ``startup["s"]``: the seconds to
    start the cluster (or connect) and warm the workers."""
    t = time.perf_counter()
    with start_client(args.scheduler, args.workers) as client, \
            progress_bar(total=len(todo), desc="reanalyze", unit="logs", waiting_note=STARTING_NOTE) as bar:
        warm_workers(client, todo, model.arg, model.sensor_health)
        startup["s"] = time.perf_counter() - t
        for path, row in run_on_dask(client, todo, model):
            rel = path.relative_to(root).as_posix()
            target = result_path(out, root, path)
            if row["status"] == "ok":
                atomic_write_text(target, json.dumps(row["doc"], indent=1) + "\n")
            else:
                target.unlink(missing_ok=True)
            rows[rel] = index_row(rel, target.relative_to(out).as_posix(), row, model)
            bar.update(1)


def _index(root: Path, model: ModelChoice, where: str, logs: list[Path], rows: dict[str, dict], analysed: int,
           wall_s: float, startup_s: float | None) -> dict:
    listed = [rows[k] for k in sorted(rows)]
    done = [r for r in listed if r["this_run"]]
    return {
        "index_version": INDEX_VERSION, "archive": str(root.resolve()), "model": model.label,
        "model_sha256": model.sha256, "sensor_health": model.sensor_health, "cluster": where,
        "logs_found": len(logs), "analysed_this_run": len(done), "up_to_date_kept": len(listed) - len(done),
        "not_reached": analysed - len(done),
        "ok": sum(r["status"] == "ok" for r in listed), "failed": sum(r["status"] == "failed" for r in listed),
        "wall_s": round(wall_s, 2), "startup_s": None if startup_s is None else round(startup_s, 2),
        "logs_per_min": round(60.0 * len(done) / wall_s, 2) if done and wall_s > 0 else None,
        "logs": listed,
    }


def _print_table(index: dict, out: Path) -> None:
    print(f"{'log':<40} {'status':<7} {'cycles':>6} {'FMEP bar':>16} {'s':>7}  reason / friction status")
    for r in index["logs"]:
        fmep = "-" if r["fmep_bar"] is None else (f"{r['fmep_bar']:.3f}" + (
            "" if r["fmep_sigma_bar"] is None else f" ± {r['fmep_sigma_bar']:.3f}"))
        secs = "-" if r["elapsed_s"] is None else f"{r['elapsed_s']:.1f}"
        note = r["reason"] if r["status"] == "failed" else (r["friction_status"] or "")
        kept = "" if r["this_run"] else " (up to date, kept)"
        print(f"{r['log']:<40} {r['status']:<7} {r['cycles'] if r['cycles'] is not None else '-':>6} {fmep:>16} "
              f"{secs:>7}  {note}{kept}")
    rate = "" if index["logs_per_min"] is None else f", {index['logs_per_min']:.1f} logs/min"
    print(f"{index['logs_found']} logs: {index['ok']} ok, {index['failed']} failed; analysed now "
          f"{index['analysed_this_run']} on {index['cluster']} in {index['wall_s']:.1f} s{rate}"
          + ("" if index["startup_s"] is None else f" (of which {index['startup_s']:.1f} s cluster start and "
             "kernel warm-up)"))
    if index["up_to_date_kept"]:
        print(f"{index['up_to_date_kept']} up to date (result newer than the log and the model, same model): "
              "kept; --force analyses them again")
    print(f"results and {INDEX_NAME} in {out}", file=sys.stderr)
