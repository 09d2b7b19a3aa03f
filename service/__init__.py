"""Wiring: the per-engine pipeline, the CLI (and the HTTP service that follows).

alerts.py (AlertEngine: per-cycle alert decisions with hysteresis), alert_baseline.py (the commissioning baseline),
alert_rules.py (the hysteresis latch and the leak statistics): decision logic on CycleResults, no physics.

One engine's pipeline is one thread of small dense linear algebra (47 x 47): multi-threaded BLAS only adds
contention on a small box (measured: eigh/pinv 0.15 ms single-threaded vs 0.7-1.7 ms with OpenBLAS threading on 2
loaded cores), so pin it to one thread unless the operator says otherwise. This must run before numpy is imported.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
