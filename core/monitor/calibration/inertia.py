"""Engine + load inertia J and a friction-vs-speed law from coast-downs (ignition off, cylinder pressure measured,
no load or a known one), pooled over several records: the commissioning step of issue 25.

Two things in a coast-down carry J; they are used separately, then combined:

1. **The speed ripple within each cycle against the measured gas torque** (core.monitor.calibration.ripple). Each
   tooth interval's kinetic energy E = omega^2 / 2 minus the same interval's one revolution earlier is regressed on
   the gas-torque work between them (the reciprocating J_rec = m_rec x'^2 from the spec taken out), with one free
   intercept per cycle. The intercept takes the cycle's mean deceleration and with it any friction or load level,
   so J comes from the ripple alone, independent of any friction law; whatever repeats every revolution (tooth-
   spacing error, a pressure offset) drops out of the difference. The speed noise sits in the regressand, so it
   does not bias J low (regressing the work on the speed would: errors in variables).

2. **The mean deceleration** (core.monitor.balance.coastdown, its one implementation) over the 720 deg from the middle of
   one cycle to the middle of the next: J a = T_gas,mean - T_f(W). In a plain coast-down a(W) is a smooth function
   of W, so J and c0 + c1 W are nearly collinear and this pins J weakly (TU/e ENGINEOFF2-6: 0.0075 +- 0.0049
   against 0.0208 +- 0.0012 from the ripple: 6 % of the information). It enters J only when it resolves J (sigma
   <= 10 %) and agrees with the ripple within 3 sigma; a torque step at one speed (ignition off) is what makes it
   resolve J.

``commission_inertia`` takes one ripple J per record and pools them with a random effect (DerSimonian-Laird). Its
sigma counts in full, not over sqrt(records), the larger of the records' spread beyond their own sigmas and the
change of the cycles' J with speed (a rigid engine's J does not depend on it; on the TU/e rig it moves 9 % between
1300 and 2400 rpm), plus the friction-ripple systematic (J re-fitted with the friction shaped like the model's loss
terms instead of constant) and, when the caller states it, the pressure gain's relative sigma (the gas torque, hence
J, scales with the gain). The friction law is then fitted with J fixed and its sigma carried into the covariance,
pooled over the records (one c0 + c1 W): a single coast-down covers a few hundred rpm, too little for a slope of its
own; the records' offsets about the pooled law beyond their cycles' scatter are added to c0's variance (over the
number of records). Arrays in, arrays out; SI units.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.kinematics import variable_inertia
from frictionwatch.core.model.terms import cylinder_samples
from frictionwatch.core.model.torques import gas_torque
from frictionwatch.core.monitor.balance.coastdown import (
    CoastdownFit,
    cycle_mean_deceleration,
    cycle_mean_speed,
    fit_inertia_friction,
)
from frictionwatch.core.monitor.balance.mean_balance import FRICTION_STEP, MID_SPEED_HALF_WIDTH, mid_cycle_speed
from frictionwatch.core.monitor.calibration.ripple import (
    CycleGeometry,
    RippleFit,
    RippleRows,
    fit_ripple_inertia,
    order_inertia,
    ripple_rows,
)
from frictionwatch.core.types import Cycle

# J's relative 1-sigma assumed for a spec nobody has commissioned: what this commissioning step pins J to from plain
# coast-downs on the TU/e 4GB10 (bench/inertia_from_coastdowns.py: 0.02077 +- 0.00124, 6.0 %; the records' J moves
# by 9 % between 1300 and 2400 rpm). A datasheet or CAD inertia is not known better than that without a coast-down.
INERTIA_UNCALIBRATED_REL = 0.06

TWO_PI = 2.0 * np.pi


def cycle_torque(grid: np.ndarray, pressure: np.ndarray, geometry: CycleGeometry, p_cc: float = 1.0e5) -> np.ndarray:
    """Total gas torque [N m] on ``grid`` (n,) from every cylinder's absolute pressure (z, n) [Pa]."""
    return gas_torque(grid, pressure, geometry.phases, geometry.params, geometry.area, p_cc).sum(axis=0)


