"""Alerts of one engine from its per-cycle results (issue 17 item 4): decision logic only, no physics.

``AlertEngine.update(result)`` reads a ``CycleResult`` and returns the events of that cycle (raised, updated,
cleared). Each alert kind is a statistic per cylinder (or for the engine) with hysteresis: an alert is raised after
the statistic is above ``raise`` for ``raise_cycles`` consecutive cycles and cleared after it is below ``clear`` for
``clear_cycles`` (between the two nothing changes: no flapping). Each statistic is a rule, a small class with one
interface (service.alert_rules, service.alert_interface: its thresholds, its state, ``update(result, ctx)`` ->
decisions); the engine keeps what the rules share (the flags per cylinder, the commissioning baseline and its
learning, the pressure statistics, the latches, the alert records and ids, the events) and runs the rules of
``default_rules`` in one loop: a new alert kind is one class and one line there (the records, Alert and AlertEvent,
in service.alert_records). What each kind reads:

    blow_by      the leak signature of the pressure (core.monitor.checks.ring_pressure): the compression exponent down and
                 the expansion exponent up against the siblings, as a change from the cylinder's commissioning
                 baseline (service.alert_baseline) less the median of all cylinders' changes (one cylinder's change
                 is seen on that cylinder only), in units of its own per-cycle scatter: Z = EWMA of the combined
                 standardised change / its standard error. Covers every cylinder from the end of commissioning, with
                 or without a friction figure. Before a baseline exists: the core's sibling-floor flag blow_by_cyl<k>.
                 The baseline is per load band (the engine's mean IMEP): at a load no band holds yet the engine is not
                 commissioned there; the pressure statistics (blow_by and the gain check) hold still, open alerts say
                 so in their evidence (commissioned_at_this_load false), and a band for that load learns over the
                 next baseline_cycles healthy cycles there; after a load change they wait settle_cycles. A leak that grows while a band learns is in that band's
                 reference; the bands learnt before still see it when the engine returns to their loads.
    ring_wear    the cylinder's measured friction (figure status "measured") above its siblings' mean by more than
                 at its first measurement, in combined sigmas, unless that cylinder's pressure-gain check is raised
                 (a 3 % gain error on a K9K cylinder read as +46 % friction: the balance books the indicated work the
                 sensor adds as friction); or the core's ring_wear_cyl<k> flag before a baseline
    sensor_fault a sensor-health flag (sensor_*), a stuck or dropped pressure (a flat or non-positive compression),
                 or the compression pressure against the siblings changed with both exponents unchanged: a gain
                 error of that sensor, or a leak too small to bend the polytropes; the exponents are gain-invariant,
                 the ratio is not, so this is a sensor check (severity info), never a ring alert
    misfire      the EWMA rate of misfire_cyl<k> flags
    model_misfit the core's model_misfit flag (the speed fit's chi^2 window), persisting

A leak-like signature on a cylinder whose sensor is flagged is reported as a sensor_fault: a TDC error bends the
polytropes like a leak (core.monitor.checks.ring_pressure), and the sensor-health stage is what can tell them apart.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.checks.pressure_statistics import pressure_statistics
from frictionwatch.core.monitor.report.figure_status import split_flag
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.service.alert_baseline import INDICATORS, Band, Baseline, BaselineLearner
from frictionwatch.service.alert_config import AlertConfig
from frictionwatch.service.alert_interface import (
    Context,
    Decision,
    Hold,
    Latch,
    LeakStatistics,
    LeakWeights,
    LongRunVariance,
    Pressure,
    Rule,
    change_against_siblings,
    ewma_variance,
    leak_statistics,
    sibling_reference_variance,
)
from frictionwatch.service.alert_records import RULE_OF_KIND, Alert, AlertEvent, snapshot
from frictionwatch.service.alert_ring_rule import RingConditionRule
from frictionwatch.service.alert_rules import (
    CoreFlagRule,
    FrictionRule,
    GainRule,
    LeakRule,
    MisfireRule,
    ModelMisfitRule,
    SensorFlagRule,
)

__all__ = ["KINDS", "RING_KINDS", "Alert", "AlertConfig", "AlertEngine", "AlertEvent", "default_rules"]

MAX_ACKNOWLEDGEMENTS = 100  # kept per alert (the first is always kept)
KINDS = ("ring_wear", "blow_by", "misfire", "sensor_fault", "model_misfit")
# the long-run-variance estimate of the pressure statistics (alert_interface.LongRunVariance, design note 71), in
# windows of the statistics' EWMA: the centre its lag-1 products are taken about, the horizon they are averaged
# over, and the warm-up before it is used (phi's scatter ~1 / sqrt(n): ~0.07 per cylinder at 4 windows). Chosen
# from the EWMA's window and the estimate's scatter, not tuned on runs
LONG_RUN_CENTRE, LONG_RUN_HORIZON, LONG_RUN_WARMUP = 2, 40, 4
RING_KINDS = ("ring_wear", "blow_by")
# AlertEngine.warm_up's counts: the baseline learnt from the third cycle on, in 3 cycles, no settling hold, EWMA
# windows of 1 cycle (the long-run variance's warm-up, 4 windows, over in 4 cycles): every path of ``update`` within
# a warm-up's ~20 cycles. Not tuned: the smallest counts that reach the paths (tests/service/test_warmup.py)
WARM_COUNTS = {"baseline_cycles": 3, "skip_cycles": 1, "settle_cycles": 1, "window": 1.0, "ring_window": 1.0,
               "misfire_window": 1.0, "raise_cycles": 1, "clear_cycles": 1, "flag_raise_cycles": 1}


def default_rules(config: AlertConfig, n_cyl: int) -> tuple[tuple[Rule, ...], ...]:
    """The alert rules (service.alert_rules) in the stages they run in: a new alert kind is one class and one line.
    The decisions of one stage become events cylinder by cylinder (the engine's first), in the rules' order within a
    cylinder; a later stage sees the latches the earlier ones left (FrictionRule reads GainRule's)."""
    return ((MisfireRule(config, n_cyl),),
            (ModelMisfitRule(config), SensorFlagRule(config), CoreFlagRule(config, "blow_by"),
             CoreFlagRule(config, "ring_wear")),
            (LeakRule(config), GainRule(config)),
            (FrictionRule(config),),
            (RingConditionRule(config, n_cyl),))


class AlertEngine:
    """The alerts of one engine (module doc). Not thread-safe: one ingest thread calls ``update``; a reader takes
    ``active()`` / ``history()`` snapshots under the caller's lock. ``rules``: the rules in their stages
    (``default_rules``, which is what it is unless a caller adds its own)."""

    def __init__(self, spec: EngineSpec, config: AlertConfig | None = None, baseline: Baseline | None = None, *,
                 rules: tuple[tuple[Rule, ...], ...] | None = None):
        self.spec, self.config = spec, config or AlertConfig()
        z = spec.n_cyl
        if baseline is not None and baseline.mean.shape != (len(INDICATORS), z):
            raise ValueError(f"baseline is for {baseline.mean.shape[1]} cylinders; the engine has {z}")
        self.baseline: Baseline | None = baseline
        self.rules = default_rules(self.config, z) if rules is None else tuple(tuple(stage) for stage in rules)
        self._learner = BaselineLearner(z)
        self._next_id = 1
        self._open: dict[tuple[str, int | None], Alert] = {}
        self._history: list[Alert] = []
        self._latches: dict[tuple[str, int | None], Latch] = {}
        # by rule name, the cylinders whose latch is raised and those with a latch or an open alert: remade where a
        # latch or an open alert comes or goes or a latch turns (``_reindex``: a few times a run), read by the rules
        # once a cycle each (Context.latching / watching)
        self._latched_by: dict[str, frozenset[int | None]] = {}
        self._watched_by: dict[str, frozenset[int | None]] = {}
        self._ewma = np.zeros((len(INDICATORS), z))
        self._ewma_n = 0
        self._ewma_var = 0.0  # the EWMA's variance per unit of per-cycle variance (alert_interface.ewma_variance)
        self._leak_weights: LeakWeights | None = None  # the newest band's (leak_statistics' per-band part)
        self._weights_rows = np.zeros((4, z))  # its w1, w2, s_sd, sd_ratio as the kernel takes them
        # how far the healthy cycles' figures are from independent (the leak signature's and the ratio's)
        w = self.config.window
        self.long_run_variance = LongRunVariance(2, z, LONG_RUN_CENTRE * w, LONG_RUN_HORIZON * w,
                                                 int(LONG_RUN_WARMUP * w))
        self._imep_ref, self._settle = math.nan, 0  # the load-change hold of the pressure statistics
        self._cycles = 0
        self._last_cycle = -1

    # ---- public ---------------------------------------------------------------------------------------------
    def active(self) -> list[Alert]:
        return [snapshot(a) for a in sorted(self._open.values(), key=lambda a: a.alert_id)]

    def history(self) -> list[Alert]:
        return [snapshot(a) for a in sorted([*self._history, *self._open.values()], key=lambda a: a.alert_id)]

    def acknowledge(self, alert_id: int, by: str, at_s: float | None = None) -> Alert:
        """Mark an open alert acknowledged (it stays open until its evidence clears); KeyError for an unknown or
        cleared id. The first acknowledger stays ``acknowledged_by``; each acknowledgement (who, when: ``at_s``,
        wall-clock, now by default; the newest cycle) is appended to ``acknowledgements``, none overwritten."""
        for a in self._open.values():
            if a.alert_id == alert_id:
                who = str(by)[:80]
                a.state = "acknowledged"
                a.acknowledged_by = a.acknowledged_by or who
                if len(a.acknowledgements) < MAX_ACKNOWLEDGEMENTS:  # bounded: a script acknowledging in a loop
                    a.acknowledgements.append({"by": who, "at_s": time.time() if at_s is None else float(at_s),
                                               "cycle": self._last_cycle})
                return snapshot(a)
        raise KeyError(f"no open alert {alert_id}")

    def restore(self, alerts: list[dict]) -> list[str]:
        """Take back the alerts a store kept (service.store ``load_alerts``) before the first ``update``: cleared
        ones into the history, open ones open again with their latch raised (they clear as any open alert does,
        after clear_cycles without their evidence), and alert ids numbered on after the highest. Returns one
        line per alert that could not be read (it is skipped; the store still holds it)."""
        skipped = []
        for doc in alerts:
            try:
                a = Alert.from_dict(doc)
            except ValueError as exc:
                skipped.append(str(exc))
                continue
            self._next_id = max(self._next_id, a.alert_id + 1)
            if a.state == "cleared":
                self._history.append(a)
                continue
            a.rule = a.rule or RULE_OF_KIND.get(a.kind, a.kind)
            key = (a.rule, a.cylinder)
            if key in self._open:  # two open alerts for one statistic (ids ascending): the first stays open
                skipped.append(f"alert {a.alert_id}: alert {self._open[key].alert_id} is open for {key} already")
                continue
            latch = self._latches.setdefault(key, Latch())
            latch.active, latch.since = True, int(a.evidence.get("first_evidence_cycle", a.raised_cycle))
            self._open[key] = a
        self._history.sort(key=lambda a: a.alert_id)
        del self._history[:-self.config.max_history]
        self._reindex()
        return skipped

    def ring_condition(self) -> list[dict]:
        """The newest ring-condition figure of every cylinder (service.alert_ring_rule.RingConditionRule's evidence, with
        ``cylinder`` 1-based), [] before its first cycle or without that rule."""
        rule = next((r for stage in self.rules for r in stage if isinstance(r, RingConditionRule)), None)
        if rule is None or rule.last is None:
            return []
        return [{"cylinder": k + 1, **rule.last.evidence(k)} for k in range(self.spec.n_cyl)]

    def load_kernels(self) -> None:
        """Compile the statistics kernel, or load it from numba's cache, now: on throwaway arrays of this engine's
        shapes and types (the signature ``statistics`` calls it with), nothing of the engine's state touched. serve
        calls it on the ingest thread before the first record, in the start's "compiling the kernels" phase;
        otherwise the first cycle with a band in use (~200 cycles in) waited for it, 4.4 s on a cold cache
        (design notes 94, 100)."""
        z = self.spec.n_cyl
        lrv = self.long_run_variance
        params = np.array((lrv.centre_cycles, lrv.horizon, lrv.warmup, 1.0, 1.0))
        pressure_statistics(np.zeros((len(INDICATORS), z)), np.zeros((len(INDICATORS), z)), np.zeros_like(self._ewma),
                            0.5, np.ones_like(self._weights_rows), np.zeros_like(lrv.state), 0, params)

    def warm_up(self) -> AlertEngine:
        """A fresh alert engine of this one's spec and rules' kinds whose learning counts are short (WARM_COUNTS:
        the baseline learnt after a few cycles, the EWMAs' windows a few cycles long), for serve's warm-up
        (service/warmup.py): fed a warm-up's cycles, it calls every kernel this one will, with the same types, before
        the live run (design note 126). This engine is not touched."""
        return AlertEngine(self.spec, replace(self.config, **WARM_COUNTS))

    def rebaseline(self) -> list[AlertEvent]:
        """Learn a new commissioning baseline from the next cycle on (after an overhaul: the state now is the normal
        one); the alerts of the rules that rest on the old baseline are cleared (their events returned) and their
        latches restart."""
        self.baseline, self._learner = None, BaselineLearner(self.spec.n_cyl)
        self._ewma[:], self._ewma_n, self._ewma_var = 0.0, 0, 0.0
        names = {rule.name for stage in self.rules for rule in stage if rule.rests_on_baseline}
        events = []
        for key in [k for k in self._open if k[0] in names]:
            self._open[key].evidence["rebaselined"] = True
            events.append(self._clear(key, self._last_cycle))
        for key in [k for k in self._latches if k[0] in names]:
            del self._latches[key]
        self._reindex()
        return events

    def update(self, result: CycleResult) -> list[AlertEvent]:
        """Fold one cycle; the events it causes, in order: the rules' stages in turn, each cylinder by cylinder."""
        z = self.spec.n_cyl
        self._cycles += 1
        self._last_cycle = int(result.index)
        cyl_flags: list[set[str]] = [set() for _ in range(z)]
        engine_flags: set[str] = set()
        for f in set(result.flags):
            kind, cyl = split_flag(f)
            (cyl_flags[cyl - 1] if cyl is not None and 1 <= cyl <= z else engine_flags).add(kind)
        at_start = self.baseline
        pressure = self._pressure(result, cyl_flags)  # learns the baseline where the cycle is healthy
        ctx = Context(cyl_flags, engine_flags, at_start, self.baseline, pressure, latching=self._latching,
                      watching=self._watching)
        events: list[AlertEvent] = []
        for stage in self.rules:
            decisions = [(rule.name, d) for rule in stage for d in rule.update(result, ctx)]
            decisions.sort(key=lambda nd: 0 if nd[1].cylinder is None else nd[1].cylinder)  # stable: rule order
            for name, d in decisions:
                events += self._apply(name, d, result)
        self.baseline = ctx.baseline  # with what the rules added (the friction references)
        return events

    # ---- the pressure statistics and the baseline's learning ------------------------------------------------
    def _pressure(self, result: CycleResult, cyl_flags: list[set[str]]) -> Pressure | None:
        """The pressure statistics of a usable cycle (None: not usable): the indicators' EWMA against the load
        band of the baseline, or why they hold still (a load change settling; a load no band holds: learning)."""
        cfg, ring = self.config, result.ring
        if ring is None:
            return None
        x = ring.compared()  # rows as INDICATORS
        imep = _mean_imep(result)
        usable = (np.isfinite(x).all() and imep > 0.0 and self._cycles > cfg.skip_cycles  # not motored
                  and "operating_point_changed" not in result.flags  # a cycle spliced across a step
                  and not any(f and ("misfire" in f or any(s.startswith("sensor_") for s in f)) for f in cyl_flags))
        if not usable:
            return None
        if self._load_moved(imep):  # a load change: the statistics and the learning wait for it to settle
            self._settle = cfg.settle_cycles
        if self._settle > 0:
            self._settle -= 1
            return Pressure(imep, held="settling after a load change", learning_cycles=self._learner.n)
        band = None if self.baseline is None else self.baseline.band_for(imep)
        if band is None:  # not commissioned at this load: learn it; the pressure statistics wait (module doc)
            self._learn(x, int(result.index), imep)
            return Pressure(imep, held="not commissioned at this load: learning", learning_cycles=self._learner.n)
        self._ewma_n += 1
        g = max(1.0 / cfg.window, 1.0 / self._ewma_n)
        self._ewma_var = ewma_variance(self._ewma_var, g)
        var = self._ewma_var * sibling_reference_variance(self.spec.n_cyl)
        if self._leak_weights is None or self._leak_weights.band is not band:  # the band's, once per band
            self._leak_weights = LeakWeights.of(band)
            lw = self._leak_weights
            self._weights_rows = np.array((lw.w1, lw.w2, lw.s_sd, lw.sd_ratio))
        # the z's standard error holds the band mean's own error too (its cycles as correlated as the run's: the
        # same factor); var, for the ring rule's leak change, is the EWMA's alone (core leak_change adds the band's)
        band_var = sibling_reference_variance(self.spec.n_cyl) / max(band.cycles, 1)
        change, stats, (f_leak, f_ratio) = self.statistics(x, band, g, var, band_var)
        return Pressure(imep, ewma=change, stats=stats, band=band, var=var * f_leak, var_ratio=var * f_ratio,
                        long_run=(f_leak, f_ratio))

    def statistics(self, x: np.ndarray, band: Band, g: float, var: float, band_var: float
                   ) -> tuple[np.ndarray, LeakStatistics, tuple[float, float]]:
        """One cycle into the EWMA and the long-run estimate: the EWMA's change against the siblings (4, z), its leak
        statistics and the long-run factors, by core/monitor/checks/pressure_statistics.py's kernel (``statistics_reference``: the
        same in numpy, to the last bit)."""
        lrv = self.long_run_variance
        params = np.array((lrv.centre_cycles, lrv.horizon, lrv.warmup, var, band_var))
        change, z_leak, effect, z_ratio, factors, lrv.n = pressure_statistics(
            x, band.mean, self._ewma, g, self._weights_rows, lrv.state, lrv.n, params)
        return change, LeakStatistics(z_leak, effect, z_ratio), (float(factors[0]), float(factors[1]))

    def statistics_reference(self, x: np.ndarray, band: Band, g: float, var: float, band_var: float
                             ) -> tuple[np.ndarray, LeakStatistics, tuple[float, float]]:
        """``statistics`` by the numpy functions that define it (service.alert_interface; design notes 71, 72)."""
        u = x - band.mean
        self._ewma += g * (u - self._ewma)
        # the EWMA's change and this cycle's own, against the siblings in one sort (design note 72)
        change, u_rel = change_against_siblings(np.array((self._ewma, u)))
        lw = self._leak_weights
        # this cycle's own standardised figures against the siblings: the long-run estimate's input
        one = leak_statistics(u_rel, band, 1.0, weights=lw)
        self.long_run_variance.add(np.array((one.z_leak, one.z_ratio)))
        f_leak, f_ratio = self.long_run_variance.factor(g).tolist()
        stats = leak_statistics(change, band, (var + band_var) * f_leak, (var + band_var) * f_ratio, weights=lw)
        return change, stats, (f_leak, f_ratio)

    def _learn(self, x: np.ndarray, cycle: int, imep: float) -> None:
        """One healthy cycle at a load no band holds: into the learner, which restarts where the IMEP has left the
        band it began in (a ramp, another step); a full learner becomes a band (the first: the baseline)."""
        cfg, learner = self.config, self._learner
        if learner.n and abs(imep / learner.imep_first - 1.0) > cfg.band_width:
            learner = self._learner = BaselineLearner(self.spec.n_cyl)
        learner.add(x, cycle, imep)
        if learner.n >= cfg.baseline_cycles:
            self.baseline = (learner.baseline(cfg.band_width) if self.baseline is None
                             else self.baseline.with_band(learner.band(cfg.band_width)))
            self._learner = BaselineLearner(self.spec.n_cyl)

    def _load_moved(self, imep: float) -> bool:
        """Whether the mean IMEP left its slow reference by more than half a band (a step or a ramp); the reference
        follows a slow drift (20 cycles) and jumps to a moved IMEP."""
        ref = self._imep_ref
        if math.isfinite(ref) and abs(imep / ref - 1.0) <= 0.5 * self.config.band_width:
            self._imep_ref += 0.05 * (imep - ref)
            return False
        self._imep_ref = imep
        return math.isfinite(ref)

    # ---- hysteresis and the alert records -----------------------------------------------------------------
    def _watching(self, name: str) -> frozenset[int | None]:
        return self._watched_by.get(name, frozenset())

    def _latching(self, name: str) -> frozenset[int | None]:
        return self._latched_by.get(name, frozenset())

    def _reindex(self) -> None:
        """``_latched_by`` and ``_watched_by`` made again from the latches and the open alerts."""
        latched: dict[str, set[int | None]] = {}
        watched: dict[str, set[int | None]] = {}
        for (name, cylinder), latch in self._latches.items():
            watched.setdefault(name, set()).add(cylinder)
            if latch.active:
                latched.setdefault(name, set()).add(cylinder)
        for name, cylinder in self._open:
            watched.setdefault(name, set()).add(cylinder)
        self._latched_by = {name: frozenset(c) for name, c in latched.items()}
        self._watched_by = {name: frozenset(c) for name, c in watched.items()}

    def _apply(self, name: str, d: Decision | Hold, result: CycleResult) -> list[AlertEvent]:
        """One statistic's hysteresis step (its key: the rule's name and the cylinder; one open alert per key, of
        the kind it was raised as)."""
        key = (name, None if d.cylinder is None else int(d.cylinder))  # a numpy index never reaches the JSON
        if isinstance(d, Hold):  # no value this cycle: the latch holds still, an open alert says why
            if key in self._open:
                self._open[key].evidence.update(d.evidence)
            return []
        latch = self._latches.get(key)
        if latch is None:
            if not d.on:  # a fresh latch stepped with nothing on stays fresh: none is kept until it counts
                return []
            latch = self._latches[key] = Latch()
            self._reindex()  # a new latch: its cylinder is watched
        change = latch.step(bool(d.on), bool(d.off), d.k_on, d.k_off, int(result.index))
        if change == "raise":
            a = Alert(self._next_id, key[1], d.kind, d.severity, "active", int(result.index), float(result.t_start),
                      d.message, {**d.evidence, "first_evidence_cycle": latch.since}, rule=name)
            self._next_id += 1
            self._open[key] = a
            self._reindex()  # the latch turned and an alert opened: once for both
            return [AlertEvent("raised", snapshot(a))]
        a = self._open.get(key)
        if change == "clear":  # the latch turned (and its alert, where one is open, clears)
            events = [] if a is None else [self._clear(key, int(result.index))]
            self._reindex()
            return events
        if a is None:
            return []
        a.evidence.update(d.evidence)
        a.message = d.message
        if _rank(d.severity) > _rank(a.severity):  # escalate, never de-escalate while open (no flapping)
            a.severity = d.severity
            return [AlertEvent("updated", snapshot(a))]
        return []

    def _clear(self, key: tuple, cycle: int) -> AlertEvent:
        a = self._open.pop(key)  # (its callers remake the rules' index, _reindex, once for all they clear)
        a.state, a.cleared_cycle = "cleared", cycle
        self._history.append(a)
        del self._history[:-self.config.max_history]
        return AlertEvent("cleared", snapshot(a))


def _rank(severity: str) -> int:
    return ("info", "warning", "alarm").index(severity)


def _mean_imep(result: CycleResult) -> float:
    """The engine's mean IMEP this cycle [Pa] over the cylinders that have one (NaN: none), the load the bands key on."""
    imep = np.asarray(result.imep, dtype=float)
    total = float(np.add.reduce(imep))  # np.mean's own sum; finite only where every value is
    if imep.size and math.isfinite(total):
        return total / imep.size
    ok = np.isfinite(imep)
    return float(np.mean(imep[ok])) if ok.any() else math.nan
