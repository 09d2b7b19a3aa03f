"""Three small kernels, a call chain, and one with an explicit signature, for tests/test_kernel_manifest.py (not
cached: each test process compiles them afresh)."""

import numba


@numba.njit
def leaf(x):
    return x + 1


@numba.njit
def middle(x):
    return leaf(x) * 2


@numba.njit
def top(x):
    return middle(x) - 3


@numba.njit("int64(int64)")
def explicit(x):
    return x * 5
