"""The HTTP API of the service (FastAPI): the contract's routes over a set of EngineService (docs in /openapi.json).

    app = create_app(services, token=token)      # attaches the SSE listener and the metrics' observer to every engine
    uvicorn.run(app, host="127.0.0.1", port=8080)  # the app's lifespan starts and stops the engines

Reads come from each engine's LatestState (service/listeners.py); what a friction figure is comes from
core/monitor/report/figure_status.py through service/api_views.py. State changes (acknowledge, baseline) need the
token (service/security.py), checked before any body is read (service/request_guard.py, with the body-size limit
and one-line errors that never echo the input), and so does starting a discrepancy job (service/discrepancy_jobs.py: one at a
time, in the background; its state and report are polled). No request value becomes a file path: the dashboard's files are listed once at start
and served by name from that list.

Bounded work per request (issue 28 item 2): every route reads a snapshot the engine's API-state listener published,
never the session, and costs the same whatever the history: a window mean reads running sums (service/window_sums.py),
window lengths stop at ``MAX_WINDOW_CYCLES``, and the large replies (a speed history past ``LARGE_CYCLES`` cycles) are
rate-limited (service/rate_limit.py: 429 with Retry-After). /health says each engine's backlog (cycles queued,
seconds behind) and is 'degraded' past ``LAG_DEGRADED_S``, and while cycles wait for a store that is down.
"""

from __future__ import annotations

import asyncio
import json
import math
import time
from collections.abc import AsyncIterator, Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import asynccontextmanager
from pathlib import Path as FilePath
from typing import Annotated, Literal

from fastapi import Body, Depends, FastAPI, Header, HTTPException, Path, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, Response
from frictionwatch.service import api_views as views
from frictionwatch.service.api_models import (
    Acknowledge,
    Alert,
    BaselineResult,
    CycleSummary,
    DiscrepancyJob,
    DiscrepancyRequest,
    EngineInfo,
    ErrorBody,
    FleetEngine,
    FrictionTorque,
    Health,
    Losses,
    RingCondition,
    SensorHealth,
    Speed,
)
from frictionwatch.service.discrepancy_jobs import KEPT, BusyError, DiscrepancyJobs
from frictionwatch.service.engine_service import EngineService
from frictionwatch.service.listeners import ServiceEvent, SseBroadcaster
from frictionwatch.service.metrics import RequestTimer, ServiceMetrics
from frictionwatch.service.rate_limit import TokenBucket
from frictionwatch.service.request_guard import MAX_BODY_BYTES, UNAUTHORISED, RequestGuard, validation_error
from frictionwatch.service.routes_startup import startup_router
from frictionwatch.service.security import ENGINE_ID, bearer_ok
from frictionwatch.service.startup import warm_up_words
from pydantic import TypeAdapter
from sse_starlette import EventSourceResponse

DASHBOARD_DIR = FilePath(__file__).with_name("dashboard")
STALE_S = 10.0  # an engine whose newest result is older than this is 'degraded' in /health
MAX_WINDOW_CYCLES = 5000  # the longest window or history a request may ask for (= serve's history per engine)
LARGE_CYCLES = 1000  # a speed history longer than this is a large reply: rate-limited
LARGE_PER_S, LARGE_BURST = 5.0, 10.0  # large replies a second the whole app gives, and the burst
LAG_DEGRADED_S = 2.0  # an engine whose real-time sources' data wait longer than this to be analysed is 'degraded'
DROPPED_RECENTLY_S = 30.0  # ... and so is one whose bounded queue dropped records this recently
DEFAULT_ALERTS, MAX_ALERTS = 100, 1000  # alerts one reply holds: by default, at most (= AlertConfig.max_history)
ALERTS_LIMIT_WORDS = (f"the newest N alerts (by alert id) are returned, default {DEFAULT_ALERTS}, at most {MAX_ALERTS}; "
                      "X-Total-Count says how many there are")
