"""J from the speed ripple of a coast-down against its measured gas torque (core.monitor.calibration.inertia
explains the method and pools it over records): the revolution-difference rows of one cycle and their fit.

Over one cycle, with a friction (+ load) torque tau that is constant within it (physics.md §3),

    J0 E(theta) + J_rec(theta) E(theta) = C + G(theta) - tau theta,     E = omega^2 / 2,  G = int T_gas dtheta,

J_rec = m_rec x'^2 the reciprocating part. Each tooth interval minus the same interval one revolution earlier,
D(theta) = E(theta + 2 pi) - E(theta), theta in [0, 2 pi), drops whatever repeats every revolution (the tooth-spacing
error, a constant pressure offset, whose torque is first order):

    D(theta) = u dG(theta) - 2 pi u tau,   u = 1 / J0,   dG = int_theta^{theta + 2 pi} T_gas - [J_rec E] difference.

Arrays in, arrays out; SI units.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.kinematics import variable_inertia

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
