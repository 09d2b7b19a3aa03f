"""Server CPU per request of two checkouts' API over HTTP, side by side (issue 28 item 2): A (another checkout, by
its package path) and B (this one), each in a child process serving one demo engine filled to ``--cycles`` cycles
on serve's HTTP stack (httptools on uvloop), the mix's routes sent on one kept-alive connection, the sides alternated
A B, B A, ... for ``--rounds`` rounds; the figure is each child's CPU (all threads, /proc) per request.

A new cycle before every request (``--fresh``, the default): the child's app is wrapped so that GET /_bench/feed
makes its engine's API state see one more cycle (bench_api_cpu.feeder), so the per-cycle caches miss as they do in
the live mix (a genset makes 2-3 cycles between two requests of one route). Each round also times the feeds alone,
and a route's figure is (its feeds and requests) - (as many feeds alone): what the requests cost.

    PYTHONPATH= .venv/bin/python -m bench.bench_api_ab --against /tmp/base-pkg [--cycles 1000] [--n 300]

``--against``: a folder holding ``frictionwatch`` (a link to the other checkout's root), put first on the child's
PYTHONPATH, as the editable install maps this checkout. Quote ``uptime``; the ratio B/A per round is the figure.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys

from bench.bench_service_plant import mix_routes

FEED = "/_bench/feed"


def child(cycles: int) -> None:
    import socket
    import threading

    import uvicorn
    from frictionwatch.service.api import create_app

    from bench.bench_api_cpu import feeder
    from bench.bench_window_request import filled_engine

    svc = filled_engine(cycles)
    app = create_app([svc], manage=False)
    feed = feeder(svc)

    async def wrapped(scope, receive, send):  # noqa: ANN001 - an ASGI app
        if scope["type"] == "http" and scope["path"] == FEED:
            feed()
            await send({"type": "http.response.start", "status": 204, "headers": []})
            await send({"type": "http.response.body", "body": b""})
            return
        await app(scope, receive, send)

    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.bind(("127.0.0.1", 0))
    sock.listen(128)
    server = uvicorn.Server(uvicorn.Config(wrapped, http="httptools", loop="uvloop", lifespan="off",
                                           log_level="warning", access_log=False))
    threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True).start()
    print(sock.getsockname()[1], flush=True)
    sys.stdin.read()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--against", help="A's package folder (holds frictionwatch -> the other checkout)")
    ap.add_argument("--cycles", type=int, default=1000)
    ap.add_argument("--n", type=int, default=300)
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--no-fresh", action="store_true")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.cycles)
        return
    import httpx

    from bench.bench_service_load import cpu_s

    env_b = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env_a = {**env_b, "PYTHONPATH": args.against}
    cmd = [sys.executable, "-m", "bench.bench_api_ab", "--child", "--cycles", str(args.cycles)]
    kids = {side: subprocess.Popen(cmd, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            for side, env in (("A", env_a), ("B", env_b))}
    try:
        clients = {s: httpx.Client(base_url=f"http://127.0.0.1:{int(k.stdout.readline())}", timeout=30)
                   for s, k in kids.items()}
        routes = list(dict.fromkeys(mix_routes(["demo"])))
        for c in clients.values():
            for path in routes:
                c.get(path)
        fresh = not args.no_fresh
        out: dict[str, list[dict]] = {"A": [], "B": []}
        for r in range(args.rounds):
            for side in ("A", "B") if r % 2 == 0 else ("B", "A"):
                c, pid = clients[side], kids[side].pid
                t = cpu_s(pid)
                for _ in range(args.n):
                    if fresh:
                        c.get(FEED)
                feeds = cpu_s(pid) - t
                row = {}
                for path in routes:
                    t = cpu_s(pid)
                    for _ in range(args.n):
                        if fresh:
                            c.get(FEED)
                        c.get(path)
                    row[path] = 1e6 * (cpu_s(pid) - t - feeds) / args.n
                out[side].append(row)
        sent = mix_routes([f"e{i}" for i in range(4)])
        keyed = [re.sub(r"/engines/e[0-9]+/", "/engines/demo/", p) for p in sent]
        mix = {s: [sum(row[p] for p in keyed) / len(keyed) for row in rows] for s, rows in out.items()}
        med = {s: {p: sorted(row[p] for row in rows)[len(rows) // 2] for p in routes} for s, rows in out.items()}
        print(json.dumps({"fresh": fresh, "n": args.n, "loadavg": os.getloadavg(),
                          "mix_us_per_request": mix, "ratio_A_over_B": [a / b for a, b in zip(mix["A"], mix["B"])],
                          "median_us_by_route": med}, indent=1))
    finally:
        for k in kids.values():
            k.stdin.close()
            k.kill()


if __name__ == "__main__":
    main()
