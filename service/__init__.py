"""Wiring: the per-engine pipeline, the CLI and the HTTP service.

The service (`frictionwatch serve`, serve.py): engine_service.py (one engine: live.LiveSession + its alert engine +
the fan-out), listeners.py (the fan-out after python-can's Notifier: a bounded queue and a thread per listener; the
API's LatestState and the SSE broadcaster), api.py (FastAPI routes), api_models.py (the contract's JSON shapes),
api_views.py (results -> those shapes, statuses from core.monitor.report.figure_status), metrics.py (Prometheus),
security.py (bind check, token, engine ids).

alerts.py (AlertEngine: per-cycle alert decisions with hysteresis), alert_rules.py (one class per alert statistic),
alert_interface.py (what the engine and its rules exchange, the hysteresis latch, the leak statistics),
alert_config.py (the thresholds), alert_baseline.py (the commissioning baseline): decision logic on CycleResults,
no physics.

One engine's pipeline is one thread of small dense linear algebra (47 x 47): multi-threaded BLAS only adds
contention on a small box (measured: eigh/pinv 0.15 ms single-threaded vs 0.7-1.7 ms with OpenBLAS threading on 2
loaded cores), so pin it to one thread unless the operator says otherwise. This must run before numpy is imported.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
