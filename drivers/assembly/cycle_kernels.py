"""One numba call for the edges of a complete cycle window (drivers/assembly/cycles.py ``_advance_epoch``).

From the verified edges of the window (a run of the mirrored tooth-tick column) it gives in one pass what the
assembler built with a dozen numpy calls: the edge ticks, their epoch positions and wheel indices, their nominal
crank angles (the timer ticks at the grid angles follow by scipy's PCHIP, ``drivers.assembly.cycle_parts.grid_times``,
outside the kernel). The numpy reference is ``cycle_edges_reference`` in tests/drivers/test_cycle_kernels.py.
"""

from __future__ import annotations

import math

import numba

_DEG = math.pi / 180.0  # np.radians(x) is x * (pi / 180)


@numba.njit(cache=True)
def cycle_edges(col, i0, m, o0, n, t, shift, a0_deg, ticks, pos, index, theta):
    """Edges col[i0 : i0 + m] (int64 ticks) of a window whose first edge has tooth ordinal o0 (wheel of n positions,
    t teeth): ticks, epoch positions ``(o // t) n + o % t``, wheel indices ``pos % n``, nominal angles
    ``radians(a0_deg + (pos + shift) 360 / n)`` [rad] into the given arrays."""
    step = 360.0 / n
    for q in range(m):
        ticks[q] = col[i0 + q]
        o = o0 + q
        p = (o // t) * n + o % t
        pos[q] = p
        index[q] = p % n
        theta[q] = (a0_deg + (p + shift) * step) * _DEG
