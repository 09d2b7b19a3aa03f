"""The TDC window's fit remembered by everything it reads, for an offline caller that reads one log's pressure again
and again (the discrepancy workflow runs the pipeline over one log ~50 times, each with one candidate effect more, and
most candidates leave the pressure and the engine's geometry as they were).

    memo = TdcFitMemo()                                  # made by the caller, handed to each run (never a global)
    estimate = memo.fit(pressure, angle, spec, speed, operator=operator)   # tdc_from_pressure's answer

Why: the window's fit (core.monitor.calibration.tdc.tdc_from_pressure, ~8 ms a cylinder warm) was ~10 % of a healthy
k9k discover's time, and 136 of its 212 fits read a pressure, grid, speed and spec that an earlier fit of the same
discover had read (k9k 2500 rpm / 0.8, seed 5, 84 cycles; design note 113). The fit is a pure function of its
arguments, so the same arguments give the same estimate.

The key is everything the fit depends on, by content: the pressure's and the grid's values as float64 (with their
shapes), the speed, the smoothing operator's step (``smoothing(step)`` makes it, a pure function of the step), and the
whole EngineSpec pickled (~5 kB, ~0.5 ms: the fit reads the kinematics, the cylinder's sizes and the combustion's
angles and temperature; a key of those fields alone would go stale the day the fit reads another one). Bounded, the
least recently used answer dropped first; the serving path does not use it (its windows never repeat). Each answer
is given its own copy of the estimate's ``evidence`` (a dict), so a caller that writes into it never changes what
the memo answers next. A fit that raises is not kept: it raises again.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import pickle
from collections import OrderedDict

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.calibration.tdc import TdcEstimate, tdc_from_pressure
from frictionwatch.core.monitor.calibration.tdc_smoothing import Smoothing

MEMO_SIZE = 256  # fits kept: a discover's distinct fits (76 of 212 above) several times over, ~2 kB of key each


def _digest(a: np.ndarray) -> tuple:
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a.shape, hashlib.sha256(a.tobytes()).hexdigest()


def fit_key(pressure: np.ndarray, angle: np.ndarray, spec: EngineSpec, speed: float,
            operator: Smoothing | None = None) -> tuple:
    """The memo's key of one fit: its arguments by content (module doc)."""
    return (_digest(pressure), _digest(angle), float(speed), None if operator is None else float(operator.step),
            hashlib.sha256(pickle.dumps(spec, protocol=5)).hexdigest())


class TdcFitMemo:
    """tdc_from_pressure's answers by their arguments' content, at most ``size`` of them; ``hits`` and ``misses``
    count the answers given from the memo and fitted afresh."""

    def __init__(self, size: int = MEMO_SIZE):
        if size < 1:
            raise ValueError(f"a memo of {size} fits")
        self.size = size
        self.hits = 0
        self.misses = 0
        self._fits: OrderedDict[tuple, TdcEstimate] = OrderedDict()

    def fit(self, pressure: np.ndarray, angle: np.ndarray, spec: EngineSpec, speed: float,
            operator: Smoothing | None = None) -> TdcEstimate:
        """``tdc_from_pressure(pressure, angle, spec, speed, operator=operator)``, from the memo where the same
        arguments were fitted before."""
        # the key is taken before the fit, so a caller's later write to its arrays cannot change what an entry
        # answers; the fit is given the caller's arrays as they are (a copy's other layout could round a sum otherwise)
        key = fit_key(pressure, angle, spec, speed, operator)
        estimate = self._fits.get(key)
        if estimate is None:
            estimate = tdc_from_pressure(pressure, angle, spec, speed, operator=operator)
            self.misses += 1
            self._fits[key] = estimate
            if len(self._fits) > self.size:
                self._fits.popitem(last=False)
        else:
            self.hits += 1
            self._fits.move_to_end(key)
        return dataclasses.replace(estimate, evidence=copy.deepcopy(estimate.evidence))


__all__ = ["MEMO_SIZE", "TdcFitMemo", "fit_key"]
