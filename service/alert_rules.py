"""The alert rules (service.alerts): one small class per statistic an alert rests on, all with one interface
(service.alert_interface). No physics.

A rule has a ``name`` (the key of its statistics: one latch and at most one open alert per name and cylinder),
``rests_on_baseline`` (a rebaseline clears its alerts and restarts its latches) and ``update(result, ctx)``: it
reads one cycle's ``CycleResult`` and the engine's shared view of that cycle (``Context``: the flags per cylinder,
the pressure statistics against the commissioning baseline, the baseline, the latches) and returns one ``Decision``
per statistic it watches (on, off, the hysteresis counts, severity, and its message and evidence, here given as a
``detail`` that makes them only where the engine reads them: a raise, an open alert), or a ``Hold`` where the
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
                                                   (its own module: service.alert_ring_rule)
"""

from __future__ import annotations

import math
from functools import partial
from typing import Any

import numpy as np
from frictionwatch.core.monitor.checks.ring_condition import friction_excess
from frictionwatch.core.monitor.report.results import PA_PER_BAR, CycleResult, change_sigma
from frictionwatch.service.alert_config import AlertConfig
from frictionwatch.service.alert_interface import MEASURED, Context, Decision, Hold, Pressure


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
        watched = ctx.watching(self.name)
        for k, rate in enumerate(self.rate.tolist()):
            if rate < cfg.misfire_raise and k + 1 not in watched:
                continue  # not on and nothing kept for it: the engine would do nothing with it
            sev = "alarm" if rate >= cfg.misfire_alarm else "warning"
            out.append(Decision(k + 1, "misfire", rate >= cfg.misfire_raise, rate < cfg.misfire_clear, 1, 1, sev,
                                detail=partial(self.explain, k, rate)))
        return out

    def explain(self, k: int, rate: float) -> tuple[str, dict]:
        return (f"cylinder {k + 1} misfires: {100 * rate:.1f} % of recent cycles",
                {"misfire_rate": rate, "window_cycles": self.config.misfire_window})


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
                         "warning", detail=partial(self.explain, result.cycle.chi2_reduced))]

    @staticmethod
    def explain(chi2_reduced: float) -> tuple[str, dict]:
        return ("the speed fit is worse than its noise model allows: the engine model does not describe this engine "
                "(friction figures may be biased)", {"chi2_reduced": chi2_reduced})


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
                                               detail=partial(self.explain, None, wheel, None))]
        n_comp = ring.n_compression.tolist() if ring is not None else None
        watched = ctx.watching(self.name)
        for k, fl in enumerate(ctx.cyl_flags):
            sensor = sorted(f for f in fl if f.startswith("sensor_") or f == "pressure_repaired") if fl else []
            if n_comp is not None and not (math.isfinite(n_comp[k]) and n_comp[k] > 0.5):
                sensor.append("pressure_stuck_or_dropped")
            if not sensor and k + 1 not in watched:
                continue
            out.append(Decision(k + 1, "sensor_fault", bool(sensor), not sensor, k_on, k_off, "warning",
                                detail=partial(self.explain, k + 1, sensor, n_comp)))
        return out

    @staticmethod
    def explain(cylinder: int | None, sensor: list[str], n_comp: list[float] | None) -> tuple[str, dict]:
        if cylinder is None:
            return "sensor check on the engine: " + ", ".join(sensor or ["-"]), {"flags": sensor}
        return (f"sensor check on cylinder {cylinder}: " + ", ".join(sensor or ["-"]),
                {"flags": sensor, "n_compression": _num(n_comp[cylinder - 1]) if n_comp is not None else None})


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
        watched = ctx.watching(self.name)
        return [Decision(k + 1, kind, kind in fl, kind not in fl, k_on, k_off, "warning",
                         detail=partial(self.explain, k)) for k, fl in enumerate(ctx.cyl_flags)
                if kind in fl or k + 1 in watched]

    def explain(self, k: int) -> tuple[str, dict]:
        return (f"cylinder {k + 1}: {self.kind.replace('_', ' ')} against its siblings (before a commissioning "
                "baseline)", {"source": "core_flag"})


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