ERRORS = {404: {"model": ErrorBody}, 422: {"model": ErrorBody}}
EngineId = Annotated[str, Path(pattern=ENGINE_ID.pattern, description="engine slug [a-z0-9-]{1,40}")]
JOB_ID = r"^[0-9a-f]{16}$"
LAG_KEYS = ("queued_cycles", "queued_s", "behind_s", "dropped_records", "dropped_s", "dropped_cycles", "realtime",
            "last_drop_age_s", "holding", "held_s", "held_bytes", "held_records")


def encode_event(event: ServiceEvent) -> list[tuple[str, str]]:
    """A fan-out event as SSE items: a 'cycle' (CycleSummary) and one 'alert' per alert change."""
    items = []
    if event.result is not None:
        items.append(("cycle", json.dumps(views.cycle_summary(event.engine_id, event.result))))
    items += [("alert", json.dumps(a)) for a in event.alerts]
    return items


def create_app(services: Sequence[EngineService], token: str | None = None, *, ping_s: float = 15.0,
               client_queue: int = 64, dashboard_dir: FilePath = DASHBOARD_DIR, manage: bool = True,
               fleet: Callable[[], list[dict]] | None = None) -> FastAPI:
    """``manage``: the app's lifespan starts the engines and stops them at shutdown. ``fleet``: every engine of
    the store this process writes to (service/store/fleet.py), for GET /api/v1/fleet; None without a store."""
    engines = {s.engine_id: s for s in services}
    if len(engines) != len(services):
        raise ValueError(f"engine ids must be distinct: {[s.engine_id for s in services]}")
    sse = SseBroadcaster(encode_event, client_queue=client_queue)
    metrics = ServiceMetrics(lambda: list(engines.values()), lambda: sse.dropped)
    for s in services:
        s.add_listener(sse)
        s.state.on_visible = metrics.observer(s.engine_id)  # on the API state's thread: no listener of its own
    files = _dashboard_files(dashboard_dir)
    started = time.monotonic()
    # engine id -> the replies made once a cycle from its newest result (the smoothed /losses reply, the window
    # replies' own-estimate documents), shared by every request
    replies = {s.engine_id: views.NewestReplies() for s in services}

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        if manage:
            for s in services:
                s.start()
        try:
            yield
        finally:
            if manage:  # every engine's drain at once, one thread each: asyncio's default pool (cores + 4 threads)
                # stopped 20 engines six at a time, 31 s after SIGTERM where each engine's drain is bounded at 5 s
                # (serve --drain-s), past a supervisor's stop timeout
                with ThreadPoolExecutor(max_workers=max(len(services), 1), thread_name_prefix="stop") as pool:
                    loop = asyncio.get_running_loop()
                    await asyncio.gather(*(loop.run_in_executor(pool, s.stop) for s in services))

    app = FastAPI(title="frictionwatch", version="1", lifespan=lifespan,
                  description="Live per-cylinder friction losses and alerts. Units in field names.")
    app.state.services, app.state.sse, app.state.metrics, app.state.token = engines, sse, metrics, token
    app.state.newest_replies = replies  # read by tests and benches (what each engine's cache made)
    app.add_middleware(RequestGuard, token=lambda: app.state.token, max_body_bytes=MAX_BODY_BYTES)
    app.add_middleware(RequestTimer, metrics=metrics)  # added last: outermost, so a refused request is timed too
    app.add_exception_handler(RequestValidationError, validation_error)
    large = app.state.large_queries = TokenBucket(LARGE_PER_S, LARGE_BURST)
    metrics.rate_limited = lambda: large.refused
    app.include_router(startup_router(lambda: list(engines.values())))  # the dashboard's words before a first cycle
    jobs = app.state.discrepancy_jobs = DiscrepancyJobs()
    # the mix's read routes return their reply rendered by the route itself: what FastAPI does with a returned dict
    # (validate against the response_model, then dump_json) without its hop onto a worker thread for the validation;
    # the decorator's response_model still makes the schema. They are coroutines (run on the event loop), none waits
    # for anything but a lock held for a copy or a sum (LatestState's, the ingest queue's): under the GIL a worker
    # thread bought no parallel work, only two hand-overs a request (~130 us of CPU, and two waits for the GIL behind
    # the monitors; design note 154). The other routes stay on worker threads (some wait for the running monitor's
    # lock between records, EngineService.session.with_pipeline, or for a store).
    typed = {m: TypeAdapter(m) for m in (Health, list[EngineInfo], CycleSummary, Losses, FrictionTorque, Speed)}

    def body(model: object, doc: object) -> bytes:
        adapter = typed[model]
        return adapter.dump_json(adapter.validate_python(doc, from_attributes=True), by_alias=True)

    def rendered(model: object, doc: object) -> Response:
        return Response(body(model, doc), media_type="application/json")

    def newest(svc: EngineService, last: int | None = None) -> tuple:
        whole, ring = svc.state.snapshot(last)
        if whole is None:
            raise HTTPException(503, f"engine '{svc.engine_id}' has no analysed cycle yet", headers={"Retry-After": "2"})
        return whole, ring

    def limit_large(what: str) -> None:
        wait_s = large.take()
        if wait_s > 0:
            raise HTTPException(429, f"{what}: at most {LARGE_PER_S:g} large replies a second are served; retry "
                                     f"after {math.ceil(wait_s)} s or ask for at most {LARGE_CYCLES} cycles",
                                headers={"Retry-After": str(math.ceil(wait_s))})

    @app.get("/api/v1/health", response_model=Health)
    async def health() -> Response:
        now = time.monotonic()
        rows = [{"engine_id": s.engine_id, "running": s.running, "sources_ended": s.sources_ended,
                 "last_cycle_age_s": None if s.last_result_s is None else now - s.last_result_s, **backlog(s),
                 **store_waiting(s),
                 # the listener a replay faster than real time waits for now: not 'degraded' (nothing is lost, the
                 # replay runs at that listener's pace)
                 "paced_by_listener": s.fanout.waiting_for, "warming_up": bool(getattr(s, "warming_up", False)),
                 "startup": warm_up_words(s)} for s in engines.values()]
        for r in rows:
            r["startup"] = r["startup"] or catching_up_words(r)
        return rendered(Health, {"status": health_status(rows),
                                 "uptime_s": now - started, "engines": rows, "lag_degraded_s": LAG_DEGRADED_S,
                                 "fleet": fleet is not None})

    @app.get("/api/v1/engines", response_model=list[EngineInfo])
    async def engine_list() -> Response:
        out = []
        for s in engines.values():
            whole, _ = s.state.snapshot(1)
            out.append({"engine_id": s.engine_id, "engine_name": s.spec.name, "n_cylinders": s.spec.n_cyl,
                        "sources": s.urls, "cycles_ok": s.cycles_ok, "skipped": s.skipped,
                        "restarts": s.restarts,
                        "rpm_latest": None if whole is None else views.num(whole.rpm_mean),
                        "listener_drops": s.fanout.drops, "listener_errors": s.fanout.errors,
                        "listener_left": s.fanout.left, "listener_waited_s": s.fanout.waited_s,
                        "session_errors": dict(s.session.errors), "alert_errors": s.alert_errors,
                        "sse_clients": sse.clients, "backlog": backlog(s), "store": store_stats(s)})
        return rendered(list[EngineInfo], out)

    @app.get("/api/v1/fleet", response_model=list[FleetEngine], responses={503: {"model": ErrorBody}})
    def fleet_view() -> list[dict]:
        """Every engine in the store this process writes to, whichever process writes it (serve --store: a
        PostgreSQL several processes share; --data-dir: this process's file): its writer, its newest stored cycle,
        the engine's friction figure there and its open alerts. One query on per-engine rows, at most 1000 engines."""
        if fleet is None:
            raise HTTPException(404, "no store: start serve with --store or --data-dir for a fleet view")
        try:
            return fleet()
        except Exception as exc:  # noqa: BLE001 - the store down (being reconnected) or failing: said, not raised
            raise HTTPException(503, f"the store did not answer: {type(exc).__name__}",
                                headers={"Retry-After": "5"}) from None

    @app.get("/api/v1/engines/{engine_id}/cycles/latest", response_model=CycleSummary, responses=ERRORS)
    async def latest_cycle(svc: Svc) -> Response:
        # on the event loop: ~20 us of work, where the hop to a worker thread and back cost ~130 us of CPU (note 139)
        whole, _ = newest(svc, 1)
        return rendered(CycleSummary, views.cycle_summary(svc.engine_id, whole))

    @app.get("/api/v1/engines/{engine_id}/losses", response_model=Losses, responses=ERRORS)
    async def losses(svc: Svc, window_cycles: Annotated[int | None, Query(ge=1, le=MAX_WINDOW_CYCLES)] = None
                     ) -> Response:
        """The smoothed estimate at the newest cycle, or (``window_cycles``) each cycle's own estimate averaged over
        the newest N cycles (fewer when fewer are held): read from running sums, the same cost for any N."""
        if window_cycles is not None:
            last, figures, version = svc.state.versioned_window(window_cycles)
            if last is None or figures is None:
                newest(svc, 1)  # the 503 with its Retry-After

            def made() -> bytes:
                holes = svc.state.holes_in(figures.first_cycle, figures.last_cycle)
                return body(Losses, views.losses_window(svc.engine_id, last, figures, svc.term_names, holes,
                                                            replies[svc.engine_id].own))

            return Response(replies[svc.engine_id].window(version, figures.cycles, made),
                            media_type="application/json")
        whole, _ = newest(svc, 1)

        def make() -> tuple[int, bytes]:
            newer, index, weight, flags = svc.state.smoothed()
            return newer.index, body(Losses, views.losses_smoothed(svc.engine_id, newer, index, weight, flags,
                                                                   svc.term_names))

        return Response(replies[svc.engine_id].smoothed(whole.index, make), media_type="application/json")

    @app.get("/api/v1/engines/{engine_id}/friction-torque", response_model=FrictionTorque, responses=ERRORS)
    async def friction_torque(svc: Svc) -> Response:
        whole, _ = newest(svc, 1)
        return rendered(FrictionTorque, views.friction_torque(whole))

    @app.get("/api/v1/engines/{engine_id}/speed", response_model=Speed, responses=ERRORS)
    async def speed(svc: Svc, cycles: Annotated[int, Query(ge=1, le=MAX_WINDOW_CYCLES)] = 200) -> Response:
        if cycles > LARGE_CYCLES:
            limit_large(f"a speed history of more than {LARGE_CYCLES} cycles")
        whole, ring = newest(svc, cycles)
        return rendered(Speed, views.speed(whole, ring))

    @app.get("/api/v1/engines/{engine_id}/sensor-health", response_model=SensorHealth, responses=ERRORS)
    def sensor_health(svc: Svc) -> dict:
        """What checks the engine's sensors, as of the newest cycle: the TDC watch (on by default: every 100 cycles
        each cylinder's TDC found from its pressure, flagged against the calibration), the model's calibration
        (uncalibrated: a typical installation's errors assumed in every sigma; commissioned: measured by
        `frictionwatch commission`), and the speed-based stage's figures where it is switched on (`enabled`;
        `serve --sensor-health`, off by default: unreliable where the model is not the engine)."""
        whole, _ = newest(svc, 1)
        return views.sensor_health(whole, svc.tdc_watch, svc.model.calibration, svc.model.spec.n_cyl)

    @app.get("/api/v1/engines/{engine_id}/alerts", response_model=list[Alert], responses=ERRORS)
    def alerts(svc: Svc, response: Response, state: Literal["active", "all"] = "active",
               limit: Annotated[int, Query(ge=1, le=MAX_ALERTS, description=ALERTS_LIMIT_WORDS)] = DEFAULT_ALERTS
               ) -> list[dict]:
        """The engine's open alerts (``state=active``) or its alert history (``state=all``: the cleared ones the
        service holds, AlertConfig.max_history, and the open ones), oldest first: the newest ``limit`` of them.
        The header X-Total-Count says how many there are; the store (--data-dir) keeps every alert."""
        shown, total = svc.alert_list(active_only=state == "active", limit=limit)
        response.headers["X-Total-Count"] = str(total)
        return shown

    @app.get("/api/v1/engines/{engine_id}/ring-condition", response_model=list[RingCondition], responses=ERRORS)
    def ring_condition(svc: Svc) -> list[dict]:
        """Each cylinder's ring condition as of the newest cycle: the one figure (with its sigma) the ring alerts
        rest on, and the evidence under it (the leak effect and the measured friction since the baseline and
        against the siblings). Empty before the first cycle or without alerts."""
        return svc.ring_condition()

    @app.post("/api/v1/engines/{engine_id}/alerts/{alert_id}/acknowledge", response_model=Alert,
              dependencies=[Depends(authorised)], responses={401: {"model": ErrorBody}, **ERRORS})
    def acknowledge(svc: Svc, alert_id: Annotated[int, Path(ge=1, le=2**31 - 1)],
                    body: Annotated[Acknowledge | None, Body()] = None) -> dict:
        try:
            return svc.acknowledge(alert_id, (body or Acknowledge()).by)
        except LookupError as exc:
            raise HTTPException(404, str(exc)) from exc

    @app.post("/api/v1/engines/{engine_id}/baseline", response_model=BaselineResult,
              dependencies=[Depends(authorised)], responses={401: {"model": ErrorBody}, **ERRORS})
    def baseline(svc: Svc) -> dict:
        try:
            return svc.rebaseline()
        except LookupError as exc:
            raise HTTPException(404, str(exc)) from exc

    @app.post("/api/v1/engines/{engine_id}/discrepancy", response_model=DiscrepancyJob, status_code=202,
              dependencies=[Depends(authorised)],
              responses={401: {"model": ErrorBody}, 409: {"model": ErrorBody}, **ERRORS})
    def discrepancy_start(svc: Svc, body: Annotated[DiscrepancyRequest | None, Body()] = None) -> dict:
        """Start the discrepancy workflow (`frictionwatch discrepancy`) on the engine's newest recorded cycles: 202
        and the job; poll GET .../discrepancy/{job_id} for its report. One job at a time (409 while one runs); the
        engine keeps its newest 30 s of raw records for this."""
        req = body or DiscrepancyRequest()
        try:
            job = jobs.start(svc, req.cycles, req.baseline, req.max_steps)
        except BusyError as exc:
            raise HTTPException(409, str(exc)) from exc
        except ValueError as exc:  # a baseline naming an effect the engine's model does not have
            raise HTTPException(422, str(exc)) from exc
        return job.to_dict()

    @app.get("/api/v1/engines/{engine_id}/discrepancy/{job_id}", response_model=DiscrepancyJob, responses=ERRORS)
    def discrepancy_job(svc: Svc, job_id: Annotated[str, Path(pattern=JOB_ID)]) -> dict:
        """A discrepancy job: running, done (with the report) or failed (with a one-line reason)."""
        job = jobs.get(job_id)
        if job is None or job.engine_id != svc.engine_id:
            raise HTTPException(404, f"engine '{svc.engine_id}' has no discrepancy job {job_id} (finished jobs are "
                                     f"kept, the newest {KEPT})")
        return job.to_dict()

    @app.get("/api/v1/stream", responses=ERRORS)
    async def stream(request: Request, engine_id: Annotated[str | None, Query(pattern=ENGINE_ID.pattern)] = None):
        if engine_id is not None:
            await service(request, engine_id)
        client = sse.subscribe(engine_id)

        async def events() -> AsyncIterator[dict]:
            try:
                while not await request.is_disconnected():
                    try:
                        kind, data = await asyncio.wait_for(client.queue.get(), timeout=1.0)
                    except TimeoutError:
                        continue
                    yield {"event": kind, "data": data}
            finally:
                sse.unsubscribe(client)

        return EventSourceResponse(events(), ping=ping_s)

    @app.get("/metrics", include_in_schema=False)
    async def prometheus() -> Response:
        return Response(metrics.text(), media_type="text/plain; version=0.0.4; charset=utf-8")

    @app.get("/", include_in_schema=False)
    def dashboard() -> Response:
        page = files.get("index.html")
        if page is None:
            raise HTTPException(404, "the dashboard is not installed (service/dashboard/index.html)")
        return FileResponse(page)

    @app.get("/static/{name:path}", include_in_schema=False)
    def static(name: str) -> Response:
        path = files.get("static/" + name)  # a lookup in the list made at start, never a path built from the request
        if path is None:
            raise HTTPException(404, "no such file")
        return FileResponse(path)

    return app


