"""One BLAS thread per test process, as the service runs (service/__init__.py): two xdist workers on a 2-core box
each with OpenBLAS's own threads spinning doubled the suite's time (test_condition + test_gain_watch with -n 2:
54 s against 25 s single-threaded). Set before any test module imports numpy; `make test` sets it for the whole
process tree too."""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def pytest_collection_modifyitems(config, items):
    """The modules holding a test marked ``slow`` are collected first, each module's tests kept together and in
    order: `make test`'s two workers are dealt whole files in collection order (xdist --dist loadfile), so the
    suite's last files are short ones, not one worker finishing a 60-second file while the other waits."""
    slow = {item.nodeid.split("::")[0] for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.nodeid.split("::")[0] not in slow)  # stable: the order within each group kept