def _holds(p: Pressure, name: str, ctx: Context) -> list[Decision | Hold]:
    """While the pressure statistics hold still: every cylinder's open pressure alert says why."""
    ev = {"commissioned_at_this_load": False, "suspended": p.held, "imep_bar": _num(p.imep_pa / PA_PER_BAR),
          "learning_cycles": p.learning_cycles}
    watched = ctx.watching(name)
    return [Hold(k + 1, ev) for k in range(ctx.n_cyl) if k + 1 in watched]


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
            return _holds(p, self.name, ctx)
        return self.decide(p, ctx)

    def decide(self, p: Pressure, ctx: Context) -> list[Decision | Hold]:
        """One decision per cylinder; the conditions as arrays over the cylinders, one comparison each (per
        cylinder and per scalar they were 2 % of a serve's GIL time with 4 gensets: design note 45)."""
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

    def decide(self, p: Pressure, ctx: Context) -> list[Decision | Hold]:
        cfg, st = self.config, p.stats
        on = ((st.z_leak > cfg.raise_z) & (st.effect > cfg.leak_floor)).tolist()
        off = (st.z_leak < cfg.clear_z).tolist()
        alarm = ((st.z_leak >= cfg.alarm_z) & (st.effect > 3 * cfg.leak_floor)).tolist()
        out: list[Decision | Hold] = []
        watched = ctx.watching(self.name)
        for k, flags in enumerate(ctx.cyl_flags):
            if not on[k] and k + 1 not in watched:
                continue
            sensor = any(s.startswith("sensor_") for s in flags)
            out.append(Decision(k + 1, "sensor_fault" if sensor else "blow_by", on[k], off[k], cfg.raise_cycles,
                                cfg.clear_cycles, "alarm" if alarm[k] else "warning",
                                detail=partial(self.explain, k, p, sensor)))
        return out

    def explain(self, k: int, p: Pressure, sensor: bool) -> tuple[str, dict]:
        return (f"cylinder {k + 1}: leak-like pressure signature (compression exponent "
                f"{p.ewma[1, k]:+.4f}, expansion exponent {p.ewma[2, k]:+.4f} from commissioning)"
                + (" with a flagged sensor: a TDC or pegging error is suspected" if sensor else ""),
                _pressure_evidence(p, k, self.config.window))


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

    def decide(self, p: Pressure, ctx: Context) -> list[Decision | Hold]:
        cfg, st = self.config, p.stats
        ratio = np.abs(st.z_ratio)
        on = ((ratio > cfg.raise_z) & (np.abs(p.ewma[0]) > cfg.gain_floor) & (st.z_leak < cfg.clear_z)).tolist()
        off = ((ratio < cfg.clear_z) | (st.z_leak > cfg.raise_z)).tolist()
        watched = ctx.watching(self.name)
        return [Decision(k + 1, "sensor_fault", on[k], off[k], cfg.raise_cycles, cfg.clear_cycles, "info",
                         detail=partial(self.explain, k, p)) for k in range(ctx.n_cyl)
                if on[k] or k + 1 in watched]

    def explain(self, k: int, p: Pressure) -> tuple[str, dict]:
        return (f"cylinder {k + 1}: compression pressure {math.exp(p.ewma[0, k]):.3f}x "
                "its commissioning value against the siblings with both polytropic exponents "
                "unchanged: a pressure-gain error of this sensor (or a leak too small to bend the "
                "exponents); check the sensor",
                {**_pressure_evidence(p, k, self.config.window), "suspect": "pressure_gain",
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
        status = ctx.smoothed_status(result)  # est is result.smoothed
        measured = (status.codes == MEASURED)
        idx = np.flatnonzero(measured)
        if idx.size < 3:  # each needs two measured siblings
            return []
        # a change against the baseline: the calibration's error is the same then and now and cancels. Core's
        # excess unscreened: the figures this rule has always given (design note 73)
        t, s = np.asarray(est.friction_torque_mean, dtype=np.float64), change_sigma(est)
        excess_all, sigma_all = (a[idx] for a in friction_excess(t, s, measured, screened=False))
        out: list[Decision | Hold] = []
        # the references as they were at the start (a cylinder's own is set below only where it had none, and then
        # not read again this cycle), as Python floats: per cylinder numpy scalars were half the rule's time
        b = ctx.baseline
        bases, base_sigmas = b.friction_excess[idx].tolist(), b.friction_excess_sigma[idx].tolist()
        rows = zip(idx.tolist(), excess_all.tolist(), sigma_all.tolist(), bases, base_sigmas, strict=True)
        gain_latched, watched = ctx.latching(self.gain_check), ctx.watching(self.name)
        for k, excess, sigma, base, base_s in rows:
            if k + 1 in gain_latched:  # its pressure is suspect, and its friction rests on it
                continue
            if not math.isfinite(base):
                ctx.baseline = ctx.baseline.with_friction(k, excess, sigma, int(result.index))
                continue
            zf = (excess - base) / math.hypot(sigma, base_s)
            if not zf > cfg.friction_raise_sigmas and k + 1 not in watched:
                continue
            out.append(Decision(k + 1, "ring_wear", zf > cfg.friction_raise_sigmas,
                                zf < cfg.friction_clear_sigmas, cfg.raise_cycles, cfg.clear_cycles,
                                "alarm" if zf > 2 * cfg.friction_raise_sigmas else "warning",
                                detail=partial(self.explain, k, zf, excess, base,
                                               int(ctx.baseline.friction_cycle[k]), t[k], s[k])))
        return out

    @staticmethod
    def explain(k: int, zf: float, excess: float, base: float, since: int, torque: float, sigma: float
                ) -> tuple[str, dict]:
        return (f"cylinder {k + 1}: friction {100 * (excess - base):+.1f} % against its siblings since cycle {since}",
                {"source": "friction", "z_friction": _num(zf), "friction_excess": _num(excess),
                 "friction_excess_baseline": _num(base), "friction_torque_nm": _num(torque),
                 "friction_torque_sigma_nm": _num(sigma)})


def _num(v: Any) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None
