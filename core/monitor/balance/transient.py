"""Inertia and friction against speed from a run whose speed changes (a coast-down, a load step, a fired -> motored
transition), from the monitor's per-cycle results (core.monitor.identify.mean_balance.transient_balance).

Each analysed cycle whose predecessor was analysed too gives one row of the mean balance over the two cycles under
a triangular weight centred on cylinder 1's firing TDC between them (the change of the cycles' angle-averaged
kinetic energy; design note 69):

    T_i,window - T_L - T_coupling = J a + T_f(W),    T_f(W) = c0 + c1 W,

a the kinetic term over J(2 pi) (CycleResult.acceleration), W the mean of the two cycles' mean speeds. The fit is
core.monitor.balance.coastdown.fit_inertia_friction (one implementation). J is taken from the rows when they resolve it (a
torque step at almost one speed: ignition off, a load step) and from the engine spec otherwise: in a plain
coast-down J a(W) and c0 + c1 W are nearly collinear (coastdown.py).

Without a load measurement the right-hand side is friction plus whatever load there is: the caller says which
(``TransientFriction.load_measured``, ``motored``). Arrays in, arrays out; SI units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from frictionwatch.core.monitor.balance.coastdown import CoastdownFit, fit_inertia_friction

FRICTION_STEP = 0.1  # assumed 1-sigma change of the friction across a torque step, relative
NEGATIVE_SIGMAS = 2.0  # a law's friction below zero by more than this many sigma is flagged (TransientFriction)


@dataclass(frozen=True)
class TransientFriction:
    """inertia, inertia_std [kg m^2]: J from the rows (inertia_identified; sigma with the friction-step allowance) or
    the prior given with its stated sigma (not from these data); fit: c0 + c1 W with J fixed at ``inertia``, its covariance
    carrying J's sigma; speed (c,) [rad/s], acceleration (c,) [rad/s^2], resisting (c,) [N m] (indicated - measured
    load - coupling loss) of the rows the friction was fitted to: the motored ones when the run has motored and fired
    rows (fired friction is higher: the cylinder pressure loads rings and bearings), else all; motored: those rows
    had no positive indicated work; load_measured: every row had a load reading (else ``resisting`` includes
    whatever load there was)."""

    inertia: float
    inertia_std: float
    inertia_identified: bool
    fit: CoastdownFit
    speed: np.ndarray
    acceleration: np.ndarray
    resisting: np.ndarray
    load_measured: bool
    motored: bool

    def friction_at(self, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T_f, 1-sigma) [N m] at speeds ``omega`` [rad/s]."""
        return self.fit.friction_torque(omega), self.fit.friction_std(omega)

    def negative_friction(self, omega_low: float, sigmas: float = NEGATIVE_SIGMAS) -> tuple[float, float, float] | None:
        """Where the law gives a friction below zero by more than ``sigmas`` 1-sigma at ``omega_low`` [rad/s] (the
        lowest speed the engine runs at, or the run reached if lower): (omega_low, T_f, 1-sigma) there, else None.
        Friction cannot be negative: such a law says the rows hold a torque the balance does not (a load still
        connected without a reading, a wrong J), not the engine's friction."""
        f, s = (float(v[0]) for v in self.friction_at(np.array([omega_low])))
        return (omega_low, f, s) if f + sigmas * s < 0.0 else None



