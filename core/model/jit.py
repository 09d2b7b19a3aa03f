"""numba options shared by the hot helpers of the plant simulator and the loss-term kernels.

``BORROWING``: compiled without numba's reference counting (the private but long-standing ``_nrt=False`` flag). A
compiled function that receives arrays increments and decrements an atomic reference count per array on entry and
exit; the plant's RK4 right-hand side passes ~30 arrays (its records and work arrays) to its helpers four times a
step, plus the library's kernels per cylinder term: without that bookkeeping the genset-v20 kernel went from 27.5 to
21.7 ms of CPU per cycle (time.process_time, same run; perf had put more than half of the samples on the atomic add,
an over-count under sampling). A function compiled this way only *borrows* the arrays its caller owns (the caller, compiled
normally, holds them for the duration of the call), so it must not allocate an array, keep one, or return one; the
arithmetic is unchanged, so its results are bit-identical.
"""

from __future__ import annotations

import math

from llvmlite import ir
from numba import config, types
from numba.core import cgutils
from numba.extending import intrinsic

BORROWING = {"cache": True, "_nrt": False}

__all__ = ["BORROWING", "sincos"]


@intrinsic
def sincos(typingctx, x):
    """(sin x, cos x) from one call of the C library's ``sincos`` (one argument reduction for both: the plant takes
    both of every cylinder's angle four times a step). glibc's sincos gives the very numbers of its sin and cos
    (tests/core/test_jit.py checks it against np.sin, np.cos on this machine's library)."""
    if not isinstance(x, types.Float):
        return None
    sig = types.UniTuple(types.float64, 2)(types.float64)

    def codegen(context, builder, signature, args):
        dbl = ir.DoubleType()
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [dbl, dbl.as_pointer(),
                                                                                             dbl.as_pointer()]), "sincos")
        s, c = cgutils.alloca_once(builder, dbl), cgutils.alloca_once(builder, dbl)
        builder.call(fn, [context.cast(builder, args[0], signature.args[0], types.float64), s, c])
        return context.make_tuple(builder, signature.return_type, [builder.load(s), builder.load(c)])

    return sig, codegen


if config.DISABLE_JIT:  # the kernels run as Python (tests with NUMBA_DISABLE_JIT=1): an intrinsic cannot
    def sincos(x):  # noqa: F811
        return math.sin(x), math.cos(x)
