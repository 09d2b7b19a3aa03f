"""The listening socket serve binds (service.serve._bind): asyncio sets TCP_NODELAY on an accepted connection only
where the socket's proto is IPPROTO_TCP. A listener made with proto 0 left Nagle on, and every reply on a kept-alive
connection waited for the client's delayed ACK (44 ms per request, whatever the route)."""

from __future__ import annotations

import asyncio
import socket

import pytest
from frictionwatch.service.serve import _bind


async def _nodelay_of_an_accepted_connection(listener: socket.socket) -> int:
    seen: asyncio.Future = asyncio.get_running_loop().create_future()

    class Probe(asyncio.Protocol):
        def connection_made(self, transport: asyncio.BaseTransport) -> None:
            conn = transport.get_extra_info("socket")
            seen.set_result(conn.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY))
            transport.close()

    server = await asyncio.get_running_loop().create_server(Probe, sock=listener)  # as uvicorn serves it
    async with server:
        _, writer = await asyncio.open_connection(*listener.getsockname()[:2])
        try:
            return await asyncio.wait_for(seen, 5)
        finally:
            writer.close()


@pytest.mark.parametrize("loop", ["asyncio", "uvloop"])  # serve's event loop where installed (serve.http_stack)
@pytest.mark.parametrize("host", ["127.0.0.1", "::1"])
def test_accepted_connections_get_tcp_nodelay(host: str, loop: str) -> None:
    factory = pytest.importorskip("uvloop").new_event_loop if loop == "uvloop" else None
    try:
        listener = _bind(host, 0)
    except OSError as exc:  # a machine without IPv6 on loopback
        pytest.skip(str(exc))
    with asyncio.Runner(loop_factory=factory) as runner:
        assert runner.run(_nodelay_of_an_accepted_connection(listener)) != 0
