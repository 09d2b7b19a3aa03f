"""The ring-condition alert rule (issue 29 item 3): ring wear in any cylinder from one figure per cylinder with its
sigma (core.monitor.checks.ring_condition), with the interface of the rules in service.alert_rules (in a module of its
own for its length). No physics: the figure is the core's; this rule gathers its inputs and decides."""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
from frictionwatch.core.monitor.checks.ring_condition import (
    SIBLINGS,
    TDC_LEAK_PER_DEG,
    RingCondition,
    RingConditionSettings,
    SiblingWindow,
    friction_excess,
    leak_change,
    leak_effect,
    ring_condition,
    update_window,
)
from frictionwatch.core.monitor.report.results import CycleResult, change_sigma
from frictionwatch.service.alert_config import AlertConfig
from frictionwatch.service.alert_interface import MEASURED, Context, Decision, Hold
from frictionwatch.service.alert_rules import FrictionRule, GainRule, LeakRule


class RingConditionRule:
    """Ring wear in any cylinder from one figure per cylinder with its sigma (core.monitor.checks.ring_condition):
    the leak effect's change since the commissioning baseline (chained through the load bands learnt during the
    run, ``_chained``: a band learnt after a fault began does not hide it) and the measured friction's change since
    its first measurement (reference "since_baseline"), or the windowed leak effect and the measured friction against
    the siblings (reference "against_siblings": a fault present from the first cycle, or grown into a baseline).
    Raised for ``raise_cycles`` cycles where either reference's figure is above 1 (a worn ring at the floor) and
    above ``raise_z`` (since) or ``ring_sibling_z`` (siblings) of its sigma; cleared when both are below
    ``clear_z`` / ``ring_sibling_clear_z`` for ``clear_cycles``. A cylinder with a sensor flag (or its gain check
    raised) leaves its friction out (its friction rests on its pressure) and its alert is a sensor_fault: a TDC error
    bends the polytropes like a leak. Nothing is raised on a cylinder whose leak or friction alert is raised already
    (one ring alert per cylinder; this figure is its explanation too). The sibling window learns only from usable
    cycles (no misfire, not across an operating-point change; a cylinder with a flagged sensor is left out of it
    while flagged); after a rebaseline (the present state declared normal) the sibling reference is off. ``last`` is
    the newest figure (for the API's explanation).

    >>> from types import SimpleNamespace
    >>> rule = RingConditionRule(AlertConfig())
    >>> ring = SimpleNamespace(n_compression_dev=np.array([-0.002, 0.001, 0.001]),
    ...                        n_expansion_dev=np.array([0.004, -0.002, -0.002]))
    >>> res = SimpleNamespace(ring=ring, flags=(), smoothed=None)
    >>> out = [rule.update(res, Context([set()] * 3)) for _ in range(150)]
    >>> [(d.cylinder, d.kind, d.on, d.evidence["ring_condition_reference"]) for d in out[-1]][:2]
    [(1, 'ring_wear', True, 'against_siblings'), (2, 'ring_wear', False, 'against_siblings')]
    >>> round(float(rule.last.figure[0]), 2), round(float(rule.last.sigma[0]), 2)
    (4.5, 1.0)
    """

    name, rests_on_baseline = "ring_condition", True
    gain_check = GainRule.name
    ring_rules = (LeakRule.name, FrictionRule.name)

    def __init__(self, config: AlertConfig, n_cyl: int | None = None):
        self.config = config
        self.settings = RingConditionSettings(window=config.ring_window, leak_scale=config.leak_floor,
                                              leak_allowance=config.ring_leak_allowance)
        self.window: SiblingWindow | None = None
        self.last: RingCondition | None = None
        self._native: set | None = None  # the baseline's bands when the rule first saw one (module: _chained)
        self._carry: dict = {}  # band key -> the leak change (z,) and sigma carried into it
        self._newest_change: tuple[np.ndarray, np.ndarray] | None = None  # the newest chained change and sigma
        self.siblings = True  # False after a rebaseline (the state then is declared normal)

    def update(self, result: CycleResult, ctx: Context) -> list[Decision | Hold]:
        cfg, ring, z = self.config, result.ring, ctx.n_cyl
        if ctx.baseline is None and self._native is not None:  # a rebaseline: the chain starts again, and the
            # present state is declared normal: the siblings no longer judge it
            self._native, self._carry, self._newest_change, self.siblings = None, {}, None, False
        if ring is None:
            return []
        if self.window is None:
            self.window = SiblingWindow.empty(z)
        gain_latched = ctx.latching(self.gain_check)
        sensor = np.array([(bool(fl) and any(f.startswith("sensor_") for f in fl)) or k + 1 in gain_latched
                           for k, fl in enumerate(ctx.cyl_flags)])
        # a cylinder with a flagged sensor keeps its window entry as it was (its siblings go on)
        effect = np.where(sensor, np.nan, leak_effect(ring.n_compression_dev, ring.n_expansion_dev))
        usable = (np.count_nonzero(np.isfinite(effect)) >= 2 and "operating_point_changed" not in result.flags
                  and not any("misfire" in fl for fl in ctx.cyl_flags))
        if usable:
            self.window = update_window(self.window, effect, self.settings)
        nan = np.full(z, np.nan)
        p = ctx.pressure
        lc, lc_s = (self._chained(*leak_change(p.ewma, p.band.cov, p.var, p.band.cycles), p.band, ctx)
                    if p is not None and p.held is None and p.ewma is not None and p.band is not None else (nan, nan))
        fc, fc_s, fn, fn_s = self._friction(result, ctx, sensor)
        rc = self.last = ring_condition(lc, lc_s, self.window, fc, fc_s, fn, fn_s, self.settings, self.siblings)
        out: list[Decision | Hold] = []
        # the conditions as arrays over the cylinders, each cylinder's read off them as Python values (per cylinder
        # and per scalar they were the rule's largest cost in serve: design note 45)
        with np.errstate(invalid="ignore", divide="ignore"):
            z_since, z_sib = rc.since / rc.since_sigma, rc.siblings / rc.siblings_sigma
            on_since = (rc.since > 1.0) & (z_since > cfg.raise_z)
            on_sib = (rc.siblings > 1.0) & (z_sib > cfg.ring_sibling_z)
            off = ~(z_since >= cfg.clear_z) & ~(z_sib >= cfg.ring_sibling_clear_z)
            # against the siblings a TDC error reads the same: never more than a warning
            alarm = on_since & (z_since > 2 * cfg.raise_z)
        read = (np.isfinite(rc.since) | np.isfinite(rc.siblings)).tolist()
        on, off_, alarm_, flagged = (on_since | on_sib).tolist(), off.tolist(), alarm.tolist(), sensor.tolist()
        misfit = "model_misfit" in ctx.engine_flags
        watched, others = ctx.watching(self.name), [ctx.latching(name) for name in self.ring_rules]
        for k in range(z):
            if not (on[k] or k + 1 in watched):
                continue  # not on and nothing kept for it (a Hold or an off Decision would change nothing)
            if not read[k]:
                out.append(Hold(k + 1, {"ring_condition": None}))
                continue
            # one ring alert per cylinder: where the leak or friction rule has raised one, this figure explains it
            # (the API's ring condition) and raises nothing more
            other = any(k + 1 in latched for latched in others)
            out.append(Decision(k + 1, "sensor_fault" if flagged[k] else "ring_wear", on[k] and not other, off_[k],
                                cfg.raise_cycles, cfg.clear_cycles, "alarm" if alarm_[k] else "warning",
                                detail=partial(self.explain, k, rc, flagged[k], misfit)))
        return out

    @staticmethod
    def explain(k: int, rc: RingCondition, sensor: bool, misfit: bool = False) -> tuple[str, dict]:
        """Cylinder k's (0-based) message and evidence from the figure ``rc`` (``misfit``: the speed fit flagged the
        engine model this cycle): made only where the engine reads them (a raise, an open alert:
        service.alert_interface.Decision)."""
        sib = rc.reference[k] == SIBLINGS
        msg = (f"cylinder {k + 1}: ring condition {rc.figure[k]:.1f} +- {rc.sigma[k]:.1f} (1.0: a worn ring at "
               f"the floor) " + ("against its siblings" if sib else "since the baseline")
               + (" with a flagged sensor: a TDC or pegging error is suspected" if sensor else "")
               + (f"; or a TDC error of {rc.leak_siblings[k] / TDC_LEAK_PER_DEG:+.2f} deg of this cylinder, which "
                  "reads the same in the pressure (a TDC found from the pressure, commissioning's too, reads a "
                  "leak as TDC: only a TDC measured apart from it tells the two apart)"
                  if sib and not sensor else "")
               # each cylinder is read at the shaft twist the model predicts (core ThrowMotion): a shaft line 15 %
               # off the model's moved healthy genset-v20 cylinders up to 3.6 units against their siblings, and
               # the speed fit flagged model_misfit by cycle 34 (design note 32)
               + ("; the speed fit flags the engine model (model_misfit): the shaft's twist this cylinder is read "
                  "at may be off, which reads like a leak against the siblings" if sib and misfit else ""))
        return msg, {"source": "ring_condition", **rc.evidence(k)}

    def _chained(self, change: np.ndarray, sigma: np.ndarray, band: Any, ctx: Context
                 ) -> tuple[np.ndarray, np.ndarray]:
        """The leak change since commissioning through the load bands learnt since: a band learnt during the run
        (after a load change to a load no band held) took in whatever had changed by then, so its first use carries
        the newest change measured before it (and its sigma) on; the bands of the baseline the rule first saw (the
        commissioning's) and the first band of a run without one carry nothing. A rebaseline starts again."""
        if ctx.baseline is None:
            return change, sigma
        if self._native is None:  # the bands this run began with: true references
            self._native = {(b.first_cycle, b.last_cycle) for b in ctx.baseline.bands}
        key = (band.first_cycle, band.last_cycle)
        if key not in self._carry:
            z = change.shape[0]
            new = key not in self._native and self._newest_change is not None
            self._carry[key] = self._newest_change if new else (np.zeros(z), np.zeros(z))
        c0, s0 = self._carry[key]
        total = (change + c0, np.hypot(sigma, s0))
        if np.all(np.isfinite(total[0])):
            self._newest_change = total
        return total

    def _friction(self, result: CycleResult, ctx: Context, sensor: np.ndarray) -> tuple[np.ndarray, ...]:
        """(change since the friction baseline, its sigma, the excess over the siblings now, its sigma) (z,): NaN
        where the friction is not measured or its cylinder's pressure is suspect."""
        z = ctx.n_cyl
        nan = np.full(z, np.nan)
        est = getattr(result, "smoothed", None)
        if est is None:
            return nan, nan.copy(), nan.copy(), nan.copy()
        status = ctx.smoothed_status(result)  # est is result.smoothed
        measured = (status.codes == MEASURED) & ~sensor
        if np.count_nonzero(measured) < 3:  # friction_excess's own answer (each needs two measured siblings), at once
            now, now_s, exc, exc_s = nan.copy(), nan.copy(), nan.copy(), nan.copy()
        else:
            t = np.asarray(est.friction_torque_mean, dtype=np.float64)
            now, now_s = friction_excess(t, np.asarray(est.friction_torque_mean_sigma, dtype=np.float64), measured)
            exc, exc_s = friction_excess(t, change_sigma(est), measured)
        change, change_s = nan.copy(), nan.copy()
        b = ctx.baseline
        if b is not None:
            change = exc - b.friction_excess
            change_s = np.hypot(exc_s, b.friction_excess_sigma)
        return change, change_s, now, now_s
