"""One numba call for the edges of a complete cycle window (drivers/assembly/cycles.py ``_advance_epoch``).

From the verified edges of the window (a run of the mirrored tooth-tick column) it gives in one pass what the
assembler built with a dozen numpy calls: the edge ticks, their epoch positions and wheel indices, their nominal
crank angles and the timer ticks at the grid angles (``drivers.assembly.resample.pchip_eval_kernel`` through the
edges). The numpy reference is ``cycle_edges_reference`` in tests/drivers/test_cycle_kernels.py.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from frictionwatch.drivers.assembly.resample import pchip_eval_kernel

_DEG = math.pi / 180.0  # np.radians(x) is x * (pi / 180)


@numba.njit(cache=True)
def cycle_edges(col, i0, m, o0, n, t, shift, a0_deg, grid, ticks, pos, index, theta, t_grid):
    """Edges col[i0 : i0 + m] (int64 ticks) of a window whose first edge has tooth ordinal o0 (wheel of n positions,
    t teeth): ticks, epoch positions ``(o // t) n + o % t``, wheel indices ``pos % n``, nominal angles
    ``radians(a0_deg + (pos + shift) 360 / n)`` [rad] and the ticks at the ``grid`` angles (monotone cubic through
    the edges, relative to the first edge) into the given arrays."""
    step = 360.0 / n
    for q in range(m):
        ticks[q] = col[i0 + q]
        o = o0 + q
        p = (o // t) * n + o % t
        pos[q] = p
        index[q] = p % n
        theta[q] = (a0_deg + (p + shift) * step) * _DEG
    rel = np.empty(m)
    for q in range(m):
        rel[q] = float(ticks[q] - ticks[0])
    pchip_eval_kernel(theta, rel, grid, t_grid)
    t0 = float(ticks[0])
    for i in range(grid.shape[0]):
        t_grid[i] += t0
