"""What every request passes before a route sees it (issue 28 item 6): the token before the body, a body-size limit,
and error replies that never echo the input.

    app.add_middleware(RequestGuard, token=lambda: app.state.token, max_body_bytes=MAX_BODY_BYTES)
    app.add_exception_handler(RequestValidationError, validation_error)

Every method other than GET, HEAD and OPTIONS is a state change (acknowledge, baseline, a discrepancy job) and needs
``Authorization: Bearer <token>``: the guard checks it from the headers alone, so a client without the token cannot
make the server read, let alone parse, a body (401). A body is read by the guard up to ``max_body_bytes`` (a
declared Content-Length past it is refused before reading; a chunked body is counted as it arrives) and handed to
the route: past the limit, 413. A 422 says where and what in one line (FastAPI's default reply carries the input
back: a 70 kB id gave a 70 kB reply).
"""

from __future__ import annotations

import json
from collections.abc import Callable

from fastapi import Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from frictionwatch.service.security import bearer_ok
from starlette.types import ASGIApp, Message, Receive, Scope, Send

MAX_BODY_BYTES = 16_384  # the largest body the API takes is a small JSON object (acknowledge's name, a job's options)
MAX_ERROR_CHARS = 200  # a validation message is cut here, whatever a validator put in it
READ_ONLY = frozenset({"GET", "HEAD", "OPTIONS"})
UNAUTHORISED = "this change needs 'Authorization: Bearer <token>' (the serve --token-file)"


async def _reply(send: Send, status: int, detail: str, headers: dict[str, str] | None = None) -> None:
    body = json.dumps({"detail": detail}).encode()
    raw = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    raw += [(k.lower().encode(), v.encode()) for k, v in (headers or {}).items()]
    await send({"type": "http.response.start", "status": status, "headers": raw})
    await send({"type": "http.response.body", "body": body})


class RequestGuard:
    """Pure ASGI middleware (see the module docstring); ``token`` is read per request (the app's state)."""

    def __init__(self, app: ASGIApp, token: Callable[[], str | None], max_body_bytes: int = MAX_BODY_BYTES) -> None:
        self.app, self.token, self.max_body = app, token, max_body_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] in READ_ONLY:
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        if not bearer_ok(headers.get("authorization"), self.token()):
            await _reply(send, 401, UNAUTHORISED, {"WWW-Authenticate": "Bearer"})
            return
        declared = headers.get("content-length", "")
        if declared.isdigit() and int(declared) > self.max_body:
            await _reply(send, 413, f"the body is larger than {self.max_body} bytes")
            return
        chunks, size = [], 0
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                return
            chunks.append(message.get("body", b""))
            size += len(chunks[-1])
            if size > self.max_body:
                await _reply(send, 413, f"the body is larger than {self.max_body} bytes")
                return
            if not message.get("more_body", False):
                break
        body, sent = b"".join(chunks), False

        async def replay() -> Message:
            nonlocal sent
            if not sent:
                sent = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()  # after the body: the disconnect, when it comes

        await self.app(scope, replay, send)


def validation_error(request: Request, exc: Exception) -> JSONResponse:
    """422 in one line: where (query, path, body) and what was expected, never the value that was sent."""
    errors = exc.errors() if isinstance(exc, RequestValidationError) else []
    parts = []
    for err in errors[:3]:
        where = ".".join(str(p) for p in err.get("loc", ()))
        parts.append(f"{where}: {err.get('msg', 'invalid')}")
    detail = "; ".join(parts) or "invalid request"
    if len(detail) > MAX_ERROR_CHARS:
        detail = detail[:MAX_ERROR_CHARS - 3] + "..."
    return JSONResponse({"detail": detail}, status_code=422)
