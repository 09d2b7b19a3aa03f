"""The one interface of the monitor's per-cycle checks (issue 26 item 4): each check is a small class with a
``name`` (the field of ``MonitorState`` its state is carried in), its own settings (thresholds, windows) and
``update(state, inp) -> CheckStep``: its state from the cycle before in (None on the first cycle), this cycle's
``CheckInput`` read, its new state, its flags, the identification as it leaves it and what it adds to the cycle's
result out. The monitor (core.monitor.monitor.process_cycle) runs the checks of ``CHECKS`` in order in one loop,
each seeing the identification the one before left. What each check decides is its own module's:

    check               state (MonitorState.<name>)   flags                                 adds to the result
    SensorHealthCheck   sensor: SensorHealthState     sensor_tdc_offset_cyl<k>, sensor_       sensor_health
                                                      pressure_gain/offset_cyl<k> (its sigmas
                                                      inflate the friction estimate's)
    ConditionCheck      condition: ConditionState     misfire_cyl<k>, motored, blow_by_cyl<k>, ring (the ring
                                                      ring_wear_cyl<k>, model_misfit; the      indicators,
                                                      change detector's condition_change_cyl   ring_pressure)
                                                      <k>, estimate_reset (the accumulator
                                                      discounted)

The service's alert rules (service.alert_rules, service.alert_interface.Rule) are the same shape one layer up: a
rule reads the ``CycleResult`` these checks made (its flags, sensor health, ring indicators) and decides an alert.
No service import here (structure.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from frictionwatch.core.model.engine import EngineSpec

if TYPE_CHECKING:
    from frictionwatch.core.monitor.balance.harmonic_balance import BalanceResult, OperatingPoint


@dataclass(frozen=True)
class CheckInput:
    """What a check reads of one cycle. config: the monitor's (core.monitor.state.MonitorConfig: a check reads its
    own settings there); grid (n,) rad; raw_pressure / pressure (z, n) Pa before and after the sensor corrections in
    use; op: the operating point the balance ran with (corrected phases); balance: the harmonic balance's result;
    params: the friction parameters the residual is taken at (the state's, before this cycle); prior_info: the
    prior's information matrix; pmax (z,) Pa; cylinder_rows (z, p_f): friction parameters -> per-cylinder torques;
    op_changed: the operating point moved this cycle; ident: the identification as the checks before left it;
    motion: each cylinder's throw against the wheel (core.monitor.checks.ring_pressure.ThrowMotion: the pressure
    read at the throw's own angle), None where the balance has no shaft line."""

    spec: EngineSpec
    config: Any
    grid: np.ndarray
    raw_pressure: np.ndarray
    pressure: np.ndarray
    op: OperatingPoint
    balance: BalanceResult
    params: np.ndarray
    prior_info: np.ndarray
    pmax: np.ndarray
    cylinder_rows: np.ndarray
    op_changed: bool
    ident: Any  # core.monitor.identify.identification.Identification: it imports the state, which imports the checks
    motion: Any = None  # core.monitor.checks.ring_pressure.ThrowMotion | None


@dataclass(frozen=True)
class CheckStep:
    """One check's cycle: its new ``state``, its ``flags`` (added to the cycle's), the ``ident`` the next check and
    the result see (its estimates' sigmas inflated, its accumulator discounted after a change), and ``report``: the
    ``CycleResult`` fields it fills (name -> value)."""

    state: Any
    flags: tuple[str, ...]
    ident: Any  # Identification (as CheckInput.ident)
    report: dict = field(default_factory=dict)


class Check(Protocol):
    """The interface every per-cycle check has (module doc)."""

    name: str

    def update(self, state: Any, inp: CheckInput) -> CheckStep: ...
