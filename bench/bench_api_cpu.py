"""Server CPU per API request, in process (issue 28 item 2): no network, no client process. The demo log looped at
full speed until ``--cycles`` results are held (one engine, stopped then, so nothing else runs), the app made over it
(create_app, manage=False) and each route of bench_service_plant's mix called ``--n`` times straight through the ASGI
app (a minimal scope/receive/send on one event loop; sync routes run on anyio's worker threads as under uvicorn). The
figure is the process's CPU time (all threads) per request, the harness's own cost included (a few us).

    .venv/bin/python -m bench.bench_api_cpu [--cycles 5000] [--n 400] [--profile ROUTE]

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


async def per_route(app, routes: list[str], n: int) -> list[dict]:
    rows = []
    for path in routes:
        status, body = await call(app, path)  # warm: the first call builds the middleware stack, imports...
        t = time.process_time()
        for _ in range(n):
            await call(app, path)
        rows.append({"route": path, "status": status, "bytes": len(body),
                     "cpu_us": 1e6 * (time.process_time() - t) / n})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=5000)
    ap.add_argument("--n", type=int, default=400)
    ap.add_argument("--profile", action="append", default=[], help="a route to profile (cProfile, top 30 by own time)")
    args = ap.parse_args()
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
    rows = asyncio.run(per_route(app, routes, args.n))
    print(json.dumps({"cycles_held": svc.state.sums.count, "loadavg": os.getloadavg(), "routes": rows}, indent=1))


if __name__ == "__main__":
    main()
