"""Benches and accuracy runs (``python -m bench.<name>``; ``make bench`` runs the speed targets, bench/run.py).

One BLAS thread, as serve runs (service/__init__.py) and the tests (tests/conftest.py), unless the caller's
environment says otherwise. This package's __init__ runs before any bench module imports numpy, so every bench gets
it: with OpenBLAS's own threads the monitor's 47 x 47 LAPACK calls (dpotri in the posterior and the pull check) wait
spinning for a worker thread that a loaded box does not schedule. ``bench.ring_condition healthy --engine
genset-v20`` spent 127-135 ms of CPU a cycle in the monitor that way against 2.0-2.3 ms with one thread, plus as
much again in the worker, growing with the box's load, not with the cycles (design note 89).
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
