"""Engine + load inertia J and a friction-vs-speed law from coast-downs (ignition off, cylinder pressure measured,
no load or a known one), pooled over several records: the commissioning step of issue 25.

Two things in a coast-down carry J, and they are used separately, then combined:

1. **The speed ripple within each cycle against the known gas torque** (``ripple_rows``, ``fit_ripple_inertia``).
   Over one cycle, with a friction (+ load) torque tau that is constant within the cycle,

       J0 E(theta) + J_rec(theta) E(theta) = C + G(theta) - tau theta,     E = omega^2 / 2,  G = int T_gas dtheta

   (physics.md §3: d/dtheta of J(theta) E is the torque; J_rec = m_rec x'^2 the reciprocating part, known from the
   spec). Differencing each tooth interval with the same interval one revolution later, D(theta) = E(theta + 2 pi)
   - E(theta) for theta in [0, 2 pi), removes everything that repeats every revolution: the tooth-spacing error (a
   fixed angle error of each tooth), a constant pressure offset (its torque is first order), and leaves

       D(theta) = u dG(theta) - 2 pi u tau,      u = 1 / J0,
       dG(theta) = int_theta^{theta + 2 pi} T_gas - [J_rec E](theta + 2 pi) + [J_rec E](theta).

   D is regressed on dG with one free intercept per cycle: the intercept takes the cycle's mean deceleration (and
   with it any friction or load level), so J0 comes from the ripple alone, independent of any friction law. The
   speed samples' noise sits in D (the regressand), not in the regressor, so it does not bias J low (regressing
   dG on D would: errors in variables). Each tooth interval's E is that interval's mean speed squared; dG is averaged
   over the same interval.

2. **The mean deceleration** (core.monitor.coastdown, its one implementation): per cycle J a = T_gas,mean - T_f(W).
   In a plain coast-down a(W) is a smooth function of W, so J and a + b W are nearly collinear: it pins J only
   weakly (TU/e ENGINEOFF2-6: +-0.003 against +-0.0004 from the ripple).

``commission_inertia`` takes J from the ripple of every record (one J per record, then pooled across records with
a random effect: the records' spread, not only each fit's formula, sets sigma), combines it with the mean-balance J
by inverse variance and says which dominates, and then fits the friction law with that J and its sigma carried.
The friction law is pooled over the records (one a + b W): a single coast-down covers a few hundred rpm, too little
for its own slope; the records' offsets from the pooled law scale its covariance (Birge ratio) when they exceed
the fit's own scatter.

Systematics carried in J's sigma: the friction ripple within the cycle (J re-fitted with the friction torque shaped
like the model's loss terms instead of constant; the difference), and, when the caller states it, the pressure
gain's relative sigma (the gas torque, hence J, scales with the gain). Arrays in, arrays out; SI units.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.kinematics import variable_inertia
from frictionwatch.core.model.terms import cylinder_samples
from frictionwatch.core.model.torques import gas_torque
from frictionwatch.core.monitor.coastdown import (
    CoastdownFit,
    cycle_mean_deceleration,
    cycle_mean_speed,
    fit_inertia_friction,
)
from frictionwatch.core.monitor.identification import mid_cycle_speed
from frictionwatch.core.types import Cycle

# J's relative 1-sigma assumed for a spec nobody has commissioned: what this commissioning step pins J to from plain
# coast-downs on the TU/e 4GB10 (bench/inertia_from_coastdowns.py: 0.02077 +- 0.00124, 6.0 %; the records' J moves
# by 9 % between 1300 and 2400 rpm). A datasheet or CAD inertia is not known better than that without a coast-down.
INERTIA_UNCALIBRATED_REL = 0.06

TWO_PI = 2.0 * np.pi
FOUR_PI = 4.0 * np.pi


@dataclass(frozen=True)
class CycleGeometry:
    """What the estimate needs of the engine: firing angles phases (z,) [rad], kinematics params [R, L, e] [m],
    piston area [m^2], reciprocating mass per cylinder [kg]."""

    phases: np.ndarray
    params: np.ndarray
    area: float
    m_rec: float


@dataclass(frozen=True)
class RippleRows:
    """One cycle's revolution-difference rows (module docstring): theta (m,) interval mid angles in [0, 2 pi)
    [rad]; d_energy (m,) D = E(theta + 2 pi) - E(theta) [rad^2/s^2]; d_work (m,) dG [N m rad]; d_shape (m,) the same
    difference of the integral of a friction shape of mean 1 [rad] (2 pi for a constant friction); omega the cycle's
    mean speed [rad/s]."""

    theta: np.ndarray
    d_energy: np.ndarray
    d_work: np.ndarray
    d_shape: np.ndarray
    omega: float


def _interval_mean(grid: np.ndarray, values: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Mean of the integral F(theta) = int_0^theta values over [lo, hi] (angles within [0, 4 pi]), values periodic on
    the uniform ``grid`` over [0, 4 pi) (trapezoid)."""
    h = grid[1] - grid[0]
    g = np.append(grid, FOUR_PI)
    v = np.append(values, values[0])
    f = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * h)])
    ff = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * h)])
    return (np.interp(hi, g, ff) - np.interp(lo, g, ff)) / (hi - lo)


