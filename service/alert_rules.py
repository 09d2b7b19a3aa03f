"""The alert rules (service.alerts): one small class per statistic an alert rests on, all with one interface
(service.alert_interface). No physics.

A rule has a ``name`` (the key of its statistics: one latch and at most one open alert per name and cylinder),
``rests_on_baseline`` (a rebaseline clears its alerts and restarts its latches) and ``update(result, ctx)``: it
reads one cycle's ``CycleResult`` and the engine's shared view of that cycle (``Context``: the flags per cylinder,
the pressure statistics against the commissioning baseline, the baseline, the latches) and returns one ``Decision``
per statistic it watches (on, off, the hysteresis counts, severity, message, evidence), or a ``Hold`` where the
statistic has no value this cycle. Its thresholds are its own fields of ``AlertConfig``; its state is its own.
The engine (service.alerts.AlertEngine) owns what they share: the latches, the alert records and their ids, the
baseline and its learning, the events. A new alert kind is one class here and one line in
``service.alerts.default_rules``.

    rule            name            raises         from
    MisfireRule     misfire         misfire        the EWMA rate of the misfire_cyl<k> flags
    ModelMisfitRule model_misfit    model_misfit   the core's model_misfit flag (the speed fit's chi^2 window)
    SensorFlagRule  sensor_fault    sensor_fault   sensor_* flags, pressure_repaired, a stuck or dropped pressure
    CoreFlagRule    core_blow_by,   blow_by,       the core's sibling-floor flags (core.monitor.checks.condition),
                    core_ring_wear  ring_wear      only until the commissioning baseline exists
    LeakRule        leak            blow_by        the leak signature of the pressure against the baseline
    GainRule        gain            sensor_fault   the compression ratio moved with both exponents unchanged
    FrictionRule    friction        ring_wear      the measured friction's excess over its siblings, against the
                                                   excess at its first measurement; not while the gain check is raised
    RingConditionRule
                    ring_condition  ring_wear      one figure per cylinder with its sigma (core.monitor.checks.
                                    (sensor_fault  ring_condition): the leak effect and the measured friction since
                                    if flagged)    the baseline or against the siblings; from the first cycle
"""

from __future__ import annotations

import math
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
from frictionwatch.core.monitor.report.figure_status import friction_status
from frictionwatch.core.monitor.report.results import PA_PER_BAR, CycleResult, change_sigma
from frictionwatch.service.alert_config import AlertConfig
from frictionwatch.service.alert_interface import Context, Decision, Hold, Pressure


# ---- the rules --------------------------------------------------------------------------------------------------
class MisfireRule:
    """Each cylinder's misfire rate, the EWMA over ``misfire_window`` cycles of its misfire flag: raised from
    ``misfire_raise`` and cleared below ``misfire_clear`` at once (the EWMA is the persistence); an alarm from
    ``misfire_alarm``.

    >>> rule = MisfireRule(AlertConfig(misfire_window=10.0), n_cyl=2)
    >>> [(d.cylinder, d.on, round(d.evidence["misfire_rate"], 2)) for d in rule.update(None, Context([{"misfire"}, set()]))]
    [(1, True, 0.1), (2, False, 0.0)]
    """

    name, rests_on_baseline = "misfire", False

    def __init__(self, config: AlertConfig, n_cyl: int):
        self.config = config
        self.rate = np.zeros(n_cyl)

    def update(self, result: CycleResult, ctx: Context) -> list[Decision | Hold]:
        cfg = self.config
        hit = np.array([1.0 if "misfire" in f else 0.0 for f in ctx.cyl_flags])
        self.rate += (1.0 / cfg.misfire_window) * (hit - self.rate)
        out: list[Decision | Hold] = []
        for k in range(ctx.n_cyl):
            rate = float(self.rate[k])
            sev = "alarm" if rate >= cfg.misfire_alarm else "warning"
            out.append(Decision(k + 1, "misfire", rate >= cfg.misfire_raise, rate < cfg.misfire_clear, 1, 1, sev,
                                f"cylinder {k + 1} misfires: {100 * rate:.1f} % of recent cycles",
                                {"misfire_rate": rate, "window_cycles": cfg.misfire_window}))
        return out