def backlog(svc: EngineService) -> dict:
    """The engine's lag (EngineService.backlog) and whether it makes the engine 'degraded' (``behind``): a real-time
    source's data waiting past LAG_DEGRADED_S, or the bounded queue having dropped within DROPPED_RECENTLY_S."""
    lag = svc.backlog()
    dropping = lag["last_drop_age_s"] is not None and lag["last_drop_age_s"] < DROPPED_RECENTLY_S
    behind = lag["realtime"] and (max(lag["behind_s"], lag["queued_s"]) > LAG_DEGRADED_S or dropping)
    return {"behind": bool(behind), **{k: lag[k] for k in LAG_KEYS}}


def starting(row: dict) -> bool:
    """An engine row (/health's) that is starting: its warm-up compiles, or its queue still holds what a board gave
    while it did and nothing was dropped (the monitor is catching up on it: behind, as every cold start of a board
    is, but losing nothing). One that dropped records is degraded, held or not."""
    return bool(row["warming_up"] or (row["holding"] and not row["dropped_records"]))


def health_status(rows: list[dict]) -> str:
    """/health's status: 'ok' when every engine runs with a recent result, is not behind and has no cycle waiting
    for the store; else 'starting' when each engine that is not is starting (``starting``); else 'degraded'."""
    fine = [r["running"] and r["last_cycle_age_s"] is not None and r["last_cycle_age_s"] < STALE_S
            and not r["behind"] and not r["store_waiting_cycles"] for r in rows]
    if all(fine):
        return "ok"
    return "starting" if all(f or starting(r) for f, r in zip(fine, rows)) else "degraded"