def ripple_rows(tooth_angle: np.ndarray, tooth_time: np.ndarray, keep: np.ndarray, grid: np.ndarray,
                torque: np.ndarray, friction_shape: np.ndarray, geometry: CycleGeometry) -> RippleRows:
    """The revolution-difference rows of one cycle.

    tooth_angle (m,) nominal edge angles [rad] (cylinder 1's firing TDC = 0, the cycle over [0, 4 pi]); tooth_time
    (m,) edge times [s]; keep (m - 1,) bool: intervals to use (False: the gap, the distorted intervals next to it);
    grid (n,) uniform over [0, 4 pi); torque (n,) total gas torque on it [N m]; friction_shape (n,) a friction torque
    shape of mean 1 (ones: constant). Only intervals inside [0, 4 pi] whose partner one revolution later is kept too.
    """
    a = np.asarray(tooth_angle, dtype=np.float64)
    t = np.asarray(tooth_time, dtype=np.float64)
    k = np.asarray(keep, dtype=bool)
    if a.ndim != 1 or a.shape != t.shape or k.shape != (a.shape[0] - 1,):
        raise ValueError("tooth_angle and tooth_time need one value per edge, keep one per interval")
    if np.any(np.diff(a) <= 0) or np.any(np.diff(t) <= 0):
        raise ValueError("tooth_angle and tooth_time must increase")
    lo, hi = a[:-1], a[1:]
    mid = 0.5 * (lo + hi)
    ok = k & (lo >= -1e-12) & (hi <= FOUR_PI + 1e-12)
    first = np.flatnonzero(ok & (mid < TWO_PI))
    later = np.minimum(np.searchsorted(mid, mid[first] + TWO_PI - 1e-9), mid.shape[0] - 1)
    pair = (np.abs(mid[later] - mid[first] - TWO_PI) < 1e-6) & ok[later]
    i, j = first[pair], later[pair]
    omega = (hi - lo) / np.diff(t)
    energy = 0.5 * omega * omega
    j_rec, _ = variable_inertia(mid, geometry.phases, geometry.params, geometry.m_rec, 0.0)
    lo_c, hi_c = np.clip(lo, 0.0, FOUR_PI), np.clip(hi, 0.0, FOUR_PI)
    both = np.concatenate([i, j])
    work = np.full(mid.shape, np.nan)
    shape = np.full(mid.shape, np.nan)
    work[both] = _interval_mean(grid, torque, lo_c[both], hi_c[both])
    shape[both] = _interval_mean(grid, friction_shape, lo_c[both], hi_c[both])
    rec = j_rec * energy
    return RippleRows(theta=mid[i], d_energy=energy[j] - energy[i], d_work=work[j] - work[i] - (rec[j] - rec[i]),
                      d_shape=shape[j] - shape[i], omega=float((a[-1] - a[0]) / (t[-1] - t[0])))


def cycle_torque(grid: np.ndarray, pressure: np.ndarray, geometry: CycleGeometry, p_cc: float = 1.0e5) -> np.ndarray:
    """Total gas torque [N m] on ``grid`` (n,) from every cylinder's absolute pressure (z, n) [Pa]."""
    return gas_torque(grid, pressure, geometry.phases, geometry.params, geometry.area, p_cc).sum(axis=0)