class ModelMisfitRule:
    """The core's model_misfit flag (the speed fit worse than its noise model), raised after ``flag_raise_cycles``
    flagged cycles in a row, cleared after ``clear_cycles`` without.

    >>> from types import SimpleNamespace
    >>> d, = ModelMisfitRule(AlertConfig()).update(SimpleNamespace(cycle=SimpleNamespace(chi2_reduced=4.0)),
    ...                                             Context([set()], {"model_misfit"}))
    >>> (d.cylinder, d.kind, d.on, d.k_on, d.evidence)
    (None, 'model_misfit', True, 5, {'chi2_reduced': 4.0})
    """

    name, rests_on_baseline = "model_misfit", False

    def __init__(self, config: AlertConfig):
        self.config = config

    def update(self, result: CycleResult, ctx: Context) -> list[Decision | Hold]:
        on = "model_misfit" in ctx.engine_flags
        return [Decision(None, "model_misfit", on, not on, self.config.flag_raise_cycles, self.config.clear_cycles,
                         "warning", "the speed fit is worse than its noise model allows: the engine model does not "
                         "describe this engine (friction figures may be biased)",
                         {"chi2_reduced": result.cycle.chi2_reduced})]


class SensorFlagRule:
    """Sensor checks from flags: the engine's sensor_* flags (the wheel) and each cylinder's (with pressure_repaired
    and a stuck or dropped pressure: a flat or non-positive compression, n_compression not above 0.5), raised after
    ``flag_raise_cycles`` cycles, cleared after ``clear_cycles``.

    >>> from types import SimpleNamespace
    >>> ds = SensorFlagRule(AlertConfig()).update(SimpleNamespace(ring=None), Context([{"sensor_tdc"}], set()))
    >>> [(d.cylinder, d.on, d.message) for d in ds]
    [(None, False, 'sensor check on the engine: -'), (1, True, 'sensor check on cylinder 1: sensor_tdc')]
    """

    name, rests_on_baseline = "sensor_fault", False

    def __init__(self, config: AlertConfig):
        self.config = config

    def update(self, result: CycleResult, ctx: Context) -> list[Decision | Hold]:
        k_on, k_off, ring = self.config.flag_raise_cycles, self.config.clear_cycles, result.ring
        wheel = sorted(f for f in ctx.engine_flags if f.startswith("sensor_"))
        out: list[Decision | Hold] = [Decision(None, "sensor_fault", bool(wheel), not wheel, k_on, k_off, "warning",
                                               "sensor check on the engine: " + ", ".join(wheel or ["-"]),
                                               {"flags": wheel})]
        for k, fl in enumerate(ctx.cyl_flags):
            sensor = sorted(f for f in fl if f.startswith("sensor_") or f == "pressure_repaired")
            if ring is not None and not (np.isfinite(ring.n_compression[k]) and ring.n_compression[k] > 0.5):
                sensor.append("pressure_stuck_or_dropped")
            out.append(Decision(k + 1, "sensor_fault", bool(sensor), not sensor, k_on, k_off, "warning",
                                f"sensor check on cylinder {k + 1}: " + ", ".join(sensor or ["-"]),
                                {"flags": sensor, "n_compression": _num(ring.n_compression[k]) if ring else None}))
        return out


class CoreFlagRule:
    """The core's sibling-floor flag ``kind`` (blow_by or ring_wear, core.monitor.checks.condition) of each
    cylinder, while no commissioning baseline exists at the start of the cycle: raised after 4 x
    ``flag_raise_cycles`` flagged cycles, cleared after ``clear_cycles`` (once the baseline exists it is no longer
    stepped: an alert it raised stays open until a rebaseline).

    >>> ds = CoreFlagRule(AlertConfig(), "ring_wear").update(None, Context([set(), {"ring_wear"}]))
    >>> [(d.cylinder, d.kind, d.on, d.k_on) for d in ds]
    [(1, 'ring_wear', False, 20), (2, 'ring_wear', True, 20)]
    """

    rests_on_baseline = True

    def __init__(self, config: AlertConfig, kind: str):
        self.config, self.kind, self.name = config, kind, "core_" + kind

    def update(self, result: CycleResult, ctx: Context) -> list[Decision | Hold]:
        if ctx.baseline_at_start is not None:
            return []
        kind, k_on, k_off = self.kind, 4 * self.config.flag_raise_cycles, self.config.clear_cycles
        return [Decision(k + 1, kind, kind in fl, kind not in fl, k_on, k_off, "warning",
                         f"cylinder {k + 1}: {kind.replace('_', ' ')} against its siblings (before a commissioning "
                         "baseline)", {"source": "core_flag"}) for k, fl in enumerate(ctx.cyl_flags)]


