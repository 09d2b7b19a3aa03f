"""Coast-down numerics: per-cycle mean speed, mean deceleration and mean gas torque -> shaft inertia and friction.

Mean balance over one 4-stroke cycle (angle span 4 pi, physics.md §4, energy form):

    1/2 J (w_end^2 - w_start^2) / (4 pi) = T_gas,mean - T_f(W) - T_load(W)

where w_start, w_end are the speeds at the same crank angle one cycle apart, so the variable inertia J(theta)
(physics.md §3) is the same at both ends and drops out, and (w_end^2 - w_start^2) / (8 pi) is the angle-averaged
dw/dt of the cycle ("deceleration" below, negative while coasting). T_gas,mean is the cycle mean of
(p - p_cc) A_p x'(theta) (physics.md §2), i.e. the net IMEP (pumping included) times V_d / (4 pi).

Identifiability: in a plain motored coast-down the deceleration is itself a smooth function of speed, so J a(W)
and T_f(W) = c0 + c1 W are nearly collinear and J is not resolved (on the TU/e files the no-load-only fit gives
J = 0.005 +- 0.003 kg m^2). J is fixed by cycles where T_gas jumps at almost the same speed: the fired -> motored
transition (ignition off). A file whose generator load stays on gets its own load term d0 + d1 W.

Cross-check: ``cyclic_inertia`` takes J from the half-order (0.5, 1.5, 2.5) content of the speed ripple and the gas
torque within each cycle. Half orders are free of tooth-spacing errors (those repeat every revolution: integer
orders) and of the reciprocating mass torque (integer orders), so J_0 (i n) E_n = T_gas,n with E = w^2 / 2.

All functions are arrays in, arrays out; no I/O. Units SI (s, rad, rad/s, N m, Pa, m).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.torques import gas_torque

CYCLE = 4.0 * np.pi  # 4-stroke cycle angle [rad]


def cycle_mean_speed(t_start: np.ndarray, t_end: np.ndarray, span: float = CYCLE) -> np.ndarray:
    """Mean angular speed [rad/s] of cycles from their start and end times [s]."""
    ts, te = np.asarray(t_start, dtype=np.float64), np.asarray(t_end, dtype=np.float64)
    if ts.shape != te.shape or np.any(te <= ts):
        raise ValueError("t_end must have the shape of t_start and be later than it")
    return span / (te - ts)


def cycle_mean_deceleration(omega_start: np.ndarray, omega_end: np.ndarray, span: float = CYCLE) -> np.ndarray:
    """Angle-averaged dw/dt [rad/s^2] over a cycle from the speeds at its two ends (same crank angle):
    (w_end^2 - w_start^2) / (2 span). Negative while the engine slows down."""
    ws, we = np.asarray(omega_start, dtype=np.float64), np.asarray(omega_end, dtype=np.float64)
    return (we * we - ws * ws) / (2.0 * span)


def window_speed(edge_angle: np.ndarray, edge_time: np.ndarray, at_angle: np.ndarray, half_width: float) -> np.ndarray:
    """Mean speed [rad/s] over [at - h, at + h] from edge angles [rad] and times [s] (both increasing), with the
    edge times linearly interpolated in angle. NaN where the window leaves the edge record."""
    a = np.asarray(edge_angle, dtype=np.float64)
    t = np.asarray(edge_time, dtype=np.float64)
    at = np.asarray(at_angle, dtype=np.float64)
    if a.shape != t.shape or a.ndim != 1 or np.any(np.diff(a) <= 0) or np.any(np.diff(t) <= 0):
        raise ValueError("edge_angle and edge_time must be 1-D, equally long and strictly increasing")
    if not half_width > 0:
        raise ValueError("half_width must be > 0 rad")
    lo, hi = at - half_width, at + half_width
    w = 2.0 * half_width / (np.interp(hi, a, t) - np.interp(lo, a, t))
    return np.where((lo >= a[0]) & (hi <= a[-1]), w, np.nan)


def mean_gas_torque(
    theta: np.ndarray, pressure: np.ndarray, params: np.ndarray, area: float, p_cc: float = 1.0e5
) -> np.ndarray:
    """Cycle mean of the gas torque (p - p_cc) A_p x'(theta) [N m] for each row of ``pressure``.

    theta : (n,) uniform grid over one whole cycle without its endpoint [rad from firing TDC]
    pressure : (n,) or (c, n) absolute pressure [Pa]; params : [R, L, pin_offset] [m]; area : piston area [m^2]
    """
    th = np.ascontiguousarray(theta, dtype=np.float64).ravel()
    p = np.atleast_2d(np.asarray(pressure, dtype=np.float64))
    if p.shape[1] != th.shape[0]:
        raise ValueError(f"pressure rows must have {th.shape[0]} samples (one per theta), got {p.shape[1]}")
    step = np.diff(th)
    if th.shape[0] < 8 or not np.allclose(step, step[0], rtol=1e-9, atol=1e-12):
        raise ValueError("theta must be a uniform grid of >= 8 points")
    if not np.isclose(step[0] * th.shape[0], CYCLE, rtol=1e-6):
        span = np.degrees(step[0] * th.shape[0])
        raise ValueError(f"theta must cover one 720 deg cycle without its endpoint; it covers {span:.3f} deg")
    if not np.all(np.isfinite(p)):
        raise ValueError("pressure has NaN or inf samples; skip that cycle first")
    # each row as one cylinder at phase 0 (core.model.torques: the one gas-torque definition); the rectangle rule
    # is exact for a periodic trapezoid
    return gas_torque(th, p, np.zeros(p.shape[0]), params, area, p_cc).mean(axis=1)


@dataclass(frozen=True)
class CoastdownFit:
    """J a + sum_m c_m W^m + sum_g [cycle in g] (d_g0 + d_g1 W) = T_gas (least squares over all cycles).

    inertia [kg m^2] and its standard error; friction_coeffs c_m [N m / (rad/s)^m]; load_coeffs one (d0, d1) row per
    load group; covariance of all parameters in the order (J, c..., d...), all inf when the columns are collinear
    (J not resolved by these cycles); residual rms [N m]; cycles used.
    """

    inertia: float
    inertia_std: float
    friction_coeffs: np.ndarray
    load_coeffs: np.ndarray
    covariance: np.ndarray
    residual_rms: float
    n_cycles: int

    def friction_torque(self, omega: np.ndarray) -> np.ndarray:
        """T_f(W) [N m] of the fitted friction polynomial."""
        return friction_torque(omega, self.friction_coeffs)

    def friction_std(self, omega: np.ndarray) -> np.ndarray:
        """Standard error of T_f(W) [N m] from the parameter covariance."""
        w = np.atleast_1d(np.asarray(omega, dtype=np.float64))
        m = self.friction_coeffs.shape[0]
        g = np.column_stack([w**k for k in range(m)])
        cov = self.covariance[1 : 1 + m, 1 : 1 + m]
        return np.sqrt(np.einsum("ij,jk,ik->i", g, cov, g))


def friction_torque(omega: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
    """sum_m c_m W^m [N m]."""
    w = np.asarray(omega, dtype=np.float64)
    return sum(c * w**k for k, c in enumerate(np.asarray(coeffs, dtype=np.float64)))


def fit_inertia_friction(
    decel: np.ndarray,
    omega: np.ndarray,
    gas_torque: np.ndarray,
    load_group: np.ndarray | None = None,
    n_friction: int = 2,
    inertia: float | None = None,
    inertia_std: float = 0.0,
) -> CoastdownFit:
    """Joint least-squares fit of one inertia J, one friction polynomial T_f(W) (``n_friction`` terms: c0 + c1 W by
    default) and a linear load torque d0 + d1 W per load group (module docstring).

    decel : (c,) angle-averaged dw/dt per cycle [rad/s^2]; omega : (c,) cycle mean speed [rad/s];
    gas_torque : (c,) cycle mean gas torque [N m]; load_group : (c,) int, -1 = no load (friction only), g >= 0 = the
    cycle belongs to load group g (e.g. one file whose generator load stayed on). inertia : a known J [kg m^2]
    (e.g. the spec's, where the cycles cannot resolve it, or one identified elsewhere): J a moves to the measured
    side and is not fitted; inertia_std : its 1-sigma, carried into the other parameters' covariance (the friction
    moves by -dJ (X^T X)^-1 X^T a) and reported as ``inertia_std``.
    """
    a = np.asarray(decel, dtype=np.float64).ravel()
    w = np.asarray(omega, dtype=np.float64).ravel()
    y = np.asarray(gas_torque, dtype=np.float64).ravel()
    grp = np.full(a.shape[0], -1, dtype=np.int64) if load_group is None else np.asarray(load_group, np.int64).ravel()
    if not (a.shape == w.shape == y.shape == grp.shape):
        raise ValueError("decel, omega, gas_torque and load_group must have one value per cycle")
    if not np.all(np.isfinite(a) & np.isfinite(w) & np.isfinite(y)):
        raise ValueError("non-finite cycle values; drop those cycles first")
    if not 1 <= n_friction <= 4:
        raise ValueError(f"n_friction must be 1..4, got {n_friction}")
    groups = np.unique(grp[grp >= 0])
    if inertia is not None:
        known = float(inertia)
        if not (np.isfinite(known) and known > 0):
            raise ValueError(f"a known inertia must be > 0 kg m^2, got {inertia!r}")
        y = y - known * a
    cols = ([a] if inertia is None else []) + [w**k for k in range(n_friction)]
    for g in groups:
        sel = (grp == g).astype(np.float64)
        cols += [sel, sel * w]
    x = np.column_stack(cols)
    if x.shape[0] <= x.shape[1]:
        raise ValueError(f"{x.shape[0]} cycles cannot fit {x.shape[1]} parameters")
    scale = np.linalg.norm(x, axis=0)
    scale[scale == 0] = 1.0
    xs = x / scale  # equilibrated columns, so the rank test below means something
    sol_s, *_ = np.linalg.lstsq(xs, y, rcond=None)
    sol = sol_s / scale
    r = y - x @ sol
    dof = x.shape[0] - x.shape[1]
    s2 = float(r @ r) / dof
    sv = np.linalg.svd(xs, compute_uv=False)
    if sv[-1] < 1e-8 * sv[0]:  # collinear columns: say "not resolved" instead of quoting noise as a number
        cov = np.full((x.shape[1], x.shape[1]), np.inf)
    else:
        cov = s2 * np.linalg.inv(xs.T @ xs) / np.outer(scale, scale)
    if inertia is not None:  # J known: the other parameters' sensitivity to it carries its sigma
        sens = -np.linalg.lstsq(xs, a, rcond=None)[0] / scale
        g = np.concatenate([[1.0], sens])
        cov = np.pad(cov, ((1, 0), (1, 0))) + float(inertia_std) ** 2 * np.outer(g, g)
        sol = np.concatenate([[float(inertia)], sol])
    return CoastdownFit(
        inertia=float(sol[0]),
        inertia_std=float(np.sqrt(cov[0, 0])),
        friction_coeffs=sol[1 : 1 + n_friction].copy(),
        load_coeffs=sol[1 + n_friction :].reshape(-1, 2).copy(),
        covariance=cov,
        residual_rms=float(np.sqrt(np.mean(r * r))),
        n_cycles=int(x.shape[0]),
    )


def _harmonics(theta: np.ndarray, values: np.ndarray, orders: np.ndarray) -> np.ndarray:
    """Complex amplitudes X_n of values ~ X0 + sum Re(X_n e^{i n theta}) by least squares."""
    cols = [np.ones_like(theta)]
    for n in orders:
        cols += [np.cos(n * theta), np.sin(n * theta)]
    sol, *_ = np.linalg.lstsq(np.column_stack(cols), values, rcond=None)
    return sol[1::2] - 1j * sol[2::2]


def cyclic_inertia(
    theta_speed: np.ndarray,
    omega: np.ndarray,
    theta_torque: np.ndarray,
    gas_torque: np.ndarray,
    orders: tuple[float, ...] = (0.5, 1.5, 2.5),
    n_max: float = 6.5,
) -> float:
    """Inertia [kg m^2] of one cycle from its speed ripple and gas torque at the half orders (module docstring).

    theta_speed, omega : nominal angles [rad] and speeds [rad/s] of the tooth-interval samples of one cycle; only
        samples whose angle + 2 pi is also present are used. The speed enters as the revolution difference
        D(theta) = E(theta + 2 pi) - E(theta), E = w^2 / 2: anything that repeats every revolution (tooth-spacing
        error, its product with the mean speed) cancels, a linear drift becomes a constant, and every half order n
        appears as -2 E_n. (A plain fit over the cycle with a drift term lets the unfitted high integer orders of
        the tooth error leak into the half orders through the drift column.)
    theta_torque, gas_torque : the gas torque [N m] on a uniform grid over the same cycle.
    orders : half orders used for J; all half orders up to ``n_max`` are fitted so none leaks into another.
    """
    ts = np.asarray(theta_speed, dtype=np.float64).ravel()
    ws = np.asarray(omega, dtype=np.float64).ravel()
    tt = np.asarray(theta_torque, dtype=np.float64).ravel()
    tq = np.asarray(gas_torque, dtype=np.float64).ravel()
    if ts.shape != ws.shape or tt.shape != tq.shape:
        raise ValueError("theta_speed/omega and theta_torque/gas_torque must be pairs of equal length")
    full = np.arange(0.5, n_max + 0.25, 1.0)
    o = np.asarray(orders, dtype=np.float64)
    want = np.searchsorted(full, o)
    if o.size == 0 or np.any(o % 1.0 != 0.5) or np.any(want >= full.size) or not np.allclose(full[want], o):
        raise ValueError(f"orders must be half orders <= n_max = {n_max}, got {orders}")
    order = np.argsort(ts)
    ts, ws = ts[order], ws[order]
    j = np.searchsorted(ts, ts + 2.0 * np.pi)
    j = np.minimum(j, ts.shape[0] - 1)
    pair = np.abs(ts[j] - ts - 2.0 * np.pi) < 1e-6
    if np.count_nonzero(pair) < 2 * full.size + 4:
        raise ValueError(f"only {np.count_nonzero(pair)} speed samples have a partner one revolution later")
    e = 0.5 * ws * ws
    d = e[j[pair]] - e[pair]
    e_n = -0.5 * _harmonics(ts[pair], d, full)[want]
    t_n = _harmonics(tt, tq, full)[want]
    de = 1j * o * e_n  # dE/dtheta at each order
    return float(np.sum((np.conj(de) * t_n).real) / np.sum(np.abs(de) ** 2))
