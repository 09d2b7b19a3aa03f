"""The container's health check (Dockerfile HEALTHCHECK): ``python -m frictionwatch.service.healthcheck [URL]``.

Exit 0 (healthy) while the service answers GET /api/v1/health, whether 'ok', 'starting' (its warm-up compiles the
kernels) or 'degraded'; exit 1 when it does not
answer, answers something else, or an engine's every thread has ended while its sources still run. One line on
stdout says why (``docker inspect`` keeps it).

Why 'degraded' is healthy for the container: degraded means an engine lags (its data wait > 2 s, or its bounded
queue dropped recently), its newest cycle is older than 10 s, or it has no cycle yet (the kernels compile on a
first start). The process is alive and serving the API, the dashboard and the store, and /health says what is
wrong; a restart would cure none of these (it throws the queue away, loses the smoothed estimates' state and starts
lagging again) and an orchestrator restarting on 'unhealthy' would turn a slow plant into a restart loop. What a
restart can cure is a wedged process (no answer) or a dead engine: those are unhealthy.
"""

from __future__ import annotations

import json
import sys
import urllib.request

URL = "http://127.0.0.1:8080/api/v1/health"
TIMEOUT_S = 4.0  # under the HEALTHCHECK's --timeout (5 s)


def verdict(doc: object) -> tuple[bool, str]:
    """(healthy, why) from /health's reply (service/api_models.Health)."""
    if not isinstance(doc, dict) or doc.get("status") not in ("ok", "degraded", "starting"):
        return False, "unhealthy: /health did not answer with a status"
    engines = doc.get("engines") if isinstance(doc.get("engines"), list) else []
    dead = [str(e.get("engine_id")) for e in engines
            if isinstance(e, dict) and e.get("running") is False and e.get("sources_ended") is False]
    if dead:
        return False, f"unhealthy: engine {', '.join(dead)} stopped while its sources run"
    lagging = [str(e.get("engine_id")) for e in engines if isinstance(e, dict) and e.get("behind")]
    if doc["status"] in ("ok", "starting"):  # starting: the warm-up compiles the kernels, or the monitor catches up
        # on what a board gave meanwhile (service/warmup.py, api.health_status)
        return True, f"healthy: {doc['status']}"
    return True, "healthy: degraded (see /api/v1/health)" + (f"; behind: {', '.join(lagging)}" if lagging else "")


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    url = args[0] if args else URL
    try:
        with urllib.request.urlopen(url, timeout=TIMEOUT_S) as reply:  # noqa: S310 - our own loopback URL
            doc = json.load(reply)
    except (OSError, ValueError) as exc:  # no answer, an HTTP error, a reply that is not JSON
        print(f"unhealthy: {url}: {type(exc).__name__}: {str(exc)[:200]}")
        return 1
    healthy, why = verdict(doc)
    print(why)
    return 0 if healthy else 1


if __name__ == "__main__":
    sys.exit(main())
