"""What each reported friction figure is: a measurement, a share, the prior, unresolved or withheld.

One function, ``friction_status``, decides it for the engine total and every cylinder from what a result already
holds (the resolved masks, the data gains, the accumulated weight, the Eq. 6 shares) and the flags that apply; add
a rule here, not in the printers. Every consumer (JSON, CSV, table) shows what it says.

    measured    from this engine's data: the engine total from the mean torque balance (a measured load) over the
                accumulated cycles; a cylinder's friction resolved from the speed signal (data gain >= the limit)
    share       a cylinder's share of the engine's measured friction in proportion to its indicated work (paper 000
                Eq. 6): a rule applied to the measured total, NOT a measurement of that cylinder
    prior       the engine model's prior (its preset friction, drawn toward the measured mean balance where there is
                one): nothing has been accumulated from the data yet
    unresolved  the data cannot give it (no load measurement, the split not separated yet); no value
    withheld    a flagged sensor fault affects it; no value

Flags are strings ``<kind>`` (the engine) or ``<kind>_cyl<k>`` (cylinder k, 1-based); ``split_flag`` parses them.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

STATUSES = ("measured", "share", "prior", "unresolved", "withheld")
_MEASURED, _SHARE, _UNRESOLVED, _WITHHELD = (STATUSES.index(s) for s in ("measured", "share", "unresolved", "withheld"))
# flag kinds that void the figures they touch (a sensor fault): a cylinder flag its cylinder, an engine flag all
WITHHOLDING_PREFIXES = ("sensor_",)
NO_LOAD = "no_load_measurement"
_CYL_FLAG = re.compile(r"^(?P<kind>.+)_cyl(?P<cyl>[1-9][0-9]*)$")


class Estimate(Protocol):
    """The part of ``core.monitor.report.results.FrictionEstimate`` the decision reads."""

    resolved: np.ndarray
    data_gain: np.ndarray
    friction_torque_mean: np.ndarray
    prior_friction_torque_mean: np.ndarray
    total_friction_torque: float
    weight: float
    source: str


@dataclass(frozen=True)
class FigureStatus:
    """status: one of STATUSES; reason: why it is not a measurement (None when measured); data_weight: the share
    (0..1) of what is known about the figure that came from the speed data rather than the priors and the equal
    share (a cylinder's FrictionEstimate.data_gain), None for the engine total (its data is the mean balance)."""

    status: str
    reason: str | None
    data_weight: float | None


class FrictionStatus:
    """The status of the engine total (``engine``) and of each cylinder's figure, compact: ``codes`` (z,) int64, each
    cylinder's status as its index in STATUSES; ``data_weight`` (z,) float, each cylinder's FigureStatus.data_weight
    with NaN where that is None. ``cylinders``, each cylinder's FigureStatus with the words of its reason, is made on
    first request: serve works out a status twice a cycle (its window row, its alert rules) and reads only the
    codes; the reasons' words were most of a call's time (~34 us a genset-v20 cycle; design note 100)."""

    __slots__ = ("engine", "codes", "data_weight", "_engine_faults", "_cyl_faults", "_pulled", "_cylinders")

    def __init__(self, engine: FigureStatus, codes: np.ndarray, data_weight: np.ndarray,
                 engine_faults: tuple[str, ...] = (), cyl_faults: dict[int, list[str]] | None = None,
                 pulled: np.ndarray | None = None) -> None:
        self.engine, self.codes, self.data_weight = engine, codes, data_weight
        self._engine_faults, self._cyl_faults, self._pulled = engine_faults, cyl_faults or {}, pulled
        self._cylinders: tuple[FigureStatus, ...] | None = None

    @property
    def cylinders(self) -> tuple[FigureStatus, ...]:
        if self._cylinders is None:
            self._cylinders = tuple(self._cylinder(k) for k in range(len(self.codes)))
        return self._cylinders

    def _cylinder(self, k: int) -> FigureStatus:
        """Cylinder k's FigureStatus, its reason in words (what ``friction_status`` decided, ``codes[k]``)."""
        status = STATUSES[int(self.codes[k])]
        w = float(self.data_weight[k])
        weight = w if math.isfinite(w) else None
        if status == "measured":
            return FigureStatus(status, None, weight)
        if status == "withheld":
            faults = [*self._engine_faults, *self._cyl_faults.get(k + 1, [])]
            return FigureStatus(status, "sensor fault flagged: " + ", ".join(faults), weight)
        if status == "share":
            shown = "n/a" if weight is None else f"{weight:.2f}"
            pulled = self._pulled is not None and bool(self._pulled[k])
            why = (f"the speed data lead this cylinder's figure further from its share than their own scatter "
                   f"allows (data weight {shown}): a repeated error of the engine model in the speed (the pull check)"
                   if pulled else
                   f"the speed data do not separate this cylinder from its siblings (data weight {shown})")
            return FigureStatus(status, why + ": the value is its share of the engine's measured friction in "
                                              "proportion to its indicated work, not a measurement of this cylinder",
                                weight)
        why = {"measured": "the data do not determine this cylinder's friction",
               "prior": "no cycle accumulated yet (the monitor's warm-up): nothing from the data for this "
                        "cylinder"}.get(self.engine.status, self.engine.reason)
        return FigureStatus(status, why, weight)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FrictionStatus):
            return NotImplemented
        return self.engine == other.engine and self.cylinders == other.cylinders

    __hash__ = None  # type: ignore[assignment]  # (as the frozen dataclass it was: its fields held a tuple of them)

    def __repr__(self) -> str:
        return f"FrictionStatus(engine={self.engine!r}, cylinders={self.cylinders!r})"


