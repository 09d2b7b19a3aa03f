"""Alerts of one engine from its per-cycle results (issue 17 item 4): decision logic only, no physics.

``AlertEngine.update(result)`` reads a ``CycleResult`` and returns the events of that cycle (raised, updated,
cleared). Each alert kind is a statistic per cylinder (or for the engine) with hysteresis: an alert is raised after
the statistic is above ``raise`` for ``raise_cycles`` consecutive cycles and cleared after it is below ``clear`` for
``clear_cycles`` (between the two nothing changes: no flapping). What each kind reads:

    blow_by      the leak signature of the pressure (core.monitor.checks.ring_pressure): the compression exponent down and
                 the expansion exponent up against the siblings, as a change from the cylinder's commissioning
                 baseline (service.alert_baseline), in units of its own per-cycle scatter: Z = EWMA of the combined
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
from dataclasses import asdict, dataclass, field, replace

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.report.figure_status import friction_status, split_flag
from frictionwatch.core.monitor.report.results import PA_PER_BAR, CycleResult, change_sigma
from frictionwatch.service.alert_baseline import INDICATORS, Baseline, BaselineLearner
from frictionwatch.service.alert_rules import Latch, leak_statistics

KINDS = ("ring_wear", "blow_by", "misfire", "sensor_fault", "model_misfit")
RING_KINDS = ("ring_wear", "blow_by")
BASELINE_KEYS = ("leak", "gain", "friction", "core_blow_by", "core_ring_wear")  # statistics a rebaseline restarts


@dataclass(frozen=True)
class AlertConfig:
    """Thresholds. Measured on K9K logs at 1700 rpm / 0.69 (60 cycles each, all default effects): per-cycle scatter
    of the sibling-relative indicators 0.0009-0.0014 (compression ratio, n_compression) and 0.0018-0.0025
    (n_expansion); a 3 % leak in cylinder 2 moved n_compression -0.0021, n_expansion +0.0033 (leak_floor's
    effect 0.0026); a load step 0.69 -> 0.40 moved no cylinder's effect by more than 0.0003 in the leak direction.
    Detection delays and false alarms: bench/alert_detection.py.

    baseline_cycles: healthy cycles the commissioning baseline learns over (cycles with a misfire or a sensor flag
    are not used; an operating-point change is not a reason: the sibling-relative indicators move by less than a
    third of their per-cycle scatter over a K9K load step 0.69 -> 0.40, and the monitor flags a change every ~20
    cycles of a steady run with 3 % COV); skip_cycles: first cycles never used. band_width: relative half-width in
    mean IMEP of a load band of the baseline (service.alert_baseline): a step 0.75 -> 0.45 on genset-v20 moves the
    sibling-relative leak effect of single cylinders by up to 0.0028 (the shaft's twist, core.monitor.checks.ring_pressure),
    smoothly with the load; +-10 % of IMEP is about a fifth of that step, so its share stays under leak_floor.
    settle_cycles: after the mean IMEP moves by more than half a band, the pressure statistics and the learning
    wait this many usable cycles, and a cycle the monitor flags operating_point_changed is not used: on genset-v20
    the cycle a step 0.45 -> 0.75 falls in read cylinder 5's n_compression 0.27 off (its trace spliced across the
    step: 0.27 x 0.02 moved the EWMA by -0.005), enough to raise a false blow_by 9 cycles later.
    window: EWMA cycles of the pressure statistics; raise_z / clear_z: their raise and clear levels (standard
    errors); alarm_z: severity alarm; leak_floor: the mean exponent change (-dn_c + dn_e) / 2 a leak alert needs
    besides Z (a persistent shift too small to matter, a load step's, is not a leak); gain_floor: |d ln p| of the
    compression ratio a gain check needs. raise_cycles / clear_cycles: the hysteresis counts.
    friction_raise_sigmas / friction_clear_sigmas: a cylinder's friction excess change in combined sigmas.
    misfire_window: EWMA cycles of the misfire rate; misfire_raise / misfire_clear / misfire_alarm: rates.
    flag_raise_cycles: consecutive flagged cycles that raise a flag-based alert (sensor, misfit, core flags).
    max_history: cleared alerts kept in memory (the store keeps them all).
    """

    baseline_cycles: int = 200
    band_width: float = 0.1
    settle_cycles: int = 50
    skip_cycles: int = 5
    window: float = 50.0
    raise_z: float = 6.0
    clear_z: float = 3.0
    alarm_z: float = 20.0
    leak_floor: float = 0.001
    gain_floor: float = 0.01
    raise_cycles: int = 10
    clear_cycles: int = 50
    friction_raise_sigmas: float = 3.0
    friction_clear_sigmas: float = 1.5
    misfire_window: float = 100.0
    misfire_raise: float = 0.03
    misfire_clear: float = 0.005
    misfire_alarm: float = 0.2
    flag_raise_cycles: int = 5
    max_history: int = 1000


@dataclass
class Alert:
    """One alert (the contract's shape; ``to_dict`` without engine_id: the service adds it). 1-based cylinder."""

    alert_id: int
    cylinder: int | None
    kind: str
    severity: str
    state: str
    raised_cycle: int
    raised_at_s: float
    message: str
    evidence: dict = field(default_factory=dict)
    cleared_cycle: int | None = None
    acknowledged_by: str | None = None

    def to_dict(self) -> dict:
        d = asdict(self)
        d["evidence"] = dict(self.evidence)
        return d


@dataclass(frozen=True)
class AlertEvent:
    """kind: raised | updated | cleared; alert: a snapshot at the event (later changes do not reach it)."""

    kind: str
    alert: Alert


def _snapshot(a: Alert) -> Alert:
    return replace(a, evidence=dict(a.evidence))


class AlertEngine:
    """The alerts of one engine (module doc). Not thread-safe: one ingest thread calls ``update``; a reader takes
    ``active()`` / ``history()`` snapshots under the caller's lock."""

    def __init__(self, spec: EngineSpec, config: AlertConfig | None = None, baseline: Baseline | None = None):
        self.spec, self.config = spec, config or AlertConfig()
        z = spec.n_cyl
        if baseline is not None and baseline.mean.shape != (len(INDICATORS), z):
            raise ValueError(f"baseline is for {baseline.mean.shape[1]} cylinders; the engine has {z}")
        self.baseline: Baseline | None = baseline
        self._learner = BaselineLearner(z)
        self._next_id = 1
        self._open: dict[tuple[str, int | None], Alert] = {}
        self._history: list[Alert] = []
        self._latches: dict[tuple[str, int | None], Latch] = {}
        self._ewma = np.zeros((len(INDICATORS), z))
        self._ewma_n = 0
        self._misfire = np.zeros(z)
        self._imep_ref, self._settle = math.nan, 0  # the load-change hold of the pressure statistics
        self._cycles = 0
        self._last_cycle = -1

    # ---- public ---------------------------------------------------------------------------------------------
    def active(self) -> list[Alert]:
        return [_snapshot(a) for a in sorted(self._open.values(), key=lambda a: a.alert_id)]

    def history(self) -> list[Alert]:
        return [_snapshot(a) for a in sorted([*self._history, *self._open.values()], key=lambda a: a.alert_id)]

    def acknowledge(self, alert_id: int, by: str) -> Alert:
        """Mark an open alert acknowledged (it stays open until its evidence clears); KeyError for an unknown or
        cleared id."""
        for a in self._open.values():
            if a.alert_id == alert_id:
                a.state, a.acknowledged_by = "acknowledged", str(by)[:80]
                return _snapshot(a)
        raise KeyError(f"no open alert {alert_id}")

    def rebaseline(self) -> list[AlertEvent]:
        """Learn a new commissioning baseline from the next cycle on (after an overhaul: the state now is the normal
        one); the ring and pressure alerts that rest on the old baseline are cleared (their events returned)."""
        self.baseline, self._learner = None, BaselineLearner(self.spec.n_cyl)
        self._ewma[:], self._ewma_n = 0.0, 0
        events = []
        for key in [k for k in self._open if k[0] in BASELINE_KEYS]:
            self._open[key].evidence["rebaselined"] = True
            events.append(self._clear(key, self._last_cycle))
        for key in [k for k in self._latches if k[0] in BASELINE_KEYS]:
            del self._latches[key]
        return events

    def update(self, result: CycleResult) -> list[AlertEvent]:
        """Fold one cycle; the events it causes, in order."""
        z = self.spec.n_cyl
        self._cycles += 1
        self._last_cycle = int(result.index)
        flags = set(result.flags)
        cyl_flags: list[set[str]] = [set() for _ in range(z)]
        engine_flags: set[str] = set()
        for f in flags:
            kind, cyl = split_flag(f)
            (cyl_flags[cyl - 1] if cyl is not None and 1 <= cyl <= z else engine_flags).add(kind)
        events: list[AlertEvent] = []
        events += self._misfires(result, cyl_flags)
        events += self._flag_alerts(result, cyl_flags, engine_flags)
        events += self._pressure(result, cyl_flags)
        events += self._friction(result)
        return events

    # ---- kinds ----------------------------------------------------------------------------------------------
    def _misfires(self, result: CycleResult, cyl_flags: list[set[str]]) -> list[AlertEvent]:
        cfg = self.config
        g = 1.0 / cfg.misfire_window
        hit = np.array([1.0 if "misfire" in f else 0.0 for f in cyl_flags])
        self._misfire += g * (hit - self._misfire)
        out = []
        for k in range(self.spec.n_cyl):
            rate = float(self._misfire[k])
            sev = "alarm" if rate >= cfg.misfire_alarm else "warning"
            out += self._decide(("misfire", k + 1), "misfire", rate >= cfg.misfire_raise, rate < cfg.misfire_clear, 1, 1,
                                result, sev, f"cylinder {k + 1} misfires: {100 * rate:.1f} % of recent cycles",
                                {"misfire_rate": rate, "window_cycles": cfg.misfire_window})
        return out

    def _flag_alerts(self, result: CycleResult, cyl_flags: list[set[str]], engine_flags: set[str]
                     ) -> list[AlertEvent]:
        cfg, out = self.config, []
        k_on, k_off = cfg.flag_raise_cycles, cfg.clear_cycles
        out += self._decide(("model_misfit", None), "model_misfit", "model_misfit" in engine_flags,
                            "model_misfit" not in engine_flags, k_on, k_off, result, "warning",
                            "the speed fit is worse than its noise model allows: the engine model does not "
                            "describe this engine (friction figures may be biased)",
                            {"chi2_reduced": result.cycle.chi2_reduced})
        wheel = sorted(f for f in engine_flags if f.startswith("sensor_"))
        out += self._decide(("sensor_fault", None), "sensor_fault", bool(wheel), not wheel, k_on, k_off, result, "warning",
                            "sensor check on the engine: " + ", ".join(wheel or ["-"]), {"flags": wheel})
        ring = result.ring
        for k, fl in enumerate(cyl_flags):
            sensor = sorted(f for f in fl if f.startswith("sensor_") or f == "pressure_repaired")
            stuck = ring is not None and not (np.isfinite(ring.n_compression[k]) and ring.n_compression[k] > 0.5)
            if stuck:
                sensor.append("pressure_stuck_or_dropped")
            out += self._decide(("sensor_fault", k + 1), "sensor_fault", bool(sensor), not sensor, k_on, k_off, result, "warning",
                                f"sensor check on cylinder {k + 1}: " + ", ".join(sensor or ["-"]),
                                {"flags": sensor, "n_compression": _num(ring.n_compression[k]) if ring else None})
            if self.baseline is None:  # before a baseline: the core's sibling-floor flags (core.monitor.checks.condition)
                for kind in RING_KINDS:
                    out += self._decide(("core_" + kind, k + 1), kind, kind in fl, kind not in fl, 4 * k_on, k_off, result,
                                        "warning", f"cylinder {k + 1}: {kind.replace('_', ' ')} against its "
                                        "siblings (before a commissioning baseline)", {"source": "core_flag"})
        return out

    def _pressure(self, result: CycleResult, cyl_flags: list[set[str]]) -> list[AlertEvent]:
        cfg, ring = self.config, result.ring
        if ring is None:
            return []
        x = ring.compared()  # rows as INDICATORS
        imep = _mean_imep(result)
        usable = (np.all(np.isfinite(x)) and imep > 0.0 and self._cycles > cfg.skip_cycles  # not motored
                  and "operating_point_changed" not in result.flags  # a cycle spliced across a step
                  and not any(f & {"misfire"} or any(s.startswith("sensor_") for s in f) for f in cyl_flags))
        if not usable:
            return []
        if self._load_moved(imep):  # a load change: the statistics and the learning wait for it to settle
            self._settle = cfg.settle_cycles
        if self._settle > 0:
            self._settle -= 1
            self._suspended(imep, "settling after a load change")
            return []
        band = None if self.baseline is None else self.baseline.band_for(imep)
        if band is None:  # not commissioned at this load: learn it; the pressure statistics wait (module doc)
            self._learn(x, int(result.index), imep)
            self._suspended(imep, "not commissioned at this load: learning")
            return []
        self._ewma_n += 1
        g = max(1.0 / cfg.window, 1.0 / self._ewma_n)
        self._ewma += g * (x - band.mean - self._ewma)
        st = leak_statistics(self._ewma, band, g)
        out = []
        for k in range(self.spec.n_cyl):
            sensor = any(s.startswith("sensor_") for s in cyl_flags[k])
            ev = {"source": "pressure", "z_leak": st.z_leak[k], "n_compression_change": self._ewma[1, k],
                  "n_expansion_change": self._ewma[2, k], "compression_ratio_change_ln": self._ewma[0, k],
                  "expansion_deficit_change_ln": self._ewma[3, k], "z_compression_ratio": st.z_ratio[k],
                  "baseline_cycles": band.cycles, "window_cycles": cfg.window, "commissioned_at_this_load": True,
                  "suspended": None,
                  "imep_bar": imep / PA_PER_BAR, "load_band_imep_bar": [band.imep_lo_pa / PA_PER_BAR,
                                                                        band.imep_hi_pa / PA_PER_BAR]}
            ev = {key: (_num(v) if isinstance(v, float | np.floating) else v) for key, v in ev.items()}
            ev["load_band_imep_bar"] = [_num(v) for v in ev["load_band_imep_bar"]]
            leak_on = st.z_leak[k] > cfg.raise_z and st.effect[k] > cfg.leak_floor
            leak_off = st.z_leak[k] < cfg.clear_z
            sev = "alarm" if st.z_leak[k] >= cfg.alarm_z and st.effect[k] > 3 * cfg.leak_floor else "warning"
            kind = "sensor_fault" if sensor else "blow_by"
            msg = (f"cylinder {k + 1}: leak-like pressure signature (compression exponent "
                   f"{self._ewma[1, k]:+.4f}, expansion exponent {self._ewma[2, k]:+.4f} from commissioning)"
                   + (" with a flagged sensor: a TDC or pegging error is suspected" if sensor else ""))
            out += self._decide(("leak", k + 1), kind, leak_on, leak_off, cfg.raise_cycles, cfg.clear_cycles, result, sev,
                                msg, ev)
            ratio_on = (abs(st.z_ratio[k]) > cfg.raise_z and abs(self._ewma[0, k]) > cfg.gain_floor
                        and st.z_leak[k] < cfg.clear_z)
            ratio_off = abs(st.z_ratio[k]) < cfg.clear_z or st.z_leak[k] > cfg.raise_z
            out += self._decide(("gain", k + 1), "sensor_fault", ratio_on, ratio_off, cfg.raise_cycles, cfg.clear_cycles, result,
                                "info", f"cylinder {k + 1}: compression pressure {math.exp(self._ewma[0, k]):.3f}x "
                                "its commissioning value against the siblings with both polytropic exponents "
                                "unchanged: a pressure-gain error of this sensor (or a leak too small to bend the "
                                "exponents); check the sensor", {**ev, "suspect": "pressure_gain",
                                                                 "gain_estimate": _num(math.exp(self._ewma[0, k]))})
        return out

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

    def _suspended(self, imep: float, why: str) -> None:
        """Say so in the evidence of the open pressure alerts: their statistics hold still (neither raised nor
        cleared) while the load settles and at a load not yet commissioned."""
        for key, a in self._open.items():
            if key[0] in ("leak", "gain"):
                a.evidence.update({"commissioned_at_this_load": False, "suspended": why,
                                   "imep_bar": _num(imep / PA_PER_BAR), "learning_cycles": self._learner.n})

    def _friction(self, result: CycleResult) -> list[AlertEvent]:
        """Ring wear from the friction where it is measured: excess over the measured siblings' mean vs its value
        at the first measurement, in combined sigmas."""
        cfg, est = self.config, result.smoothed
        if self.baseline is None:
            return []
        status = friction_status(est, result.flags)
        measured = np.array([c.status == "measured" for c in status.cylinders])
        # a change against the baseline: the calibration's error is the same then and now and cancels
        t, s = est.friction_torque_mean, change_sigma(est)
        out = []
        for k in np.flatnonzero(measured):
            gain = self._latches.get(("gain", int(k) + 1))
            if gain is not None and gain.active:  # its pressure is suspect, and its friction rests on that pressure
                continue
            others = np.flatnonzero(measured)
            others = others[others != k]
            if others.size < 2:
                continue
            ref = float(np.mean(t[others]))
            excess = t[k] / ref - 1.0
            sigma = math.sqrt(s[k] ** 2 + float(np.mean(s[others] ** 2)) / others.size) / ref
            if not np.isfinite(self.baseline.friction_excess[k]):
                self.baseline = self.baseline.with_friction(k, excess, sigma, int(result.index))
                continue
            base, base_s = self.baseline.friction_excess[k], self.baseline.friction_excess_sigma[k]
            zf = (excess - base) / math.hypot(sigma, base_s)
            out += self._decide(("friction", k + 1), "ring_wear", zf > cfg.friction_raise_sigmas,
                                zf < cfg.friction_clear_sigmas, cfg.raise_cycles, cfg.clear_cycles, result,
                                "alarm" if zf > 2 * cfg.friction_raise_sigmas else "warning",
                                f"cylinder {k + 1}: friction {100 * (excess - base):+.1f} % against its siblings since "
                                f"cycle {int(self.baseline.friction_cycle[k])}",
                                {"source": "friction", "z_friction": _num(zf), "friction_excess": _num(excess),
                                 "friction_excess_baseline": _num(base), "friction_torque_nm": _num(t[k]),
                                 "friction_torque_sigma_nm": _num(s[k])})
        return out

    # ---- hysteresis and the alert records -----------------------------------------------------------------
    def _decide(self, key: tuple[str, int | None], kind: str, on: bool, off: bool, k_on: int, k_off: int,
                result: CycleResult, severity: str, message: str, evidence: dict) -> list[AlertEvent]:
        """One statistic's hysteresis step (``key``: the statistic and cylinder; one open alert of ``kind`` per
        key; the kind is fixed when it is raised)."""
        key = (key[0], None if key[1] is None else int(key[1]))  # a numpy index never reaches the JSON
        latch = self._latches.setdefault(key, Latch())
        change = latch.step(bool(on), bool(off), k_on, k_off, int(result.index))
        akey = key
        if change == "raise":
            a = Alert(self._next_id, key[1], kind, severity, "active", int(result.index), float(result.t_start),
                      message, {**evidence, "first_evidence_cycle": latch.since})
            self._next_id += 1
            self._open[akey] = a
            return [AlertEvent("raised", _snapshot(a))]
        a = self._open.get(akey)
        if a is None:
            return []
        if change == "clear":
            return [self._clear(akey, int(result.index))]
        a.evidence.update(evidence)
        a.message = message
        if _rank(severity) > _rank(a.severity):  # escalate, never de-escalate while open (no flapping)
            a.severity = severity
            return [AlertEvent("updated", _snapshot(a))]
        return []

    def _clear(self, akey: tuple, cycle: int) -> AlertEvent:
        a = self._open.pop(akey)
        a.state, a.cleared_cycle = "cleared", cycle
        self._history.append(a)
        del self._history[:-self.config.max_history]
        return AlertEvent("cleared", _snapshot(a))


def _rank(severity: str) -> int:
    return ("info", "warning", "alarm").index(severity)


def _mean_imep(result: CycleResult) -> float:
    """The engine's mean IMEP this cycle [Pa] over the cylinders that have one (NaN: none), the load the bands key on."""
    imep = np.asarray(result.imep, dtype=float)
    ok = np.isfinite(imep)
    return float(np.mean(imep[ok])) if ok.any() else math.nan


def _num(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None
