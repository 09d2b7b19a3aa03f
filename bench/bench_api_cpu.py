"""Server CPU per API request, in process (issue 28 item 2): no network, no client process. The demo log looped at
full speed until ``--cycles`` results are held (one engine, stopped then, so nothing else runs), the app made over it
(create_app, manage=False) and each route of bench_service_plant's mix called ``--n`` times straight through the ASGI
app (a minimal scope/receive/send on one event loop; sync routes run on anyio's worker threads as under uvicorn). The
figure is the process's CPU time (all threads) per request, the harness's own cost included (a few us).

    .venv/bin/python -m bench.bench_api_cpu [--cycles 5000] [--n 400] [--profile ROUTE]
    .venv/bin/python -m bench.bench_api_cpu --over-http [--rounds 4]   # uvicorn's HTTP stacks, over a socket

``--over-http``: the same app served over loopback by uvicorn in a child process, once per HTTP stack (h11 on
asyncio, httptools on uvloop: two servers of the one app, one thread each), and the mix's routes sent in turn on one
kept-alive connection, the stacks alternated for ``--rounds`` rounds; the figure is the child's CPU (all threads,
/proc) per request, so it holds uvicorn's parsing and writing as well as the app's (the in-process figure has only
the app's).

Ratios are what to quote on a shared box; absolute figures only with `uptime`.
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import json
import os
import pstats
import time

from frictionwatch.service.api import create_app

from bench.bench_service_plant import mix_routes
from bench.bench_window_request import filled_engine


async def call(app, path: str) -> tuple[int, bytes]:
    """One GET through the ASGI app: (status, body)."""
    route, _, query = path.partition("?")
    scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1", "method": "GET", "scheme": "http",
             "path": route, "raw_path": route.encode(), "query_string": query.encode(), "root_path": "",
             "headers": [(b"host", b"bench")], "client": ("127.0.0.1", 1), "server": ("bench", 80)}
    out = {"status": 0, "body": []}

    async def receive() -> dict:
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message: dict) -> None:
        if message["type"] == "http.response.start":
            out["status"] = message["status"]
        elif message["type"] == "http.response.body":
            out["body"].append(message.get("body", b""))

    await app(scope, receive, send)
    return out["status"], b"".join(out["body"])


async def per_route(app, routes: list[str], n: int, fresh=None) -> list[dict]:
    """Each route ``n`` times; ``fresh``: called (untimed) before each request, a new cycle for the engine (the
    per-cycle caches miss as in the live mix, where a genset makes 2-3 cycles between two requests of one route)."""
    rows = []
    for path in routes:
        status, body = await call(app, path)  # warm: the first call builds the middleware stack, imports...
        spent = 0.0
        for _ in range(n):
            if fresh is not None:
                fresh()
            t = time.process_time()
            await call(app, path)
            spent += time.process_time() - t
        rows.append({"route": path, "status": status, "bytes": len(body), "cpu_us": 1e6 * spent / n})
    return rows


def feeder(svc):
    """A callable that makes the engine's API state see one more cycle (the newest whole result again, numbered
    next), as its listener thread does: the per-cycle caches keyed by the newest result then miss."""
    import dataclasses
    import itertools

    from frictionwatch.service.listeners import ServiceEvent

    base = svc.state.newest
    numbers = itertools.count(int(base.index) + 1)

    def feed() -> None:
        result = dataclasses.replace(base, index=next(numbers))
        svc.state.on_message_received(ServiceEvent(svc.engine_id, result, time.monotonic()))

    return feed


def mix_weighted(rows: list[dict], engines: int = 4) -> float:
    """us a request of bench_service_plant's mix on ``engines`` engines, from one engine's per-route rows."""
    sent = mix_routes([f"e{i}" for i in range(engines)])
    cost = {r["route"].replace("/demo/", "/{id}/"): r["cpu_us"] for r in rows}
    import re as _re
    return sum(cost[_re.sub(r"/engines/e[0-9]+/", "/engines/{id}/", p)] for p in sent) / len(sent)


STACKS = {"h11": ("h11", "asyncio"), "httptools": ("httptools", "uvloop")}


def serve_stacks(cycles: int) -> None:
    """The child of ``--over-http``: one filled engine's app served by one uvicorn server per stack (each on its
    own thread and event loop); prints each stack's port, then serves until killed."""
    import socket
    import sys
    import threading

    import uvicorn

    app = create_app([filled_engine(cycles)], manage=False)
    for name, (http, loop) in STACKS.items():
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)  # serve._bind: TCP_NODELAY
        sock.bind(("127.0.0.1", 0))
        sock.listen(128)
        server = uvicorn.Server(uvicorn.Config(app, http=http, loop=loop, lifespan="off", log_level="warning"))
        threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True, name=name).start()
        print(name, sock.getsockname()[1], flush=True)
    sys.stdin.read()  # until the parent closes the pipe