def split_flag(flag: str) -> tuple[str, int | None]:
    """``'misfire_cyl3'`` -> ``('misfire', 3)``; ``'no_load_measurement'`` -> ``('no_load_measurement', None)``."""
    m = _CYL_FLAG.match(flag)
    return (m["kind"], int(m["cyl"])) if m else (flag, None)


def withholds(kind: str) -> bool:
    return kind.startswith(WITHHOLDING_PREFIXES)


def friction_status(est: Estimate, active_flags: Iterable[str]) -> FrictionStatus:
    """The status of the engine total and of each cylinder's friction in ``est``, given the flags that apply to
    the data it stands for (``active_flags``: e.g. ``core.monitor.report.run_summary.active_flags``)."""
    z = int(np.shape(est.resolved)[0])
    engine_faults: list[str] = []
    cyl_faults: dict[int, list[str]] = {}
    no_load = False
    for flag in sorted(set(active_flags)):
        kind, cyl = split_flag(flag)
        if kind == NO_LOAD:
            no_load = True
        elif withholds(kind):
            (engine_faults if cyl is None else cyl_faults.setdefault(cyl, [])).append(flag)
    accumulated = est.weight > 0
    # unresolved before withheld: where nothing balances the indicated work there is no figure to withhold
    if no_load:
        engine = FigureStatus("unresolved", "no load measurement: nothing balances the indicated work (a measured "
                                            "load or a deceleration would), so the engine's friction is not known",
                              None)
    elif est.source != "data":  # nothing to balance the indicated work against
        engine = FigureStatus("unresolved", est.source.removeprefix("prior: "), None)
    elif engine_faults:
        engine = FigureStatus("withheld", "sensor fault flagged: " + ", ".join(engine_faults), None)
    elif not accumulated:
        engine = FigureStatus("prior", "no cycle accumulated yet (the monitor's warm-up): the engine model's prior "
                                       "friction, drawn toward the mean balance of the cycles so far; not an estimate "
                                       "from enough data", None)
    elif not math.isfinite(est.total_friction_torque):
        engine = FigureStatus("unresolved", "the data do not determine the engine's friction", None)
    else:
        engine = FigureStatus("measured", None, None)
    # each cylinder's status as a code, by masks (the words of its reason on request: FrictionStatus.cylinders).
    # In order of precedence: withheld (a sensor fault, unless the engine is unresolved), measured (resolved, with a
    # finite figure), share (the engine measured, the share finite), else unresolved
    gain = np.asarray(est.data_gain, dtype=np.float64)
    finite_gain = np.isfinite(gain)
    # nothing accumulated: nothing came from the data; one cylinder: no split to learn (the gain is 1 by
    # convention), its friction is the engine total, whose data is the balance
    weight = np.where(finite_gain, gain, np.nan) if accumulated else np.where(finite_gain, 0.0, np.nan)
    if z == 1:
        weight[:] = np.nan
    codes = np.full(z, _UNRESOLVED, np.int64)
    if engine.status == "measured":
        codes[np.isfinite(np.asarray(est.prior_friction_torque_mean, dtype=np.float64))] = _SHARE
    codes[np.asarray(est.resolved, dtype=bool) & np.isfinite(np.asarray(est.friction_torque_mean,
                                                                         dtype=np.float64))] = _MEASURED
    if engine.status != "unresolved":
        if engine_faults:
            codes[:] = _WITHHELD
        for cyl in cyl_faults:
            if cyl <= z:
                codes[cyl - 1] = _WITHHELD
    pulled = getattr(est, "pulled", None)  # (an estimate made by hand may not have it); the words read it later
    return FrictionStatus(engine, codes, weight, tuple(engine_faults), cyl_faults,
                          None if pulled is None else np.array(pulled, dtype=bool))