@dataclass(frozen=True)
class CycleBalance:
    """The mean balance over the 720 deg from the middle of one cycle to the middle of the next (the calibration's
    own window; the monitor's transient balance weighs two whole cycles instead, design note 69): omega its mean
    speed [rad/s], decel its angle-averaged
    dw/dt from the two mid-cycle speeds [rad/s^2] (the same angle, so the gas-torque ripple drops out), gas_mean its
    mean gas torque [N m]; rec_inertia [kg m^2] the reciprocating inertia m_rec x'^2 averaged over the mid-cycle
    speed's window. That speed is the window's mean, and within the window J(theta) omega^2 / 2 stays (nearly)
    constant, so the speed at theta = 2 pi (where J = J0) is the mean times sqrt(1 + rec_inertia / J0): the true
    dw/dt is decel (1 + rec_inertia / J0) (simulated deutz-1cyl: friction -1.0 % at 3.8 sigma without it)."""

    omega: float
    decel: float
    gas_mean: float
    rec_inertia: float = 0.0

    def acceleration(self, inertia: float) -> float:
        """dw/dt [rad/s^2] for the rotating inertia J0 = ``inertia`` [kg m^2] (class docstring)."""
        return self.decel * (1.0 + self.rec_inertia / inertia)


def window_balance(mid_times: tuple[float, float], mid_speeds: tuple[float, float], torque_before: np.ndarray,
                   torque_after: np.ndarray, rec_inertia: float = 0.0) -> CycleBalance:
    """The balance of the window from theta = 2 pi of one cycle to theta = 2 pi of the next: mid_times [s] and
    mid_speeds [rad/s] there; torque_before, torque_after (n,) the two cycles' gas torque on their uniform grid over
    [0, 4 pi) (the window takes the second half of the first and the first half of the second); rec_inertia:
    ``CycleBalance.rec_inertia``."""
    n = torque_before.shape[0]
    if torque_after.shape != (n,) or n % 2:
        raise ValueError("both cycles' torques need the same even number of grid points")
    gas = 0.5 * (float(np.mean(torque_before[n // 2:])) + float(np.mean(torque_after[: n // 2])))
    omega = float(cycle_mean_speed(np.array([mid_times[0]]), np.array([mid_times[1]]))[0])
    decel = float(cycle_mean_deceleration(np.array(mid_speeds[0]), np.array(mid_speeds[1])))
    return CycleBalance(omega=omega, decel=decel, gas_mean=gas, rec_inertia=float(rec_inertia))


def pool_random_effects(values: np.ndarray, stds: np.ndarray) -> tuple[float, float, float]:
    """(mean, its sigma, between-record sigma) of per-record estimates with their sigmas: DerSimonian-Laird. The
    between-record variance is what the records' spread shows beyond their own sigmas; with one record it is 0."""
    x = np.asarray(values, dtype=np.float64)
    s = np.asarray(stds, dtype=np.float64)
    if x.ndim != 1 or x.shape != s.shape or x.shape[0] < 1 or not np.all(s > 0):
        raise ValueError("values and stds need one entry per record, stds > 0")
    w = 1.0 / (s * s)
    fixed = float(np.sum(w * x) / np.sum(w))
    q = float(np.sum(w * (x - fixed) ** 2))
    denom = float(np.sum(w) - np.sum(w * w) / np.sum(w))
    tau2 = max(0.0, (q - (x.shape[0] - 1)) / denom) if denom > 0 else 0.0
    ws = 1.0 / (s * s + tau2)
    return float(np.sum(ws * x) / np.sum(ws)), float(1.0 / np.sqrt(np.sum(ws))), float(np.sqrt(tau2))


def speed_trend(inertia: np.ndarray, omega: np.ndarray) -> float:
    """Half the change [kg m^2] of a straight line through (omega, J) of the cycles over the speeds they cover:
    a rigid engine's J does not depend on the speed (0 with fewer than 3 cycles)."""
    j = np.asarray(inertia, dtype=np.float64)
    w = np.asarray(omega, dtype=np.float64)
    if j.shape != w.shape or j.ndim != 1:
        raise ValueError("inertia and omega need one value per cycle")
    if j.shape[0] < 3 or np.ptp(w) <= 0:
        return 0.0
    slope = np.polyfit(w, j, 1)[0]
    return float(0.5 * abs(slope) * np.ptp(w))


@dataclass(frozen=True)
class CoastdownRecord:
    """One coast-down record: rows one cycle's ripple rows each (constant friction), shaped_rows the same with the
    model's friction shape (the systematic check); balance one CycleBalance per two consecutive usable cycles;
    load_group: -1 no load (friction only), g >= 0 a load that stayed on (its own d0 + d1 W in the mean balance,
    records of one g share it; the record is left out of the friction law's spread)."""

    name: str
    rows: tuple[RippleRows, ...]
    shaped_rows: tuple[RippleRows, ...]
    balance: tuple[CycleBalance, ...]
    load_group: int = -1


@dataclass(frozen=True)
class RecordInertia:
    """One record's ripple J: inertia, inertia_std [kg m^2] (the larger of the fit's sigma and its cycles' scatter
    over sqrt(cycles)); shaped: J with the model's friction shape [kg m^2]; fit: the ripple fit; speed_range [rad/s]
    of its mean balances; order_inertia, order_weight: J read from each half order alone (``order_inertia``)."""

    name: str
    inertia: float
    inertia_std: float
    shaped: float
    fit: RippleFit
    speed_range: tuple[float, float]
    order_inertia: np.ndarray
    order_weight: np.ndarray


@dataclass(frozen=True)
class InertiaCalibration:
    """J and the friction law from coast-downs (module docstring). All sigmas 1-sigma, [kg m^2] unless stated.

    inertia, inertia_std: the value used and its sigma (the parts below in quadrature); records: each record's
    ripple J; ripple_inertia: those pooled (random effect); between_std: the records' spread beyond their own
    sigmas; speed_systematic: the change of the cycles' J with their speed (``speed_trend``); ripple_std: the pooled
    ripple J's sigma with the larger of those two and shape_systematic (constant vs shaped friction) in full;
    order_systematic: the weighted spread of J read from each half order of each record (a diagnostic, not in
    sigma); gain_systematic: J times the stated relative gain sigma; mean_balance: the mean-balance fit with J free
    (None: too few rows), mean_std: its J sigma with the friction-step allowance, mean_weight: its share of the
    information on J (0..1), mean_used: whether it entered J (sigma <= 10 % and within 3 sigma of the ripple's);
    friction: c0 + c1 W (+ c2 W^2) pooled over the records with J fixed and its sigma carried (CoastdownFit);
    friction_between_std [N m]: the unloaded records' spread about it beyond their cycles' scatter (added to c0's
    variance over the number of records); record_offsets [N m]: each unloaded record's mean resisting torque minus
    the law at its speeds (NaN for a loaded record)."""

    inertia: float
    inertia_std: float
    records: tuple[RecordInertia, ...]
    ripple_inertia: float
    ripple_std: float
    between_std: float
    speed_systematic: float
    order_systematic: float
    shape_systematic: float
    gain_systematic: float
    mean_balance: CoastdownFit | None
    mean_std: float
    mean_weight: float
    mean_used: bool
    friction: CoastdownFit
    friction_between_std: float
    record_offsets: np.ndarray

    def friction_at(self, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T_f, 1-sigma) [N m] of the pooled law at speeds ``omega`` [rad/s]."""
        return self.friction.friction_torque(omega), self.friction.friction_std(omega)


def record_inertia(record: CoastdownRecord) -> RecordInertia:
    """J of one record from its ripple (one free friction level per cycle)."""
    fit = fit_ripple_inertia(record.rows)
    shaped = fit_ripple_inertia(record.shaped_rows, shaped=True)
    c = fit.per_cycle.shape[0]
    scatter = float(np.std(fit.per_cycle, ddof=1) / np.sqrt(c)) if c >= 2 else 0.0
    w = np.array([b.omega for b in record.balance])
    span = (float(w.min()), float(w.max())) if w.size else (float("nan"), float("nan"))
    j_n, w_n = order_inertia(record.rows)
    return RecordInertia(record.name, fit.inertia, max(fit.inertia_std, scatter), shaped.inertia, fit, span, j_n, w_n)


def commission_inertia(records: Sequence[CoastdownRecord], n_friction: int = 2, gain_rel_std: float = 0.0,
                       resolve_rel: float = 0.1, min_span: float = 0.03) -> InertiaCalibration:
    """J, its sigma and the friction law from coast-down records (module docstring).

    n_friction: terms of the friction polynomial in W (2: c0 + c1 W); gain_rel_std: the pressure gain's relative
    1-sigma (J scales with it; 0 = J stated at the gain used); resolve_rel: the mean-balance J enters only when its
    sigma is at most this fraction of it; min_span: the pooled cycles' speeds must span this fraction of their mean
    for a speed-dependent law (else a constant).
    """
    if not records:
        raise ValueError("no coast-down records")
    per = tuple(record_inertia(r) for r in records)
    bad = [p.name for p in per if not (p.inertia > 0 and p.inertia_std <= resolve_rel * p.inertia)]
    if bad:
        # a balanced engine's gas torque has little half-order content (a 4-cylinder fires at order 2): the ripple
        # does not resolve J there (simulated k9k-4cyl: J < 0)
        raise ValueError(f"the speed ripple does not resolve J in {', '.join(bad)} (sigma above "
                         f"{100 * resolve_rel:.0f} % or J <= 0): too little half-order gas torque")
    j_r, s_r, between = pool_random_effects(np.array([p.inertia for p in per]), np.array([p.inertia_std for p in per]))
    shape_sys = float(abs(np.mean([p.shaped - p.inertia for p in per])))
    gain_sys = float(gain_rel_std) * j_r
    # J read from each half order alone, weighted by its gas-torque content: a diagnostic, not in sigma (on the
    # rigid simulated TU/e the orders spread by 6-10 % while the J of all orders together is within 0.4 %)
    j_n = np.concatenate([p.order_inertia for p in per])
    w_n = np.concatenate([p.order_weight for p in per])
    order_sys = float(np.sqrt(np.sum(w_n * (j_n - np.sum(w_n * j_n) / np.sum(w_n)) ** 2) / np.sum(w_n)))
    # a rigid engine's J does not depend on the speed: each cycle's J against its speed (all records), half the
    # change of the fitted line over the speeds covered. It and the records' spread (the same dependence seen
    # record by record) count in full, not over sqrt(records): a systematic, not a random draw per record
    trend = speed_trend(np.concatenate([p.fit.per_cycle for p in per]),
                        np.array([r.omega for rec in records for r in rec.rows]))
    s_ripple = float(np.sqrt(s_r**2 + max(between, trend) ** 2 + shape_sys**2))
    bal = [b for r in records for b in r.balance]
    if len(bal) < 2:
        raise ValueError(f"{len(bal)} mean-balance rows (two consecutive motored cycles each): too few for a friction law")
    a = np.array([b.acceleration(j_r) for b in bal])  # the first-order correction needs J0 only roughly
    w = np.array([b.omega for b in bal])
    y = np.array([b.gas_mean for b in bal])
    grp = np.concatenate([np.full(len(r.balance), r.load_group, dtype=np.int64) for r in records])
    if not np.all(np.isfinite(a) & np.isfinite(w) & np.isfinite(y)):
        raise ValueError("a cycle's mean balance is not finite; leave that cycle out of its record")
    free = grp < 0
    n_fr = n_friction if np.any(free) and np.ptp(w[free]) >= min_span * w[free].mean() else 1
    mean_fit, mean_std = _mean_balance(a, w, y, grp, n_fr)
    mean_weight, mean_used, j, s = 0.0, False, j_r, s_ripple
    if mean_fit is not None and np.isfinite(mean_std) and mean_std > 0:
        wm, wr = 1.0 / mean_std**2, 1.0 / s_ripple**2
        mean_weight = wm / (wm + wr)
        consistent = abs(mean_fit.inertia - j_r) <= 3.0 * np.hypot(mean_std, s_ripple)
        mean_used = bool(consistent and mean_std <= resolve_rel * abs(mean_fit.inertia))
        if mean_used:
            j = (wm * mean_fit.inertia + wr * j_r) / (wm + wr)
            s = float(1.0 / np.sqrt(wm + wr))
    s_total = float(np.hypot(s, gain_sys))
    friction = fit_inertia_friction(a, w, y, grp, n_friction=n_fr, inertia=j, inertia_std=s_total)
    # the unloaded records' offsets about the pooled law beyond what their cycles' scatter explains
    resid = y - j * a - friction.friction_torque(w)
    sizes = np.array([len(r.balance) for r in records])
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    have = np.array([r.load_group < 0 and len(r.balance) > 0 for r in records])
    offsets = np.array([resid[bounds[k]:bounds[k + 1]].mean() if have[k] else np.nan for k in range(len(records))])
    dof = max(int(np.count_nonzero(free)) - (n_fr + (1 if mean_used else 0)), 1)
    s2 = float(resid[free] @ resid[free]) / dof
    f_between = float(np.sqrt(max(0.0, np.var(offsets[have], ddof=1) - s2 * np.mean(1.0 / sizes[have])))) \
        if np.count_nonzero(have) >= 2 else 0.0
    if f_between > 0:
        cov = friction.covariance.copy()
        cov[1, 1] += f_between**2 / np.count_nonzero(have)
        friction = CoastdownFit(friction.inertia, friction.inertia_std, friction.friction_coeffs,
                                friction.load_coeffs, cov, friction.residual_rms, friction.n_cycles)
    return InertiaCalibration(inertia=float(j), inertia_std=s_total, records=per, ripple_inertia=j_r,
                              mean_std=mean_std,
                              ripple_std=s_ripple, between_std=between, speed_systematic=trend,
                              order_systematic=order_sys,
                              shape_systematic=shape_sys,
                              gain_systematic=gain_sys, mean_balance=mean_fit, mean_weight=float(mean_weight),
                              mean_used=mean_used, friction=friction, friction_between_std=f_between,
                              record_offsets=offsets)


def _mean_balance(a: np.ndarray, w: np.ndarray, y: np.ndarray, grp: np.ndarray,
                  n_fr: int) -> tuple[CoastdownFit | None, float]:
    """The mean balance with J free (core.monitor.balance.coastdown) and J's sigma with an allowance for a friction step: a
    loaded record's torque step (ignition off) also steps its friction (the cylinder pressure loads rings and
    bearings), which its smooth d0 + d1 W cannot follow and J absorbs: FRICTION_STEP of its resisting torque over the
    span of its dw/dt, as core.monitor.balance.mean_balance allows. (None, inf) with too few rows."""
    n_par = 1 + n_fr + 2 * np.unique(grp[grp >= 0]).shape[0]
    if a.shape[0] < n_par + 2:
        return None, float("inf")
    fit = fit_inertia_friction(a, w, y, grp, n_friction=n_fr)
    std = fit.inertia_std
    for g in np.unique(grp[grp >= 0]):
        sel = grp == g
        span = float(np.ptp(a[sel]))
        level = float(np.mean(np.abs(y[sel] - fit.inertia * a[sel])))
        std = float(np.hypot(std, FRICTION_STEP * level / span)) if span > 0 else float("inf")
    return fit, std


def geometry_of(model: EngineModel) -> CycleGeometry:
    """The engine geometry the estimate needs, from a model's spec."""
    spec = model.spec
    return CycleGeometry(np.asarray(spec.firing_angles, dtype=np.float64), spec.kinematics_params(),
                         float(spec.piston_area), float(spec.reciprocating_mass))


def friction_shape(model: EngineModel, grid: np.ndarray, pressure: np.ndarray, omega: float) -> np.ndarray:
    """The model's friction torque over the cycle (its loss terms at their coefficients, every cylinder with its
    pressure (z, n) [Pa] at mean speed ``omega`` [rad/s]) divided by its mean: a shape of mean 1 on ``grid``."""
    spec = model.spec
    consts = spec.friction_params()
    total = np.zeros(grid.shape[0])
    for k in range(spec.n_cyl):
        p = pressure[k] if np.all(np.isfinite(pressure[k])) else np.full(grid.shape[0], 1.0e5)
        s = cylinder_samples(grid - spec.firing_angles[k], omega, p - 1.0e5, consts)
        total += model.coefficients[k] @ model.terms.evaluate(s, consts)
    return total / total.mean()


def interval_mask(tooth_angle: np.ndarray, tooth_index: np.ndarray) -> np.ndarray:
    """Intervals to use (m - 1,): not across the missing-tooth gap and not touching the edge on either side of it
    (a VR sensor distorts those: TU/e 290/240 us instead of 340)."""
    d = np.diff(tooth_angle)
    pitch = float(np.min(d))
    last = int(np.max(tooth_index))
    start = tooth_index[:-1]
    return (d < 1.5 * pitch) & (start != 0) & (start != last) & (start != last - 1)


def coastdown_record(name: str, cycles: Sequence[Cycle], model: EngineModel, motored_only: bool = True,
                     min_rows: int = 20, load_group: int = -1) -> CoastdownRecord | None:
    """One record's ripple rows (one per usable motored cycle) and mean balances (one per two consecutive usable
    cycles) from its assembled cycles (core.types.Cycle, pressure of every instrumented cylinder on the cycle grid).

    A rigid (single-node) shaft line and a pressure sensor in every cylinder are needed (ValueError otherwise); a cycle with a NaN pressure sample or fewer than
    ``min_rows`` paired intervals is left out. A fired cycle (positive mean gas torque) never gives ripple rows (its friction ripple is large and not
    modelled) and enters the mean balances only when ``motored_only`` is False (a torque step: ignition off).
    load_group: ``CoastdownRecord.load_group``. None when no ripple row is left."""
    geo = geometry_of(model)
    spec = model.spec
    if np.asarray(spec.node_inertia).shape[0] != 1:
        # the ripple reads the inertia that moves with the wheel at the half orders' frequencies: behind a soft
        # coupling that is not the total (simulated maruti-3cyl, flywheel + soft shaft to the dyno: -68 %)
        raise ValueError(f"{spec.name} has a {np.asarray(spec.node_inertia).shape[0]}-node shaft line; J from the "
                         "coast-down ripple needs a rigid (single-node) one")
    half = np.linspace(-MID_SPEED_HALF_WIDTH, MID_SPEED_HALF_WIDTH, 181)
    rec_window = float(np.mean(variable_inertia(TWO_PI + half, geo.phases, geo.params, geo.m_rec, 0.0)[0]))
    rows, shaped, bal = [], [], []
    prev = None  # (index, mid time, mid speed, torque) of the last cycle in the balance
    for c in cycles:
        p = np.asarray(c.pressure, dtype=np.float64)
        if not np.any(np.isfinite(p), axis=1).all():
            raise ValueError(f"{name}: cylinder(s) {np.flatnonzero(~np.any(np.isfinite(p), axis=1)) + 1} have no "
                             "pressure; J from the ripple needs every cylinder's gas torque")
        if not np.all(np.isfinite(p)):
            continue
        t = c.tooth_ticks.astype(np.float64) / c.tick_hz
        torque = cycle_torque(c.grid, p, geo)
        fired = float(np.mean(torque)) > 0
        if fired and motored_only:
            continue
        keep = interval_mask(c.tooth_angle, c.tooth_index)
        r = ripple_rows(c.tooth_angle, t, keep, c.grid, torque, np.ones_like(torque), geo)
        if r.d_energy.shape[0] < min_rows:
            continue
        if not fired:
            rows.append(r)
            shaped.append(ripple_rows(c.tooth_angle, t, keep, c.grid, torque,
                                      friction_shape(model, c.grid, p, r.omega), geo))
        mid = (float(np.interp(TWO_PI, c.tooth_angle, t)), mid_cycle_speed(spec, c), torque)
        if prev is not None and prev[0] == c.index - 1 and np.isfinite(prev[2]) and np.isfinite(mid[1]):
            bal.append(window_balance((prev[1], mid[0]), (prev[2], mid[1]), prev[3], torque, rec_window))
        prev = (c.index, *mid)
    if not rows:
        return None
    return CoastdownRecord(name, tuple(rows), tuple(shaped), tuple(bal), int(load_group))