def _pressure_evidence(p: Pressure, k: int, window: float) -> dict:
    """The evidence a pressure alert of cylinder k (0-based) carries."""
    st, ewma, band = p.stats, p.ewma, p.band
    ev = {"source": "pressure", "z_leak": st.z_leak[k], "n_compression_change": ewma[1, k],
          "n_expansion_change": ewma[2, k], "compression_ratio_change_ln": ewma[0, k],
          "expansion_deficit_change_ln": ewma[3, k], "z_compression_ratio": st.z_ratio[k],
          "baseline_cycles": band.cycles, "window_cycles": window, "commissioned_at_this_load": True,
          "suspended": None,
          "imep_bar": p.imep_pa / PA_PER_BAR, "load_band_imep_bar": [band.imep_lo_pa / PA_PER_BAR,
                                                                     band.imep_hi_pa / PA_PER_BAR]}
    ev = {key: (_num(v) if isinstance(v, float | np.floating) else v) for key, v in ev.items()}
    ev["load_band_imep_bar"] = [_num(v) for v in ev["load_band_imep_bar"]]
    return ev


def _holds(p: Pressure, n_cyl: int) -> list[Decision | Hold]:
    """While the pressure statistics hold still: every cylinder's open pressure alert says why."""
    ev = {"commissioned_at_this_load": False, "suspended": p.held, "imep_bar": _num(p.imep_pa / PA_PER_BAR),
          "learning_cycles": p.learning_cycles}
    return [Hold(k + 1, ev) for k in range(n_cyl)]


class _PressureRule:
    """What the rules on the pressure statistics share: nothing without them, every cylinder held while they are,
    else one decision per cylinder (``decide``)."""

    rests_on_baseline = True

    def __init__(self, config: AlertConfig):
        self.config = config

    def update(self, result: CycleResult, ctx: Context) -> list[Decision | Hold]:
        p = ctx.pressure
        if p is None:
            return []
        if p.held:
            return _holds(p, ctx.n_cyl)
        return [self.decide(k, p, ctx) for k in range(ctx.n_cyl)]

    def decide(self, k: int, p: Pressure, ctx: Context) -> Decision:
        raise NotImplementedError


class LeakRule(_PressureRule):
    """The leak signature of each cylinder's pressure (service.alerts module doc): raised when its Z exceeds
    ``raise_z`` with a mean exponent change above ``leak_floor`` for ``raise_cycles`` cycles, cleared below
    ``clear_z`` for ``clear_cycles``; an alarm from ``alarm_z`` and 3 x ``leak_floor``. A blow_by, or a sensor_fault
    where that cylinder has a sensor flag (a TDC error bends the polytropes like a leak). Held while the pressure
    statistics are.

    >>> from types import SimpleNamespace
    >>> from frictionwatch.service.alert_interface import LeakStatistics
    >>> band = SimpleNamespace(cycles=100, imep_lo_pa=10.8e5, imep_hi_pa=13.2e5)
    >>> p = Pressure(12e5, ewma=np.array([[-0.004], [-0.003], [0.003], [-0.002]]), band=band,
    ...              stats=LeakStatistics(z_leak=np.array([9.0]), effect=np.array([0.003]), z_ratio=np.array([-4.0])))
    >>> d, = LeakRule(AlertConfig()).update(None, Context([set()], pressure=p))
    >>> (d.kind, d.on, d.severity, d.evidence["z_leak"])
    ('blow_by', True, 'warning', 9.0)
    """

    name = "leak"

    def decide(self, k: int, p: Pressure, ctx: Context) -> Decision:
        cfg, st = self.config, p.stats
        sensor = any(s.startswith("sensor_") for s in ctx.cyl_flags[k])
        sev = "alarm" if st.z_leak[k] >= cfg.alarm_z and st.effect[k] > 3 * cfg.leak_floor else "warning"
        msg = (f"cylinder {k + 1}: leak-like pressure signature (compression exponent "
               f"{p.ewma[1, k]:+.4f}, expansion exponent {p.ewma[2, k]:+.4f} from commissioning)"
               + (" with a flagged sensor: a TDC or pegging error is suspected" if sensor else ""))
        return Decision(k + 1, "sensor_fault" if sensor else "blow_by",
                        bool(st.z_leak[k] > cfg.raise_z and st.effect[k] > cfg.leak_floor),
                        bool(st.z_leak[k] < cfg.clear_z), cfg.raise_cycles, cfg.clear_cycles, sev, msg,
                        _pressure_evidence(p, k, cfg.window))