@dataclass(frozen=True)
class CycleBalance:
    """The mean balance over the 720 deg from the middle of one cycle to the middle of the next (the monitor's
    window, core.monitor.identification.transient_balance): omega its mean speed [rad/s], decel its angle-averaged
    dw/dt from the two mid-cycle speeds [rad/s^2] (the same angle, so the ripple and J(theta) drop out), gas_mean its
    mean gas torque [N m]."""

    omega: float
    decel: float
    gas_mean: float


def window_balance(mid_times: tuple[float, float], mid_speeds: tuple[float, float], torque_before: np.ndarray,
                   torque_after: np.ndarray) -> CycleBalance:
    """The balance of the window from theta = 2 pi of one cycle to theta = 2 pi of the next: mid_times [s] and
    mid_speeds [rad/s] there; torque_before, torque_after (n,) the two cycles' gas torque on their uniform grid over
    [0, 4 pi) (the window takes the second half of the first and the first half of the second)."""
    n = torque_before.shape[0]
    if torque_after.shape != (n,) or n % 2:
        raise ValueError("both cycles' torques need the same even number of grid points")
    gas = 0.5 * (float(np.mean(torque_before[n // 2:])) + float(np.mean(torque_after[: n // 2])))
    omega = float(cycle_mean_speed(np.array([mid_times[0]]), np.array([mid_times[1]]))[0])
    decel = float(cycle_mean_deceleration(np.array(mid_speeds[0]), np.array(mid_speeds[1])))
    return CycleBalance(omega=omega, decel=decel, gas_mean=gas)


@dataclass(frozen=True)
class RippleFit:
    """J from the ripple of some cycles: inertia, inertia_std [kg m^2] (least-squares, scaled by the residual);
    per_cycle (c,) each cycle's own J [kg m^2]; resisting (c,) each cycle's friction + load level tau [N m] from its
    intercept at the pooled J; residual_rms [rad^2/s^2]."""

    inertia: float
    inertia_std: float
    per_cycle: np.ndarray
    resisting: np.ndarray
    residual_rms: float


def fit_ripple_inertia(rows: Sequence[RippleRows], shaped: bool = False) -> RippleFit:
    """D = u dG + s_c d_c per cycle c (module docstring), u shared, s_c free; d_c = 1 (constant friction: the
    intercept) or the cycle's ``d_shape`` (``shaped``). J = 1 / u, its sigma by the delta rule."""
    if not rows:
        raise ValueError("no cycles to fit")
    y = np.concatenate([r.d_energy for r in rows])
    if y.shape[0] < len(rows) + 4:
        raise ValueError(f"{y.shape[0]} ripple samples cannot fit {len(rows)} cycles")
    x = np.zeros((y.shape[0], 1 + len(rows)))
    x[:, 0] = np.concatenate([r.d_work for r in rows])
    start = 0
    for c, r in enumerate(rows):
        n = r.d_energy.shape[0]
        x[start:start + n, 1 + c] = r.d_shape if shaped else 1.0
        start += n
    sol, *_ = np.linalg.lstsq(x, y, rcond=None)
    res = y - x @ sol
    dof = x.shape[0] - x.shape[1]
    cov = float(res @ res) / dof * np.linalg.inv(x.T @ x)
    u = float(sol[0])
    per_cycle = np.empty(len(rows))
    for c, r in enumerate(rows):
        xc = np.column_stack([r.d_work, r.d_shape if shaped else np.ones_like(r.d_work)])
        per_cycle[c] = 1.0 / np.linalg.lstsq(xc, r.d_energy, rcond=None)[0][0]
    # intercept s = -u tau (2 pi: D per revolution; the shape's difference is 2 pi mean times tau)
    tau = -sol[1:] / u / (1.0 if shaped else TWO_PI)
    return RippleFit(inertia=1.0 / u, inertia_std=float(np.sqrt(cov[0, 0])) / u**2, per_cycle=per_cycle,
                     resisting=tau, residual_rms=float(np.sqrt(np.mean(res * res))))


HALF_ORDERS = np.arange(0.5, 7.0, 1.0)  # the revolution difference holds half orders only; fitted up to 6.5


def order_inertia(rows: Sequence[RippleRows], orders: np.ndarray = HALF_ORDERS) -> tuple[np.ndarray, np.ndarray]:
    """J read from each half order alone: (J_n (k,) [kg m^2], weight_n (k,) = sum |dG_n|^2 [(N m rad)^2]).

    D and dG of every cycle are decomposed on a constant and the half orders (least squares over [0, 2 pi));
    1 / J_n = Re(sum conj(dG_n) D_n) / sum |dG_n|^2 over the cycles. A rigid shaft line seen by a rigidly mounted
    sensor gives one J at every order (the friction level sits in the constant); a compliant coupling, a rocking
    block or a sensor's own dynamics make J_n depend on the frequency n omega / 2 pi."""
    o = np.asarray(orders, dtype=np.float64)
    num = np.zeros(o.shape[0], dtype=np.complex128)
    den = np.zeros(o.shape[0])
    for r in rows:
        basis = [np.ones_like(r.theta)]
        for n in o:
            basis += [np.cos(n * r.theta), np.sin(n * r.theta)]
        x = np.column_stack(basis)
        sol = np.linalg.lstsq(x, np.column_stack([r.d_energy, r.d_work]), rcond=None)[0]
        d_n = sol[1::2, 0] - 1j * sol[2::2, 0]
        g_n = sol[1::2, 1] - 1j * sol[2::2, 1]
        num += np.conj(g_n) * d_n
        den += np.abs(g_n) ** 2
    return den / num.real, den


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
    model's friction shape (the systematic check); balance one CycleBalance per two consecutive usable cycles."""

    name: str
    rows: tuple[RippleRows, ...]
    shaped_rows: tuple[RippleRows, ...]
    balance: tuple[CycleBalance, ...]


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
    """J and the friction law from coast-downs (module docstring).

    inertia, inertia_std [kg m^2]: the value used and its 1-sigma, all parts below in quadrature;
    records: each record's ripple J; ripple_inertia: the ripple J pooled over the records (random effect),
    between_std the records' spread beyond their own sigmas, speed_systematic the change of the cycles' J with
    their speed (``speed_trend``), ripple_std its sigma with the larger of those two and the shape systematic;
    order_systematic: the weighted spread of J read from each half order of each record (a diagnostic); shape_systematic [kg m^2]: constant vs shaped
    friction; gain_systematic [kg m^2]: J times the stated relative gain sigma; mean_balance: the mean-balance fit
    with J free (None: too few cycles), mean_weight: its share of the information on J (0..1), mean_used: whether it
    entered J (resolved and consistent with the ripple within 3 sigma); friction: c0 + c1 W (+ c2 W^2) pooled over
    the records with J's sigma carried (CoastdownFit, J fixed); friction_between_std [N m]: the records' spread about
    it beyond the cycles' scatter (added to c0's variance over the number of records); record_offsets [N m]: each
    record's mean resisting torque minus the law at its speeds."""

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
    a = np.array([b.decel for b in bal])
    w = np.array([b.omega for b in bal])
    y = np.array([b.gas_mean for b in bal])
    if not np.all(np.isfinite(a) & np.isfinite(w) & np.isfinite(y)):
        raise ValueError("a cycle's mean balance is not finite; leave that cycle out of its record")
    n_fr = n_friction if (w.max() - w.min()) >= min_span * w.mean() else 1
    mean_fit = fit_inertia_friction(a, w, y, n_friction=n_fr) if a.shape[0] > n_fr + 2 else None
    mean_weight, mean_used, j, s = 0.0, False, j_r, s_ripple
    if mean_fit is not None and np.isfinite(mean_fit.inertia_std) and mean_fit.inertia_std > 0:
        wm, wr = 1.0 / mean_fit.inertia_std**2, 1.0 / s_ripple**2
        mean_weight = wm / (wm + wr)
        consistent = abs(mean_fit.inertia - j_r) <= 3.0 * np.hypot(mean_fit.inertia_std, s_ripple)
        mean_used = bool(consistent and mean_fit.inertia_std <= resolve_rel * abs(mean_fit.inertia))
        if mean_used:
            j = (wm * mean_fit.inertia + wr * j_r) / (wm + wr)
            s = float(1.0 / np.sqrt(wm + wr))
    s_total = float(np.hypot(s, gain_sys))
    friction = fit_inertia_friction(a, w, y, n_friction=n_fr, inertia=j, inertia_std=s_total)
    # the records' offsets about the pooled law beyond what their cycles' scatter explains
    resid = y - j * a - friction.friction_torque(w)
    sizes = np.array([len(r.balance) for r in records])
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    offsets = np.array([resid[bounds[k]:bounds[k + 1]].mean() if sizes[k] else np.nan for k in range(len(records))])
    dof = max(resid.shape[0] - (n_fr + (1 if mean_used else 0)), 1)
    s2 = float(resid @ resid) / dof
    have = sizes > 0
    f_between = float(np.sqrt(max(0.0, np.var(offsets[have], ddof=1) - s2 * np.mean(1.0 / sizes[have])))) \
        if np.count_nonzero(have) >= 2 else 0.0
    if f_between > 0:
        cov = friction.covariance.copy()
        cov[1, 1] += f_between**2 / np.count_nonzero(have)
        friction = CoastdownFit(friction.inertia, friction.inertia_std, friction.friction_coeffs,
                                friction.load_coeffs, cov, friction.residual_rms, friction.n_cycles)
    return InertiaCalibration(inertia=float(j), inertia_std=s_total, records=per, ripple_inertia=j_r,
                              ripple_std=s_ripple, between_std=between, speed_systematic=trend,
                              order_systematic=order_sys,
                              shape_systematic=shape_sys,
                              gain_systematic=gain_sys, mean_balance=mean_fit, mean_weight=float(mean_weight),
                              mean_used=mean_used, friction=friction, friction_between_std=f_between,
                              record_offsets=offsets)


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
                     min_rows: int = 40) -> CoastdownRecord | None:
    """One record's ripple rows (one per usable cycle) and mean balances (one per two consecutive usable cycles)
    from its assembled cycles (core.types.Cycle, pressure of every instrumented cylinder on the cycle grid). Cycles
    with a NaN pressure sample of an instrumented cylinder, fewer than ``min_rows`` paired intervals, or
    (``motored_only``) a positive mean gas torque (fired) are left out; None when none is left."""
    geo = geometry_of(model)
    spec = model.spec
    rows, shaped, bal = [], [], []
    prev = None  # (index, mid time, mid speed, torque) of the last usable cycle
    for c in cycles:
        p = np.asarray(c.pressure, dtype=np.float64)
        have = np.any(np.isfinite(p), axis=1)
        if not np.any(have) or not np.all(np.isfinite(p[have])):
            continue
        p = np.where(have[:, None], p, 1.0e5)  # an uninstrumented cylinder's gas torque is not knowable: none
        t = c.tooth_ticks.astype(np.float64) / c.tick_hz
        torque = cycle_torque(c.grid, p, geo)
        if motored_only and float(np.mean(torque)) > 0:
            continue
        keep = interval_mask(c.tooth_angle, c.tooth_index)
        r = ripple_rows(c.tooth_angle, t, keep, c.grid, torque, np.ones_like(torque), geo)
        if r.d_energy.shape[0] < min_rows:
            continue
        omega = 4.0 * np.pi / (t[-1] - t[0])
        rows.append(r)
        shaped.append(ripple_rows(c.tooth_angle, t, keep, c.grid, torque,
                                  friction_shape(model, c.grid, p, omega), geo))
        mid = (float(np.interp(TWO_PI, c.tooth_angle, t)), mid_cycle_speed(spec, c), torque)
        if prev is not None and prev[0] == c.index - 1 and np.isfinite(prev[2]) and np.isfinite(mid[1]):
            bal.append(window_balance((prev[1], mid[0]), (prev[2], mid[1]), prev[3], torque))
        prev = (c.index, *mid)
    if not rows:
        return None
    return CoastdownRecord(name, tuple(rows), tuple(shaped), tuple(bal))
