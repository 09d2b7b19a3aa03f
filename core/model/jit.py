"""numba options shared by the hot helpers of the plant simulator and the loss-term kernels.

``BORROWING``: compiled without numba's reference counting (the private but long-standing ``_nrt=False`` flag). A
compiled function that receives arrays increments and decrements an atomic reference count per array on entry and
exit; the plant's RK4 right-hand side passes ~30 arrays (its records and work arrays) to its helpers four times a
step, plus the library's kernels per cylinder term: on genset-v20 that bookkeeping was ~58 % of the simulator's CPU
time (perf, 2331c52). A function compiled this way only *borrows* the arrays its caller owns (the caller, compiled
normally, holds them for the duration of the call), so it must not allocate an array, keep one, or return one; the
arithmetic is unchanged, so its results are bit-identical.
"""

from __future__ import annotations

BORROWING = {"cache": True, "_nrt": False}

__all__ = ["BORROWING"]