class GainRule(_PressureRule):
    """A pressure-gain check of each cylinder's sensor: the compression ratio against the siblings moved by more
    than ``gain_floor`` (|d ln p|) and ``raise_z`` standard errors while the leak signature stays below ``clear_z``
    (the exponents are gain-invariant, the ratio is not); cleared when the ratio is back below ``clear_z`` or the leak
    signature rises above ``raise_z``. Severity info: never a ring alert. Held while the pressure statistics are.

    >>> from types import SimpleNamespace
    >>> from frictionwatch.service.alert_interface import LeakStatistics
    >>> band = SimpleNamespace(cycles=100, imep_lo_pa=10.8e5, imep_hi_pa=13.2e5)
    >>> p = Pressure(12e5, ewma=np.array([[0.03], [0.0], [0.0], [0.0]]), band=band,
    ...              stats=LeakStatistics(z_leak=np.array([0.5]), effect=np.array([0.0]), z_ratio=np.array([25.0])))
    >>> d, = GainRule(AlertConfig()).update(None, Context([set()], pressure=p))
    >>> (d.kind, d.on, d.severity, round(d.evidence["gain_estimate"], 4))
    ('sensor_fault', True, 'info', 1.0305)
    """

    name = "gain"

    def decide(self, k: int, p: Pressure, ctx: Context) -> Decision:
        cfg, st = self.config, p.stats
        on = bool(abs(st.z_ratio[k]) > cfg.raise_z and abs(p.ewma[0, k]) > cfg.gain_floor
                  and st.z_leak[k] < cfg.clear_z)
        off = bool(abs(st.z_ratio[k]) < cfg.clear_z or st.z_leak[k] > cfg.raise_z)
        return Decision(k + 1, "sensor_fault", on, off, cfg.raise_cycles, cfg.clear_cycles, "info",
                        f"cylinder {k + 1}: compression pressure {math.exp(p.ewma[0, k]):.3f}x "
                        "its commissioning value against the siblings with both polytropic exponents "
                        "unchanged: a pressure-gain error of this sensor (or a leak too small to bend the "
                        "exponents); check the sensor",
                        {**_pressure_evidence(p, k, cfg.window), "suspect": "pressure_gain",
                         "gain_estimate": _num(math.exp(p.ewma[0, k]))})


