"""One BLAS thread per test process, as the service runs (service/__init__.py): two xdist workers on a 2-core box
each with OpenBLAS's own threads spinning doubled the suite's time (test_condition + test_gain_watch with -n 2:
54 s against 25 s single-threaded). Set before any test module imports numpy; `make test` sets it for the whole
process tree too."""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