def over_http(cycles: int, rounds: int, n: int) -> dict:
    import subprocess
    import sys

    import httpx

    from bench.bench_service_load import cpu_s

    child = subprocess.Popen([sys.executable, "-m", "bench.bench_api_cpu", "--serve-stacks", "--cycles", str(cycles)],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        ports = dict(child.stdout.readline().split() for _ in STACKS)
        routes = [p for p in dict.fromkeys(mix_routes(["demo"])) if "speed?cycles=5000" not in p]  # not the 429s
        clients = {name: httpx.Client(base_url=f"http://127.0.0.1:{port}") for name, port in ports.items()}
        for client in clients.values():  # warm: each route once
            for path in routes:
                assert client.get(path).status_code == 200, path
        runs: dict[str, list[float]] = {name: [] for name in clients}
        walls: dict[str, list[float]] = {name: [] for name in clients}
        for r in range(rounds):
            for name in (list(clients) if r % 2 == 0 else list(clients)[::-1]):  # A B, then B A
                t, w = cpu_s(child.pid), time.perf_counter()
                for _ in range(n):
                    for path in routes:
                        clients[name].get(path)
                runs[name].append(1e6 * (cpu_s(child.pid) - t) / (n * len(routes)))
                walls[name].append(1e6 * (time.perf_counter() - w) / (n * len(routes)))
        return {"routes": routes, "requests_per_run": n * len(routes),
                "server_cpu_us_per_request": runs,
                "round_trip_us_per_request": walls,  # one at a time: a delayed ACK (no TCP_NODELAY) shows as ~40 ms
                "ratio_h11_over_httptools": [a / b for a, b in zip(runs["h11"], runs["httptools"])]}
    finally:
        child.stdin.close()
        child.kill()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=5000)
    ap.add_argument("--n", type=int, default=400)
    ap.add_argument("--profile", action="append", default=[], help="a route to profile (cProfile, top 30 by own time)")
    ap.add_argument("--over-http", action="store_true", help="server CPU a request over uvicorn's HTTP stacks")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--serve-stacks", action="store_true", help=argparse.SUPPRESS)  # --over-http's child
    ap.add_argument("--fresh", action="store_true", help="a new cycle before each request: the caches miss")
    args = ap.parse_args()
    if args.serve_stacks:
        serve_stacks(args.cycles)
        return
    if args.over_http:
        print(json.dumps({**over_http(args.cycles, args.rounds, args.n // 4), "loadavg": os.getloadavg()}, indent=1))
        return
    svc = filled_engine(args.cycles)
    app = create_app([svc], manage=False)
    routes = list(dict.fromkeys(mix_routes(["demo"])))
    for path in args.profile:
        asyncio.run(call(app, path))
        prof = cProfile.Profile()
        prof.enable()
        asyncio.run(per_route(app, [path], args.n))
        prof.disable()
        print("==", path)
        pstats.Stats(prof).sort_stats("tottime").print_stats(25)
    if args.profile:
        return
    rows = asyncio.run(per_route(app, routes, args.n, feeder(svc) if args.fresh else None))
    print(json.dumps({"cycles_held": svc.state.sums.count, "fresh": args.fresh, "loadavg": os.getloadavg(),
                      "mix_us_per_request": mix_weighted(rows), "routes": rows}, indent=1))


if __name__ == "__main__":
    main()
