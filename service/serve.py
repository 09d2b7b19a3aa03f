"""`frictionwatch serve`: live per-cylinder losses and alerts over HTTP, one pipeline per engine, several engines in
one process.

    frictionwatch serve --source 'mcap:replay_logs/demo.mcap?loop=1&speed=1'
    frictionwatch serve --source 'serial:/dev/ttyUSB0?baud=921600#genset-1' --source 'can:socketcan/can0#genset-1'

Sources (drivers/source.py URLs) that end in the same ``#ID`` feed one engine (a tooth board and a pressure DAQ of
one genset); a source without ``#ID`` is an engine of its own, named after its engine (``genset-v20``, then
``genset-v20-2``). Each engine's sources share their own timer clocks (drivers.timebase.Clocks). The engine model
is the one named by ``--engine`` or the spec the source carries (a replay log).

Safety (service/security.py): 127.0.0.1 by default; another address only with --token-file. Without a token file a
token is made at start and printed once: acknowledging and re-baselining always need it.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import signal
import socket
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from frictionwatch.drivers.logs.recorder import Recorder
from frictionwatch.drivers.source import Source, open_source
from frictionwatch.drivers.timebase import Clocks
from frictionwatch.service.alerts import AlertConfig, AlertEngine
from frictionwatch.service.app_gc import FrozenHeap
from frictionwatch.service.cmd_analyze import SENSOR_HEALTH_HELP, monitor_config
from frictionwatch.service.data_dir import CHECKPOINT_S, DataDir
from frictionwatch.service.engine_service import EngineService
from frictionwatch.service.pipeline import resolve_model
from frictionwatch.service.security import ENGINE_ID, check_bind, new_token, read_token
from frictionwatch.service.startup import StartupTicker
from frictionwatch.service.warmup import HOLD_BYTES

log = logging.getLogger(__name__)
DEFAULT_SOURCE = "mcap:replay_logs/demo.mcap?loop=1&speed=1"
MAX_QUEUE_S, DRAIN_S = 10.0, 5.0  # LiveSession's defaults (service/live.py, Backpressure)
# below ~1 s the queue would drop on an ordinary hiccup of the ingest thread (a batch spans 50-100 ms, the merge's
# reorder window 1 s); above 600 s one genset-v20 queues ~2 GB
QUEUE_LIMITS = (1.0, 600.0)
HOLD_MB_LIMITS = (0, 16384)  # --hold-mb: 0 (no hold) to 16 GB
SPANS_SAID = 8  # the stop line names this many of the index ranges holes left out (a run that fell behind often: 39)
RECORD_FILE_BYTES, RECORD_FILES = 64 << 20, 16  # serve --record: the recorder's defaults (drivers/logs/recorder.py)
DRAIN_LIMITS = (0.0, 600.0)  # 0: abandon what is queued at once (logged)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("serve", help="serve live losses, alerts and the dashboard over HTTP")
    p.add_argument("--source", action="append", metavar="URL[#ID]",
                   help=f"a source URL, '#ID' names its engine (repeatable; default {DEFAULT_SOURCE})")
    p.add_argument("--engine", help="engine preset, engine TOML or model TOML for every engine (default: the spec "
                                    "the source carries)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8080, help="port (default 8080; 0 picks a free one)")
    p.add_argument("--data-dir", type=Path, help="keep cycles, estimates, alerts and baselines in DIR/frictionwatch.db; "
                                                 "a restart with the same DIR continues from them")
    p.add_argument("--store", metavar="URL",
                   help="instead of --data-dir: keep them in a PostgreSQL database several serve processes may share "
                        "(postgresql://user[:password]@host[:port]/db; each engine id written by one process only; "
                        "docs/scaling.md)")
    p.add_argument("--keep-days", type=float, help="with --data-dir or --store: delete cycles and estimates older than "
                                                   "this many days (at start, then hourly; alerts and baselines are "
                                                   "kept; with --store only this process's engines)")
    p.add_argument("--checkpoint-s", type=float, default=CHECKPOINT_S, metavar="S",
                   help=f"with --data-dir or --store: save each engine's smoothed estimates this often while it runs "
                        f"(default {CHECKPOINT_S:g}: what a kill -9 loses of them; a clean stop saves them too)")
    p.add_argument("--token-file", type=Path, help="file holding the token state changes need (required off loopback)")
    p.add_argument("--history-cycles", type=int, default=5000, help="recent cycles each engine holds for the API")
    p.add_argument("--max-queue-s", type=float, default=MAX_QUEUE_S, metavar="S",
                   help=f"the most acquisition time each engine's ingest queue holds; a real-time source that gets "
                        f"further ahead of the analysis loses its oldest queued data, counted (default {MAX_QUEUE_S:g}; "
                        f"{QUEUE_LIMITS[0]:g}-{QUEUE_LIMITS[1]:g}; genset-v20: ~3.2 MB a second)")
    p.add_argument("--hold-mb", type=int, default=HOLD_BYTES // 2**20, metavar="MB",
                   help=f"while an engine's warm-up compiles its kernels (a cold start), how much of a serial or CAN "
                        f"board's input its queue holds beyond --max-queue-s, to analyse after it; past it the oldest "
                        f"is dropped, counted (default {HOLD_BYTES // 2**20}, in memory, per engine; 0: no hold; "
                        f"genset-v20: ~3.2 MB a second)")
    p.add_argument("--drain-s", type=float, default=DRAIN_S, metavar="S",
                   help=f"at stop (SIGTERM, Ctrl-C), how long each engine may go on analysing what is queued; what is "
                        f"left then is logged, not analysed (default {DRAIN_S:g}; {DRAIN_LIMITS[0]:g}-"
                        f"{DRAIN_LIMITS[1]:g}; keep it under the stop grace time, docker's is 10 s)")
    p.add_argument("--sensor-health", action="store_true", help=SENSOR_HEALTH_HELP)
    p.add_argument("--record", type=Path, metavar="DIR",
                   help="the black box: each engine's raw input as it was analysed, with its restarts, in rotating "
                        f"replay logs DIR/ENGINE-ID/rec-*.mcap (at most {RECORD_FILES} files of "
                        f"{RECORD_FILE_BYTES >> 20} MiB each; `frictionwatch analyze` reads one)")
    p.set_defaults(func=run)


def engine_groups(urls: Sequence[str]) -> list[tuple[str | None, list[str]]]:
    """[(engine id or None, [source URLs])] in command-line order; '#ID' groups sources into one engine."""
    groups: dict[str, list[str]] = {}
    out: list[tuple[str | None, list[str]]] = []
    for raw in urls:
        url, sep, ident = raw.rpartition("#") if "#" in raw else (raw, "", "")
        if not sep:
            out.append((None, [raw]))
            continue
        if not ENGINE_ID.fullmatch(ident):
            raise ValueError(f"--source {raw}: the engine id after '#' must be 1-40 of a-z, 0-9 and '-'")
        if ident not in groups:
            groups[ident] = []
            out.append((ident, groups[ident]))
        groups[ident].append(url)
    return out


def slug(name: str) -> str:
    s = re.sub(r"[^a-z0-9-]+", "-", name.lower()).strip("-")[:36]
    return s or "engine"


def build_engine(ident: str | None, urls: list[str], engine: str | None, taken: set[str], record: Path | None = None,
                 **options) -> EngineService:
    """Open the sources of one engine (closed again if anything fails) and wire its EngineService; ``record``: the
    folder whose ENGINE-ID subfolder gets its black-box recording (the session closes the recorder)."""
    clocks = Clocks()
    sources: dict[str, Source] = {}
    try:
        for i, url in enumerate(urls):
            sources[f"{url.partition(':')[0]}{i}"] = open_source(url, clocks)
        info = next((s.info for s in sources.values() if s.info is not None), None)
        if info is None:
            raise ValueError(f"{', '.join(urls)}: no source states the acquisition (tick clock, wheel); give the "
                             "serial source tick_hz=..., teeth=..., missing=...")
        toml = next((s.engine_toml for s in sources.values() if s.engine_toml), None)
        model = resolve_model(toml, engine, urls[0], info)
        engine_id = ident or _free_id(slug(model.spec.name), taken)
        if engine_id in taken:
            raise ValueError(f"engine id {engine_id} given twice")
        taken.add(engine_id)
        if record is not None:  # files are opened at the first record written
            options["recorder"] = Recorder(record / engine_id, toml, info, max_file_bytes=RECORD_FILE_BYTES,
                                           max_files=RECORD_FILES)
        return EngineService(engine_id, model, info, sources, urls=urls, warm=True, **options)
    except BaseException:
        for s in sources.values():
            s.close()
        raise


def build_engines(args: argparse.Namespace, data: DataDir | None) -> list[EngineService]:
    """Every engine the command line names, wired (not started): its sources, its model, the alert engine with the
    stored baseline (--data-dir), the monitor's settings (--sensor-health). On a failure the engines made so far
    are stopped again."""
    alerts = _alerts_factory()
    services: list[EngineService] = []
    taken: set[str] = set()
    try:
        for ident, urls in engine_groups(args.source or [DEFAULT_SOURCE]):
            svc = build_engine(ident, urls, args.engine, taken, history_cycles=args.history_cycles,
                               alerts=data.with_baseline(alerts) if data else alerts,
                               config=monitor_config(args.sensor_health), max_queue_s=args.max_queue_s,
                               drain_s=args.drain_s, record=args.record, hold_bytes=args.hold_mb * 2**20)
            services.append(svc)
            if data:
                print(f"frictionwatch serve: {data.attach(svc)}", flush=True)
    except BaseException:
        for s in services:
            s.stop()
        raise
    return services


def _free_id(base: str, taken: set[str]) -> str:
    if base not in taken:
        return base
    i = 2
    while f"{base}-{i}" in taken:
        i += 1
    return f"{base}-{i}"


def run(args: argparse.Namespace) -> int:
    with batch_scheduling():  # before any of serve's threads starts: they inherit it
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    import uvicorn
    from frictionwatch.service.api import create_app

    token = read_token(args.token_file) if args.token_file else None
    check_bind(args.host, token)
    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port must be 0..65535, got {args.port}")
    if args.history_cycles < 64:
        raise ValueError(f"--history-cycles must be >= 64, got {args.history_cycles}")
    if args.data_dir and args.store:
        raise ValueError("give --data-dir (SQLite in a folder) or --store (a PostgreSQL URL), not both")
    if args.store and not args.store.startswith(("postgresql://", "postgres://")):
        raise ValueError("--store takes a postgresql://user@host/db URL (for SQLite give --data-dir)")
    if args.keep_days is not None and not (args.data_dir or args.store):
        raise ValueError("--keep-days needs --data-dir or --store")
    check_seconds("--max-queue-s", args.max_queue_s, QUEUE_LIMITS)
    check_seconds("--drain-s", args.drain_s, DRAIN_LIMITS)
    if not HOLD_MB_LIMITS[0] <= args.hold_mb <= HOLD_MB_LIMITS[1]:
        raise ValueError(f"--hold-mb must be {HOLD_MB_LIMITS[0]} to {HOLD_MB_LIMITS[1]}, got {args.hold_mb}")
    where = args.data_dir or args.store
    data = DataDir(where, keep_days=args.keep_days, checkpoint_s=args.checkpoint_s) if where else None
    if data:
        print(f"frictionwatch serve: keeping data in the {data.store.where}", flush=True)  # no password (redact)
    services: list[EngineService] = []
    sock = None
    try:
        sock = _bind(args.host, args.port)  # first: a port in use begins no run
        services += build_engines(args, data)
    except BaseException:
        for s in services:
            s.stop()
        if sock is not None:
            sock.close()
        if data:
            data.close(failed_start=True)
        raise
    if data:
        data.start_retention()
        data.start_checkpoints()
    made = token is None
    token = token or new_token()
    app = create_app(services, token=token, fleet=data.store.fleet if data else None)
    host, port = sock.getsockname()[:2]
    shown = f"[{host}]" if ":" in host else host
    print(f"frictionwatch serve: dashboard at http://{shown}:{port}/ ; engines: "
          + ", ".join(f"{s.engine_id} ({s.spec.name}, {' + '.join(s.urls)})" for s in services), flush=True)
    if made:
        print(f"frictionwatch serve: token for acknowledge and baseline (this run only): {token}", flush=True)
    # until each engine's first cycle the terminal says what it waits for (a fresh install compiles for 1-2 min)
    ticker = StartupTicker(lambda: services).start()
    # the collector's full passes out of the request path (service/app_gc.py); one more once every engine started
    heap = FrozenHeap(settled=lambda: all(s.last_result_s is not None for s in services)).start()
    http, loop, missing = http_stack()
    if missing:
        print(f"frictionwatch serve: {missing} not installed: HTTP on {http} and {loop} (the pure-Python stand-in "
              f"costs more of the server's CPU a request; pip install {missing.replace(' and ', ' ')})", flush=True)
    # access_log off: uvicorn's access logger is below log_level 'warning' anyway, its record never printed
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", lifespan="on", http=http, loop=loop,
                                           access_log=False))
    # uvicorn shuts down on SIGINT / SIGTERM (the lifespan stops every engine), then raises the signal again with
    # the handlers it found: these make that a normal end (exit 0) instead of death by the signal
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: None)
    try:
        server.run(sockets=[sock])
    finally:
        ticker.stop()
        heap.stop()
        sock.close()
        for s in services:  # what /health said while it ran, once more where the operator started it
            print(stop_summary(s), flush=True)
        if data:
            data.close()
    return 0


def http_stack() -> tuple[str, str, str]:
    """uvicorn's HTTP parser and event loop: (http, loop, what is missing of the fast pair: '' when nothing).
    httptools (a C parser) and uvloop where installed (pyproject's dependencies; design note 146), each else its
    pure-Python stand-in, h11 and asyncio, which serve then says at start."""
    import importlib.util

    has = {m: importlib.util.find_spec(m) is not None for m in ("httptools", "uvloop")}
    missing = " and ".join(m for m, ok in has.items() if not ok)
    return "httptools" if has["httptools"] else "h11", "uvloop" if has["uvloop"] else "asyncio", missing


def stop_summary(svc: EngineService) -> str:
    """One terminal line per engine at the end of a serve run: the cycles analysed, the acquisition a real-time source
    lost while the analysis was behind (serve --max-queue-s: a cold start's compile, an overloaded box), which until
    now only /health and /metrics said, the cycles skipped and why, and a looped replay's seams. A dropped stretch
    is said once, as dropped: the cycle its hole cut is not a skip as well (design note 119), with the cycle indices
    its holes left out (design note 124), and a seam is a restart, not a loss."""
    parts = [f"{svc.cycles_ok} cycles analysed"]
    warm = getattr(svc, "warmup", None)
    if warm is not None and warm.seconds is not None:
        after = getattr(svc, "compiled_after_warm_up", None)
        parts.append(f"kernels warmed up in {warm.seconds:.1f} s before the first record"
                     + (f" (failed: {warm.error})" if warm.error else "")
                     + ("" if after is None else f", {after} compiled after it"))
    lag = svc.backlog()
    if lag.get("held_records"):
        parts.append(f"held while the kernels warmed up: up to {lag['held_s']:.1f} s of acquisition "
                     f"({lag['held_records']} records, {lag['held_bytes'] / 2**20:.1f} MB), analysed after it"
                     + ("" if lag.get("dropped_records") else ", nothing dropped"))
    if lag.get("dropped_records"):
        cycles = lag.get("dropped_cycles")
        about = f"~{cycles:.0f} cycles, " if cycles is not None else ""
        # a hole whose cut left every index numbered (its last before its first: 0 cycles) is not a span
        cut = [(h["first_cycle"], h["last_cycle"]) for h in getattr(svc, "holes", ())
               if h["first_cycle"] is not None and h["last_cycle"] is not None and h["last_cycle"] >= h["first_cycle"]]
        spans = [f"{a}" if a == b else f"{a}-{b}" for a, b in cut]
        shown = ", ".join(spans[:SPANS_SAID]) + (f" and {len(spans) - SPANS_SAID} more" if len(spans) > SPANS_SAID
                                                 else "")
        parts.append(f"dropped while the analysis was behind: {about}{lag['dropped_s']:.1f} s of acquisition "
                     f"({lag['dropped_records']} records)"
                     + (f", not numbered: cycle{'s' if len(spans) > 1 else ''} {shown}" if spans else ""))
    skipped = {str(k): int(n) for k, n in svc.skipped.items() if n}
    if skipped:
        parts.append("skipped: " + ", ".join(f"{k} {n}" for k, n in sorted(skipped.items())))
    seams = int(svc.restarts.get("loop_restart", 0))
    if seams:
        parts.append(f"{seams} loop seam{'s' if seams > 1 else ''} of the replay (restarts, nothing lost)")
    return f"frictionwatch serve: stopped {svc.engine_id}: " + "; ".join(parts)


@contextmanager
def batch_scheduling() -> Iterator[bool]:
    """The calling thread, and every thread it starts meanwhile, under Linux's SCHED_BATCH until the block ends (the
    thread's default policy back then: an in-process caller, a test, keeps its own); it yields False, changing
    nothing, where the platform has no such policy, refuses it, or the thread runs under another policy than the
    default (``chrt``: the operator's choice stays).

    Why (design note 107): serve is one process of many Python threads on few cores (per engine a reader and an
    ingest thread, the listeners, the API). Under the default policy a thread that wakes (a reader's 40 ms pacing,
    a queue hand-over, the API state's next event) preempts the one running, mid-cycle; a batch thread that wakes
    waits for the running one's time slice instead. Measured (8 looped demo gensets on one core, a shared box at
    load 8-13): per monitor call 16 -> 8.5 voluntary and 6.5 -> 2.2 involuntary context switches, and every part of
    serve cheaper a cycle (base/this: the monitor 1.06-1.17, the readers 1.14-1.41, all in 1.06-1.21). The price:
    a thread that wakes runs up to one time slice (a few ms) later, a request to the API likewise."""
    setter, policy = getattr(os, "sched_setscheduler", None), getattr(os, "SCHED_BATCH", None)
    changed = False
    if setter is not None and policy is not None:
        try:
            if os.sched_getscheduler(0) == os.SCHED_OTHER:
                setter(0, policy, os.sched_param(0))  # 0: this thread (Linux); threads started after it inherit it
                changed = True
        except OSError as exc:  # a container's seccomp profile may refuse it: serve runs as before
            log.info("serve: SCHED_BATCH refused (%s); threads keep the default policy", exc)
    try:
        yield changed
    finally:
        if changed:
            setter(0, os.SCHED_OTHER, os.sched_param(0))


def check_seconds(flag: str, value: float, limits: tuple[float, float]) -> None:
    """A one-line error unless ``limits[0] <= value <= limits[1]`` (NaN and inf fail too)."""
    if not limits[0] <= value <= limits[1]:
        raise ValueError(f"{flag} must be {limits[0]:g} to {limits[1]:g} seconds, got {value:g}")


def _alerts_factory():
    """(engine_id, spec, baseline=None) -> the engine's AlertEngine (service/alerts.py) with the default settings."""
    config = AlertConfig()
    return lambda engine_id, spec, baseline=None: AlertEngine(spec, config, baseline=baseline)


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    # proto named, not 0: asyncio sets TCP_NODELAY on an accepted connection only where its proto is IPPROTO_TCP
    # (accepted sockets inherit the listener's). With proto 0 every reply on a kept-alive connection waited for
    # the client's delayed ACK: 44 ms per request against 0.6 ms (measured, a FastAPI app on uvicorn 0.54)
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(128)
    except OSError as exc:
        sock.close()
        raise OSError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from exc
    sock.set_inheritable(True)
    return sock
