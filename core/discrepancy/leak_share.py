"""How much of a leak past the rings is gone by the compression reading: the share that sizes blow_by from the
compression deficit (pressure_channel.leak_size; design note 149).

A leak's mass_loss is the trapped mass lost from IVC to EVO; the pressure reads it as the compression deficit ~30 deg
before TDC (the ring indicators' ``compression_ratio``), by which time only a share of it is gone: the rest leaks
through combustion and expansion, where the pressure is highest. With the gas leaving through an orifice into the
crankcase (choked, or subsonic below the critical ratio) at T = p V / (m R), the mass flow goes as
sqrt(p m / V) psi(p_cc / p); with m about constant (a leak of a few tenths at most) the share lost by an angle is
the integral of sqrt(p / V) psi over the closed cycle up to it, over that up to EVO, read from the log's own mean
pressure trace. The deficit is then ~ LEAK_GAMMA x share x mass_loss (d ln p = gamma dm / m for the gas that stays).

Why: one factor for every engine (design note 97's BLOW_BY_PER_LN 5.06, tuned on k9k and maruti) read genset-v20's
12 % leaks 0.154 and 0.150 at seed 17 (its share 0.172 against k9k's 0.155 and maruti 1500's 0.123): the factor
each log needs ran 3.86-5.53 over the matrix points at seed 13 and this share explains all but +-3 % of it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.kinematics import kinematics
from frictionwatch.core.model.thermo import P_CRANKCASE
from frictionwatch.core.monitor.checks.ring_pressure import ring_windows
from frictionwatch.core.types import Cycle

# cp / cv of the charge at compression and expansion temperatures (600-1500 K: 1.30-1.37): the leak law's ratio
# and the deficit's d ln p = gamma dm / m; what this approximation misses is the tuned scale's (BLOW_BY_SHARE_SCALE)
LEAK_GAMMA = 1.35


def mean_pressure(cycles: Sequence[Cycle]) -> tuple[np.ndarray, np.ndarray]:
    """(n,) the cycles' crank grid [rad] and (z, n) each cylinder's mean absolute pressure [Pa] over them (NaN where
    a cylinder has no finite sample at an angle)."""
    if not cycles:
        raise ValueError("no cycles to read a mean pressure from")
    total = np.zeros(np.shape(cycles[0].pressure))
    count = np.zeros(total.shape)
    for c in cycles:  # summed in place: a 300-cycle genset-v20 log stacked would be ~70 MB
        p = np.asarray(c.pressure, dtype=np.float64)
        ok = np.isfinite(p)
        total += np.where(ok, p, 0.0)
        count += ok
    with np.errstate(invalid="ignore", divide="ignore"):  # a row without a sensor is NaN: leak_share leaves it out
        return np.asarray(cycles[0].grid, dtype=np.float64), np.where(count > 0, total / count, np.nan)


def flow_weight(p: np.ndarray, vol: np.ndarray) -> np.ndarray:
    """(n,) the leak's mass flow per unit trapped mass, up to a constant: sqrt(p / V) psi(P_CRANKCASE / p), psi the
    isentropic orifice function (choked at or below the critical ratio; 0 where p <= the crankcase's)."""
    g = LEAK_GAMMA
    pr = np.where(p > P_CRANKCASE, P_CRANKCASE / np.where(p > 0.0, p, 1.0), 1.0)
    crit = (2.0 / (g + 1.0)) ** (g / (g - 1.0))
    choked = math.sqrt(g) * (2.0 / (g + 1.0)) ** ((g + 1.0) / (2.0 * (g - 1.0)))
    sub = np.sqrt(np.maximum(2.0 * g / (g - 1.0) * (pr ** (2.0 / g) - pr ** ((g + 1.0) / g)), 0.0))
    psi = np.where(pr <= crit, choked, sub)
    return np.sqrt(np.maximum(p, 0.0) / vol) * psi


def leak_share(spec: EngineSpec, grid: np.ndarray, pressure: np.ndarray) -> float:
    """The share of a leak's IVC -> EVO loss gone by the compression reading (ring_windows' comp_end), the median
    over the cylinders with a full trace of each one's share from its own mean trace ``pressure`` (z, n) on ``grid``
    (cylinder 1's angle, 0-4 pi; each cylinder read around its own firing TDC); NaN when no cylinder has one."""
    cb = spec.combustion
    kin = np.asarray(spec.kinematics_params(), dtype=np.float64)
    ends = np.radians([cb.ivc_deg, ring_windows(spec).comp_end, cb.evo_deg])
    shares = []
    for k in range(spec.n_cyl):
        th = np.mod(grid - spec.firing_angles[k] + 2.0 * np.pi, 4.0 * np.pi) - 2.0 * np.pi  # [-360, 360) deg
        order = np.argsort(th)
        th, p = th[order], np.asarray(pressure[k], dtype=np.float64)[order]
        # the closed cycle and one sample beyond each end, so that the integral's ends are interpolated
        lo, hi = max(int(np.searchsorted(th, ends[0])) - 1, 0), int(np.searchsorted(th, ends[2])) + 1
        th, p = th[lo:hi], p[lo:hi]
        if th.size < 3 or th[0] > ends[0] or th[-1] < ends[2] or not np.all(np.isfinite(p)):
            continue
        x, _, _ = kinematics(th, kin)
        w = flow_weight(p, spec.clearance_volume + spec.piston_area * x)
        cum = np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(th))))
        at = np.interp(ends, th, cum)
        if at[2] > at[0]:
            shares.append(float((at[1] - at[0]) / (at[2] - at[0])))
    return float(np.median(shares)) if shares else math.nan


__all__ = ["LEAK_GAMMA", "flow_weight", "leak_share", "mean_pressure"]