class FrictionRule:
    """Ring wear from the friction where it is measured (figure status "measured"): each cylinder's excess over its
    measured siblings' mean (at least two), against that excess at its first measurement after commissioning (kept
    in the baseline), in combined sigmas: raised above ``friction_raise_sigmas`` for ``raise_cycles`` cycles (an
    alarm above twice that), cleared below ``friction_clear_sigmas`` for ``clear_cycles``. A cylinder whose gain check
    (GainRule) is raised is skipped: its friction rests on its suspect pressure. Nothing before a baseline.

    >>> from types import SimpleNamespace
    >>> from frictionwatch.service.alert_baseline import BaselineLearner
    >>> est = SimpleNamespace(resolved=np.ones(3, bool), data_gain=np.ones(3), friction_torque_mean=np.array(
    ...     [5.0, 5.0, 6.0]), friction_torque_mean_sigma=np.full(3, 0.05), prior_friction_torque_mean=np.full(3, 5.0),
    ...     total_friction_torque=16.0, weight=10.0, source="data")
    >>> ctx = Context([set()] * 3, baseline=BaselineLearner(3).baseline(0.1))
    >>> FrictionRule(AlertConfig()).update(SimpleNamespace(index=7, flags=(), smoothed=est), ctx)  # first: references
    []
    >>> ctx.baseline.friction_cycle.tolist()
    [7, 7, 7]
    """

    name, rests_on_baseline = "friction", True
    gain_check = GainRule.name

    def __init__(self, config: AlertConfig):
        self.config = config

    def update(self, result: CycleResult, ctx: Context) -> list[Decision | Hold]:
        cfg, est = self.config, result.smoothed
        if ctx.baseline is None:
            return []
        status = friction_status(est, result.flags)
        measured = np.array([c.status == "measured" for c in status.cylinders])
        # a change against the baseline: the calibration's error is the same then and now and cancels
        t, s = est.friction_torque_mean, change_sigma(est)
        out: list[Decision | Hold] = []
        for k in np.flatnonzero(measured):
            if ctx.latched(self.gain_check, int(k) + 1):  # its pressure is suspect, and its friction rests on it
                continue
            others = np.flatnonzero(measured)
            others = others[others != k]
            if others.size < 2:
                continue
            ref = float(np.mean(t[others]))
            excess = t[k] / ref - 1.0
            sigma = math.sqrt(s[k] ** 2 + float(np.mean(s[others] ** 2)) / others.size) / ref
            if not np.isfinite(ctx.baseline.friction_excess[k]):
                ctx.baseline = ctx.baseline.with_friction(k, excess, sigma, int(result.index))
                continue
            base, base_s = ctx.baseline.friction_excess[k], ctx.baseline.friction_excess_sigma[k]
            zf = (excess - base) / math.hypot(sigma, base_s)
            out.append(Decision(int(k) + 1, "ring_wear", zf > cfg.friction_raise_sigmas,
                                zf < cfg.friction_clear_sigmas, cfg.raise_cycles, cfg.clear_cycles,
                                "alarm" if zf > 2 * cfg.friction_raise_sigmas else "warning",
                                f"cylinder {k + 1}: friction {100 * (excess - base):+.1f} % against its siblings "
                                f"since cycle {int(ctx.baseline.friction_cycle[k])}",
                                {"source": "friction", "z_friction": _num(zf), "friction_excess": _num(excess),
                                 "friction_excess_baseline": _num(base), "friction_torque_nm": _num(t[k]),
                                 "friction_torque_sigma_nm": _num(s[k])}))
        return out


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
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # the newest chained change and sigma
        self.siblings = True  # False after a rebaseline (the state then is declared normal)

    def update(self, result: CycleResult, ctx: Context) -> list[Decision | Hold]:
        cfg, ring, z = self.config, result.ring, ctx.n_cyl
        if ctx.baseline is None and self._native is not None:  # a rebaseline: the chain starts again, and the
            # present state is declared normal: the siblings no longer judge it
            self._native, self._carry, self._last, self.siblings = None, {}, None, False
        if ring is None:
            return []
        if self.window is None:
            self.window = SiblingWindow.empty(z)
        sensor = np.array([any(f.startswith("sensor_") for f in fl) or ctx.latched(self.gain_check, k + 1)
                           for k, fl in enumerate(ctx.cyl_flags)])
        # a cylinder with a flagged sensor keeps its window entry as it was (its siblings go on)
        effect = np.where(sensor, np.nan, leak_effect(ring.n_compression_dev, ring.n_expansion_dev))
        usable = (np.sum(np.isfinite(effect)) >= 2 and "operating_point_changed" not in result.flags
                  and not any("misfire" in fl for fl in ctx.cyl_flags))
        if usable:
            self.window = update_window(self.window, effect, self.settings)
        nan = np.full(z, np.nan)
        p = ctx.pressure
        lc, lc_s = (self._chained(*leak_change(p.ewma, p.band.cov, p.g, p.band.cycles), p.band, ctx)
                    if p is not None and p.held is None and p.ewma is not None and p.band is not None else (nan, nan))
        fc, fc_s, fn, fn_s = self._friction(result, ctx, sensor)
        rc = self.last = ring_condition(lc, lc_s, self.window, fc, fc_s, fn, fn_s, self.settings, self.siblings)
        out: list[Decision | Hold] = []
        with np.errstate(invalid="ignore", divide="ignore"):
            z_since, z_sib = rc.since / rc.since_sigma, rc.siblings / rc.siblings_sigma
        for k in range(z):
            on_since = bool(rc.since[k] > 1.0 and z_since[k] > cfg.raise_z)
            on_sib = bool(rc.siblings[k] > 1.0 and z_sib[k] > cfg.ring_sibling_z)
            off = bool(not (z_since[k] >= cfg.clear_z) and not (z_sib[k] >= cfg.ring_sibling_clear_z))
            if not (np.isfinite(rc.since[k]) or np.isfinite(rc.siblings[k])):
                out.append(Hold(k + 1, {"ring_condition": None}))
                continue
            sib = rc.reference[k] == SIBLINGS
            kind = "sensor_fault" if sensor[k] else "ring_wear"
            msg = (f"cylinder {k + 1}: ring condition {rc.figure[k]:.1f} +- {rc.sigma[k]:.1f} (1.0: a worn ring at "
                   f"the floor) " + ("against its siblings" if sib else "since the baseline")
                   + (" with a flagged sensor: a TDC or pegging error is suspected" if sensor[k] else "")
                   + (f"; or a TDC error of {rc.leak_siblings[k] / TDC_LEAK_PER_DEG:+.2f} deg of this cylinder, which "
                      "reads the same (commissioning measures each cylinder's TDC)" if sib and not sensor[k] else ""))
            # against the siblings a TDC error reads the same: never more than a warning
            sev = "alarm" if on_since and z_since[k] > 2 * cfg.raise_z else "warning"
            # one ring alert per cylinder: where the leak or friction rule has raised one, this figure explains it
            # (the API's ring condition) and raises nothing more
            other = any(ctx.latched(name, k + 1) for name in self.ring_rules)
            out.append(Decision(k + 1, kind, (on_since or on_sib) and not other, off, cfg.raise_cycles,
                                cfg.clear_cycles, sev, msg,
                                {"source": "ring_condition", **rc.evidence(k)}))
        return out

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
            new = key not in self._native and self._last is not None
            self._carry[key] = self._last if new else (np.zeros(z), np.zeros(z))
        c0, s0 = self._carry[key]
        total = (change + c0, np.hypot(sigma, s0))
        if np.all(np.isfinite(total[0])):
            self._last = total
        return total

    def _friction(self, result: CycleResult, ctx: Context, sensor: np.ndarray) -> tuple[np.ndarray, ...]:
        """(change since the friction baseline, its sigma, the excess over the siblings now, its sigma) (z,): NaN
        where the friction is not measured or its cylinder's pressure is suspect."""
        z = ctx.n_cyl
        nan = np.full(z, np.nan)
        est = getattr(result, "smoothed", None)
        if est is None:
            return nan, nan.copy(), nan.copy(), nan.copy()
        status = friction_status(est, result.flags)
        measured = np.array([c.status == "measured" for c in status.cylinders]) & ~sensor
        t = np.asarray(est.friction_torque_mean, dtype=np.float64)
        now, now_s = friction_excess(t, np.asarray(est.friction_torque_mean_sigma, dtype=np.float64), measured)
        exc, exc_s = friction_excess(t, change_sigma(est), measured)
        change, change_s = nan.copy(), nan.copy()
        b = ctx.baseline
        if b is not None:
            change = exc - b.friction_excess
            change_s = np.hypot(exc_s, b.friction_excess_sigma)
        return change, change_s, now, now_s


def _num(v: Any) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None