def transient_friction(index: np.ndarray, omega: np.ndarray, acceleration: np.ndarray, indicated: np.ndarray,
                       load: np.ndarray, coupling: np.ndarray, inertia_prior: float, load_step_nm: float,
                       min_span: float = 0.03, resolve_rel: float = 0.1,
                       inertia_prior_std: float = 0.0) -> TransientFriction | None:
    """The fit of one run's consecutive cycles, or None when the run is not a transient (its window speeds span less
    than ``min_span`` of their mean) or has too few rows (fewer than 3; J is fitted from 5 rows on, friction is
    c0 + c1 W from 4 rows on and a constant from 3).

    index (c,) stream cycle numbers; omega (c,) cycle mean speeds [rad/s]; acceleration, indicated (c,) the window's
    dw/dt [rad/s^2] and indicated torque [N m] (NaN without the cycle before); load (c,) measured load [N m] (NaN:
    none); coupling (c,) modelled coupling loss [N m]; inertia_prior: J [kg m^2] at theta = 2 pi from the spec;
    load_step_nm: a row whose load differs from the cycle before by more is dropped (the window's load is unknown);
    resolve_rel: J is taken from the rows when its sigma is at most this fraction of it; inertia_prior_std: the
    prior J's 1-sigma [kg m^2] (a commissioned J's, or an uncalibrated spec's assumed one), carried into the
    friction's covariance when J is not taken from the rows (friction = T_i - J a: sigma_J |a| goes straight in).
    """
    idx = np.asarray(index, dtype=np.int64)
    arrays = [np.asarray(x, dtype=np.float64) for x in (omega, acceleration, indicated, load, coupling)]
    w_c, acc, t_i, t_l, t_c = arrays
    if not all(x.shape == idx.shape for x in arrays) or idx.ndim != 1:
        raise ValueError("index, omega, acceleration, indicated, load and coupling need one value per cycle")
    if idx.shape[0] < 2:
        return None
    ok = np.zeros(idx.shape[0], dtype=bool)
    ok[1:] = (idx[1:] == idx[:-1] + 1) & np.isfinite(acc[1:]) & np.isfinite(t_i[1:]) & np.isfinite(t_c[1:])
    load_measured = bool(np.all(np.isfinite(t_l[ok])))
    if load_measured:
        stepped = np.zeros_like(ok)
        stepped[1:] = np.abs(t_l[1:] - t_l[:-1]) > load_step_nm
        ok &= ~stepped
    rows = np.flatnonzero(ok)
    if rows.shape[0] < 3:
        return None
    w = 0.5 * (w_c[rows - 1] + w_c[rows])
    if (w.max() - w.min()) < min_span * w.mean():
        return None
    y = t_i[rows] - t_c[rows] - (t_l[rows] if load_measured else 0.0)
    a = acc[rows]
    if rows.shape[0] < 5:  # J free needs 3 parameters and 2 degrees of freedom for its sigma: take the prior
        free = None
    else:
        free = fit_inertia_friction(a, w, y)
    # a torque step also steps the friction (ring and bearing loads follow the cylinder pressure: simulated TU/e
    # fired -> motored, -5 %), which c0 + c1 W cannot follow and J absorbs (there +3.7 %): allow for a step of
    # FRICTION_STEP of the friction across the rows' range of dw/dt
    identified = False
    if free is not None:
        span_a = float(a.max() - a.min())
        level = float(np.mean(np.abs(free.friction_torque(w))))
        j_std = float(np.hypot(free.inertia_std, FRICTION_STEP * level / span_a)) if span_a > 0 else np.inf
        identified = bool(free.inertia > 0 and np.isfinite(j_std) and j_std <= resolve_rel * free.inertia)
    j, j_std = (free.inertia, j_std) if identified else (float(inertia_prior), float(inertia_prior_std))
    motored = t_i[rows] <= 0.0
    use = motored if 3 <= np.count_nonzero(motored) < motored.shape[0] else np.ones_like(motored)
    # c0 + c1 W from 4 rows on (2 degrees of freedom), a constant from 3
    n_friction = 2 if np.count_nonzero(use) >= 4 else 1
    fit = fit_inertia_friction(a[use], w[use], y[use], n_friction=n_friction, inertia=j, inertia_std=j_std)
    return TransientFriction(inertia=j, inertia_std=j_std, inertia_identified=identified, fit=fit, speed=w[use],
                             acceleration=a[use], resisting=y[use], load_measured=load_measured,
                             motored=bool(np.all(motored[use])))