def catching_up_words(row: dict) -> str | None:
    """While an engine's hold outlives its warm-up: what it is doing, in words (/health's ``startup``)."""
    if row["warming_up"] or not row["holding"] or row["dropped_records"]:
        return None
    return (f"catching up on the input held while the kernels warmed up: {row['queued_s']:.1f} s queued, "
            f"{row['behind_s']:.1f} s behind (the most held: {row['held_s']:.1f} s), nothing dropped")


def store_stats(svc: EngineService) -> dict | None:
    """The engine's store listener's counts (service/store/listener.py) and its backlog; None without a store."""
    listener = svc.fanout.listener("store")
    if listener is None:
        return None
    return {**{k: int(v) for k, v in listener.stats.items()}, "backlog_cycles": listener.backlog}


def store_waiting(svc: EngineService) -> dict:
    """Cycles kept for a store that is down (the store listener's backlog: 'degraded' while any wait) and lost."""
    listener = svc.fanout.listener("store")
    if listener is None:
        return {"store_waiting_cycles": 0, "store_lost_cycles": 0}
    return {"store_waiting_cycles": listener.backlog, "store_lost_cycles": int(listener.stats["lost_cycles"])}


async def service(request: Request, engine_id: EngineId) -> EngineService:
    """The engine named in the path (404 naming the known ones; the pattern gives 422 before this). A coroutine: a
    dict lookup, run on the event loop; as a plain function FastAPI ran it on a worker thread, one more hand-over
    per request."""
    engines = request.app.state.services
    if engine_id not in engines:
        raise HTTPException(404, f"no engine '{engine_id}'; known: {', '.join(sorted(engines))}")
    return engines[engine_id]


def authorised(request: Request, authorization: Annotated[str | None, Header()] = None) -> None:
    # request_guard checked it before the body was read; kept here so each state-changing route says it needs it
    if not bearer_ok(authorization, request.app.state.token):
        raise HTTPException(401, UNAUTHORISED, headers={"WWW-Authenticate": "Bearer"})


Svc = Annotated[EngineService, Depends(service)]


def _dashboard_files(root: FilePath) -> dict[str, FilePath]:
    """index.html and every file under static/, by their relative names (symlinks out of the folder are left out)."""
    if not root.is_dir():
        return {}
    base = root.resolve()
    out = {}
    for p in [root / "index.html", *sorted((root / "static").rglob("*"))]:
        real = p.resolve()
        if p.is_file() and real.is_relative_to(base):
            out[p.relative_to(root).as_posix()] = real
    return out
