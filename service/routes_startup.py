"""``GET /api/v1/startup``: what the service is doing before each engine's first cycle (service/startup.py), so the
dashboard can say "compiling the numerical kernels (first run only)" where the other routes still answer 503."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from fastapi import APIRouter
from frictionwatch.service.api_models import Startup
from frictionwatch.service.startup import STARTUP, StartupState


def startup_router(engines: Callable[[], Iterable[Any]], state: StartupState = STARTUP) -> APIRouter:
    """``engines``: the app's engine services (``engine_id``, ``cycles_ok``), read at each request."""
    router = APIRouter()

    @router.get("/api/v1/startup", response_model=Startup)
    def startup() -> dict:
        return state.document(engines())

    return router
