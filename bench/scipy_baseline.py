"""A straightforward scipy implementation of the monitor's method: the benchmark baseline (design.md §5).

Same method, same inputs, plain tools (paper 000 Fig. 7a; physics.md §10-11):

- measured flywheel speed (bench/scipy_measure.py): the monitor's own tooth fit (core.monitor.teeth.flywheel.fit_flywheel, drift
  fitted apart) mapped onto the cycle's crank-angle grid, so both paths see the same measurement;
- model: the torsional chain of physics.md §11 integrated in time with ``scipy.integrate.solve_ivp``, a numpy
  right-hand side vectorised over nodes and cylinders: exact J(theta) per throw, gas torque from the measured
  pressure at the flywheel angle, the six Rezeka-Henein terms at each throw's own angle and speed, the shaft and
  ground matrices of core.model.dynamics.shaft_model (the monitor's chain). It starts at constant speed (all nodes at the
  measured mean speed, static twist) and runs cycle after cycle until the flywheel speed repeats. The load takes up
  the mean torque imbalance, and a free shaft line (dyno) is re-tuned each cycle, so the mean speed is the measured
  one (the monitor takes the mean from the measurement and leaves the mean balance to its Eq. 7 row);
- identification: ``scipy.optimize.least_squares`` (trf, bounds theta >= 0, 2-point finite-difference Jacobian) over
  the grouped scales theta of core.monitor.identify.parameters.parameter_layout; residual = whitened harmonics (orders <= the monitor's
  limit) of measured minus modelled flywheel speed on the grid, the in-band tooth-error nuisances of the monitor
  (linear, so eliminated in closed form), the mean-balance row (paper 000 Eq. 7) and the monitor's priors (weak
  theta ~ 1, siblings, Eq. 6 sharing; core.monitor.identify.parameters, core.monitor.identify.parameters);
- outer loop as paper 000 Fig. 7a: share the mean loss (with the model's damper/coupling dissipation), identify,
  re-simulate until periodic, until the shares and the modelled speed stop moving.

Per cycle, from its own equations only: no accumulation across cycles (the monitor's smoothed estimate has no
counterpart here), no drift random effect (the drift is fitted apart in the tooth fit). Each least-squares
evaluation warm-starts from the last periodic state with the load re-balanced, which saves most of the cycles a
cold start needs (this favours the baseline).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.dynamics import shaft_model
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.indicated import peak_pressure
from frictionwatch.core.monitor.identify.parameters import (
    ParameterLayout,
    build_priors,
    firing_mask,
    motored_friction_per_cylinder,
    parameter_layout,
    share_mean_loss,
)
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares

from bench.scipy_measure import MeasuredCycle, angle_harmonics, on_angle_grid

FOUR_PI = 4.0 * np.pi
P_CC = 1.0e5  # crankcase pressure [Pa], as core.monitor.balance.excitation


# ---- model pieces in plain numpy (physics.md §1, §7) -------------------------------------------------------------
def slider_crank(theta: np.ndarray, r: float, rod: float, e: float) -> tuple[np.ndarray, np.ndarray]:
    """x'(theta) [m/rad] and x''(theta) [m/rad^2] of the slider-crank with pin offset e (physics.md §1)."""
    st, ct = np.sin(theta), np.cos(theta)
    sb = (r * st - e) / rod
    cb = np.sqrt(1.0 - sb * sb)
    tb = sb / cb
    return r * st + r * ct * tb, r * ct - r * st * tb + r * r * ct * ct / (rod * cb**3)


def friction_constants(fp: np.ndarray) -> np.ndarray:
    """Constant factors of the six terms from EngineSpec.friction_params() (physics.md §7):
    [pi D (n_o + 0.4 n_c) sqrt(mu e), P_e, pi D n_c, mu pi D L_FP / g_a, N_v L_s, mu, pi/4 D^2 r_b]."""
    d, mu, pe, eth, nc, no, lfp, ga, nv, ls, rb = (float(v) for v in fp[3:14])
    return np.array([np.pi * d * (no + 0.4 * nc) * np.sqrt(mu * eth), pe, np.pi * d * nc, mu / ga * np.pi * d * lfp,
                     nv * ls, mu, 0.25 * np.pi * d * d * rb])


def friction_terms(theta: np.ndarray, omega: np.ndarray, p_gauge: np.ndarray, dx: np.ndarray,
                   const: np.ndarray) -> np.ndarray:
    """The six Rezeka-Henein terms F_l (6, ...) at local angle theta [rad], throw speed omega [rad/s], gauge
    pressure p [Pa] and lever x'(theta) [m/rad] (physics.md §7); const from ``friction_constants``."""
    w = np.maximum(omega, 1e-3)
    p = np.maximum(p_gauge, 0.0)
    lever = np.abs(dx)
    th = np.mod(theta, FOUR_PI)
    rw = 1.0 / np.sqrt(w)
    out = np.empty((6,) + np.shape(th))
    out[0] = const[0] * np.sqrt(w * lever * (const[1] + p)) * lever
    window = (th <= 0.5 * np.pi) | (th >= FOUR_PI - 0.5 * np.pi)  # +-90 deg about firing TDC
    out[1] = window * (const[2] * (const[1] + p) * (1.0 - np.abs(np.sin(th))) * lever)
    out[2] = const[3] * w * lever * lever
    out[3] = const[4] * lever * rw
    out[4] = const[5] * w
    out[5] = const[6] * p * np.abs(np.cos(th)) * rw
    return out


# ---- the chain in time (physics.md §11) --------------------------------------------------------------------------
class ChainODE:
    """M(theta) omega' = sum over cylinders (T_g - T_f - m x' x'' omega^2) - K phi - C v - T_L e_L, with
    phi = theta - theta_start - Omega t, v = omega - Omega; state y = [phi (N), v (N)]."""

    def __init__(self, spec: EngineSpec, meas: MeasuredCycle):
        shaft = shaft_model(spec, meas.load_torque, meas.omega)  # same K, C and ground terms as the monitor
        self.n = spec.n_nodes
        self.stiffness, self.damping = shaft.stiffness, shaft.damping
        self.edges, self.edge_damping, self.ground_damping = shaft.edges, shaft.edge_damping, shaft.ground_damping
        self.grounded = bool(shaft.stiffness.sum(axis=0).max() > 1e-9 * np.abs(shaft.stiffness).max()) \
            if self.n > 1 else False
        self.j_rot = spec.node_inertia.astype(np.float64)
        self.node_of = spec.cylinder_node
        self.incidence = np.zeros((self.n, spec.n_cyl))
        self.incidence[spec.cylinder_node, np.arange(spec.n_cyl)] = 1.0
        self.phase = spec.firing_angles.astype(np.float64)
        self.kin = spec.kinematics_params()
        self.fric_const = friction_constants(spec.friction_params())
        self.area, self.m_rec = spec.piston_area, spec.reciprocating_mass
        self.fly, self.load_node = spec.flywheel_node, spec.load_node
        self.meas = meas
        g = meas.grid
        self.g0, self.dg, self.ng = float(g[0]), float(g[1] - g[0]), g.shape[0]
        self.coef = np.zeros((spec.n_cyl, 6))
        self.load = meas.load_torque if np.isfinite(meas.load_torque) else 0.0

    def torques(self, t: np.ndarray | float, phi: np.ndarray, v: np.ndarray):
        """Per-cylinder gas torque, friction terms F (6, z, ...), x', x'' and node speeds at state (phi, v); works
        on one state (N,) or on a trajectory (N, n_t)."""
        om = self.meas.omega
        theta = self.meas.theta_start + om * np.asarray(t) + phi  # node angles
        omega = om + v
        u = np.mod(theta[self.fly] - self.g0, FOUR_PI) / self.dg  # pressure at the flywheel angle (as sampled)
        i0 = np.floor(u).astype(np.int64) % self.ng
        w = u - np.floor(u)
        p = self.meas.pressure[:, i0] * (1.0 - w) + self.meas.pressure[:, (i0 + 1) % self.ng] * w
        ph = self.phase if np.ndim(phi) == 1 else self.phase[:, None]
        local = theta[self.node_of] - ph
        dx, ddx = slider_crank(local, *self.kin)
        w_cyl = omega[self.node_of]
        gas = (p - P_CC) * self.area * dx
        basis = friction_terms(local, w_cyl, p - P_CC, dx, self.fric_const)
        return gas, basis, dx, ddx, omega

    def energy(self, t: float, y: np.ndarray) -> float:
        """Kinetic energy with J(theta) per node plus the shaft's strain energy [J] at state y."""
        n = self.n
        theta = self.meas.theta_start + self.meas.omega * t + y[:n]
        dx, _ = slider_crank(theta[self.node_of] - self.phase, *self.kin)
        inertia = self.j_rot + self.incidence @ (self.m_rec * dx * dx)
        omega = self.meas.omega + y[n:]
        return float(0.5 * inertia @ omega**2 + 0.5 * y[:n] @ self.stiffness @ y[:n])

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        n = self.n
        phi, v = y[:n], y[n:]
        gas, basis, dx, ddx, omega = self.torques(t, phi, v)
        fric = np.einsum("kl,lk->k", self.coef, basis)
        cyl = gas - fric - self.m_rec * dx * ddx * omega[self.node_of] ** 2
        torque = self.incidence @ cyl - self.stiffness @ phi - self.damping @ v
        torque[self.load_node] -= self.load
        inertia = self.j_rot + self.incidence @ (self.m_rec * dx * dx)
        return np.concatenate([v, torque / inertia])


@dataclass
class Periodic:
    """The periodic solution at one coefficient set: flywheel speed on the grid and the work means the Eq. 6/7 rows
    need (cycle mean of T omega_q / Omega), plus the end state for a warm start."""

    speed: np.ndarray  # (n,) rad/s on the crank-angle grid
    basis_mean: np.ndarray  # (z, 6)
    indicated_mean: np.ndarray  # (z,)
    coupling_loss: float  # N m: relative-damper power / Omega
    ground_power: float  # W: load-node ground damper power
    y_end: np.ndarray
    load: float
    cycles: int
    rhs_calls: int
    theta_fly: np.ndarray  # (S,) flywheel angle of the samples of the last cycle [rad]
    basis: np.ndarray  # (6, z, S) friction terms there


def periodic_solution(ode: ChainODE, coef: np.ndarray, y0: np.ndarray | None = None, load0: float | None = None,
                      method: str = "RK45", rtol: float = 1e-6, tol: float = 1e-3, min_cycles: int = 2,
                      max_cycles: int = 60, samples: int = 1024) -> Periodic:
    """Integrate cycle after cycle from ``y0`` until the flywheel speed on the sampled cycle changes by less than
    ``tol`` times its ripple rms (paper 000 Fig. 7a).

    y0 None: every node at the measured mean speed, twisted statically under the constant-speed mean torques.
    load0: mean load torque of the model [N m]; None: the one that balances the constant-speed mean torques. The
    load node takes up the mean imbalance, as in the monitor (core.model.dynamics.static_twist), so the mean speed is the
    measured one and the slow load/grid mode is not set ringing; a free shaft line (dyno) also gets a governor that
    re-tunes this load each cycle."""
    n, om, period = ode.n, ode.meas.omega, ode.meas.period
    ode.coef = coef
    if y0 is None or load0 is None:
        twist, balancing = _static_state(ode, coef)
        y0 = np.concatenate([twist, np.zeros(n)]) if y0 is None else y0
        load0 = balancing if load0 is None else load0
    ode.load = load0
    atol = np.concatenate([np.full(n, 1e-10), np.full(n, 1e-8 * om)])
    t_eval = np.arange(samples) * (period / samples)
    y, prev, calls = np.asarray(y0, dtype=np.float64).copy(), None, 0
    for c in range(1, max_cycles + 1):
        sol = solve_ivp(ode.rhs, (0.0, period), y, method=method, t_eval=np.append(t_eval, period), rtol=rtol,
                        atol=atol)
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed: {sol.message}")
        calls += sol.nfev
        traj = sol.y[:, :-1]
        y = sol.y[:, -1].copy()
        theta_fly = ode.meas.theta_start + om * t_eval + traj[ode.fly]
        speed = on_angle_grid(ode.meas.grid, theta_fly, om + traj[n + ode.fly])
        if not ode.grounded:
            # governor: the load that keeps the mean speed at the measured one. The energy gained over the cycle
            # is the mean torque imbalance times 4 pi; the speed offset and its ground-damper torque are moved
            # into the load
            v_mean = float(np.mean(traj[n + ode.fly]))
            ode.load += (ode.energy(period, y) - ode.energy(0.0, sol.y[:, 0])) / (om * period) \
                + float(ode.ground_damping.sum()) * v_mean
            y[n:] -= v_mean
            speed = speed - v_mean
        ripple = float(np.std(speed)) + 1e-12
        if prev is not None and c >= min_cycles and float(np.sqrt(np.mean((speed - prev) ** 2))) < tol * ripple:
            break
        prev = speed
    gas, basis, _, _, omega = ode.torques(t_eval[None, :], traj[:n], traj[n:])
    w_over = omega[ode.node_of] / om
    rel = 0.0
    if ode.edges.shape[0]:
        dv = traj[n + ode.edges[:, 0]] - traj[n + ode.edges[:, 1]]
        rel = float(np.sum(ode.edge_damping[:, None] * dv**2) / samples)
    gnd = float(np.sum(ode.ground_damping[:, None] * traj[n:] ** 2) / samples)
    return Periodic(speed, np.mean(basis * w_over[None], axis=-1).T, np.mean(gas * w_over, axis=-1), rel / om, gnd,
                    y, ode.load, c, calls, theta_fly, basis)


def _static_state(ode: ChainODE, coef: np.ndarray) -> tuple[np.ndarray, float]:
    """Static twist (N,) [rad] and the balancing load [N m] under the mean torques at constant speed."""
    th = np.arange(720) * (FOUR_PI / 720)
    zeros = np.zeros((ode.n, th.shape[0]))
    gas, basis, _, _, _ = ode.torques((th - ode.meas.theta_start) / ode.meas.omega, zeros, zeros)
    t = ode.incidence @ (gas.mean(axis=1) - np.einsum("kl,lk->k", coef, basis.mean(axis=-1)))
    load = float(t.sum())
    t[ode.load_node] -= load
    twist = np.linalg.pinv(ode.stiffness) @ t if ode.n > 1 else np.zeros(1)
    return twist, load


# ---- identification (physics.md §10; paper 000 Fig. 7a) ---------------------------------------------------------
@dataclass
class BaselineResult:
    """theta (P,) scales; coefficients (z, 6) raw a_kl; friction_mean (z,) N m per cylinder (work mean);
    friction_torque (z, n) N m per cylinder vs the flywheel angle on the grid;
    speed_measured, speed_model (n,) rad/s on the grid; r_squared of the in-band speed ripple (the estimated
    tooth-error part taken out); outer iterations (paper 000 Fig. 7a: sharings computed), least-squares fits,
    least-squares evaluations (Jacobian columns included), simulated cycles, RHS calls, seconds; warm: (theta, end
    state, load) to start the next cycle from."""

    theta: np.ndarray
    coefficients: np.ndarray
    friction_mean: np.ndarray
    friction_torque: np.ndarray  # (z, n) N m per cylinder on the crank-angle grid (flywheel angle)
    speed_measured: np.ndarray
    speed_model: np.ndarray
    r_squared: float
    outer: int
    fits: int
    nfev: int
    cycles_simulated: int
    rhs_calls: int
    seconds: float
    warm: tuple


def identify_cycle(spec: EngineSpec, meas: MeasuredCycle, layout: ParameterLayout | None = None,
                   sigma: np.ndarray | None = None, sigma_balance: float | None = None, method: str = "RK45",
                   rtol: float = 1e-6, share_spread: float = 0.3, sibling_spread: float = 0.15,
                   parameter_sigma: float = 1.0, max_outer: int = 4, outer_tol: float = 1e-3,
                   diff_step: float = 0.05, ls_tol: float = 1e-3, tooth_error_deg: float = 0.05,
                   eval_cycles: int = 2, warm: tuple | None = None) -> BaselineResult:
    """Identify the grouped friction scales of one cycle with solve_ivp + least_squares, iterating as paper 000
    Fig. 7a (priors and sharing as core.monitor.monitor.MonitorConfig's defaults).

    sigma : (M,) noise of each speed harmonic [rad/s per real component]; default: the tooth-fit floor
        w_m sqrt(2/edges) * residual rms (core.monitor.monitor's floor)
    sigma_balance : 1-sigma of the mean balance [N m]; default 0.2 % of the indicated torque
    method, rtol : solve_ivp integrator and relative tolerance (absolute: 1e-10 rad, 1e-8 Omega)
    diff_step : relative finite-difference step of the Jacobian (rtol 1e-6 makes sqrt(eps) steps difference solver
        noise; the response is nearly linear in theta, physics.md §12.2, so 5 % is accurate)
    eval_cycles : each least-squares evaluation re-simulates exactly this many cycles from the base periodic state
        (a smooth function of theta, so the finite-difference Jacobian is clean; a run "until periodic" changes its
        length with theta and makes the residual jump). The outer loop then checks the periodic speed at the fit and
        fits again from there until the shares move by less than ``outer_tol`` of the balance and the periodic
        speed harmonics at the fit differ from the fit's by less than 0.1 sigma
    ls_tol : ftol = xtol = gtol of least_squares: the cost carries ~1e-3 of solver noise (rtol 1e-6) and one
        cycle does not fix theta better than a few % (core.monitor.monitor's per-cycle sigmas), so tighter only adds
        Jacobians
    tooth_error_deg : rms per-tooth angle error behind the prior of the in-band tooth-error nuisances (as the
        monitor). They enter the speed linearly, so they are eliminated in closed form inside the residual
        (variable projection) and cost no extra simulations
    warm : (theta, state, load) of a previous cycle (``BaselineResult.warm``) to start from; None: theta = 1 (the
        prior) and constant speed
    """
    t0 = time.perf_counter()
    layout = layout or parameter_layout(spec)
    m = meas.n_harmonics
    freq = 0.5 * meas.omega * np.arange(1, m + 1)
    if sigma is None:
        sigma = np.sqrt(freq**2 * 2.0 * meas.edge_noise**2 / meas.n_edges + 1e-12)
    ode = ChainODE(spec, meas)
    meas_h = angle_harmonics(meas.speed, m)
    # tooth nuisances e ~ N(0, s^2): whitened columns d, e_hat = g @ r_w with g = (d^T d + I/s^2)^-1 d^T
    s_tooth = np.radians(tooth_error_deg) * np.sqrt(2.0 / (spec.sensors.wheel_teeth - spec.sensors.wheel_missing))
    cols = np.concatenate([meas.tooth_columns.real, meas.tooth_columns.imag]) / np.concatenate([sigma, sigma])[:, None]
    proj = np.linalg.solve(cols.T @ cols + np.eye(cols.shape[1]) / s_tooth**2, cols.T)
    pmax, _ = peak_pressure(meas.grid, meas.pressure, spec.firing_angles)
    theta = np.ones(layout.n_params) if warm is None else np.asarray(warm[0], dtype=np.float64).copy()
    # a previous cycle's end state is a good start; its load is not (combustion differs): rebalance
    sol = periodic_solution(ode, layout.coefficients(theta), None if warm is None else warm[1], None,
                            method=method, rtol=rtol)
    cycles, calls, nfev, outer, fits, last, gap = sol.cycles, sol.rhs_calls, 0, 0, 0, None, np.inf
    for _ in range(max_outer):
        outer += 1
        # share the mean loss with this iterate's indicated torques and damper/coupling dissipation (Eq. 6); the
        # loop has converged when the shares no longer move (the next fit would return the same theta)
        t_i = float(sol.indicated_mean.sum())
        balance = t_i - (meas.load_torque + sol.ground_power / meas.omega) - sol.coupling_loss
        not_firing = ~firing_mask(sol.indicated_mean)
        motored = motored_friction_per_cylinder(spec, meas.omega * 30.0 / np.pi,
                                                float(np.mean(pmax[not_firing])) if not_firing.any() else 0.0)
        share = share_mean_loss(balance, sol.indicated_mean, motored, share_spread)
        targets = np.append(share.friction_mean, balance)
        if last is not None and np.max(np.abs(targets - last)) < outer_tol * max(abs(balance), 1e-9) \
                and gap < 0.1:
            break
        last = targets
        s_bal = sigma_balance if sigma_balance is not None else max(0.002 * abs(t_i), 1e-6)
        prior = build_priors(spec, layout, 0, layout.cylinder_rows(sol.basis_mean), parameter_sigma, 0.0,
                             sibling_spread).with_share(share)
        count = {"cycles": 0, "calls": 0, "speed": {}}
        base_coef = layout.coefficients(theta)

        def residual(th: np.ndarray, base: Periodic = sol, base_coef=base_coef, prior=prior, balance=balance,
                     s_bal=s_bal, count=count) -> np.ndarray:
            # warm start; the load takes up the change of mean friction at once (no slow mode set ringing)
            load = base.load - float(np.sum((layout.coefficients(th) - base_coef) * base.basis_mean))
            s = periodic_solution(ode, layout.coefficients(th), base.y_end, load, method, rtol,
                                  min_cycles=eval_cycles, max_cycles=eval_cycles)
            count["cycles"] += s.cycles
            count["calls"] += s.rhs_calls
            count["speed"][th.tobytes()] = s.speed
            r = angle_harmonics(meas.speed - s.speed, m)
            r_w = np.concatenate([r.real / sigma, r.imag / sigma])
            e = proj @ r_w
            mean_fric = float(np.sum(layout.coefficients(th) * s.basis_mean))
            return np.concatenate([r_w - cols @ e, e / s_tooth, [(mean_fric - balance) / s_bal],
                                   (prior.rows @ th - prior.target) / prior.sigma])

        fit = least_squares(residual, theta, bounds=(0.0, np.inf), method="trf", diff_step=diff_step,
                            ftol=ls_tol, xtol=ls_tol, gtol=ls_tol)
        fits += 1
        nfev += fit.nfev + (fit.njev or 0) * layout.n_params
        theta = fit.x
        load = sol.load - float(np.sum((layout.coefficients(theta) - base_coef) * sol.basis_mean))
        sol = periodic_solution(ode, layout.coefficients(theta), sol.y_end, load, method, rtol)
        seen = count["speed"].get(theta.tobytes())
        gap = np.inf if seen is None else float(np.max(np.abs(angle_harmonics(sol.speed - seen, m)) / sigma))
        cycles += count["cycles"] + sol.cycles
        calls += count["calls"] + sol.rhs_calls
    r_w = np.concatenate([(meas_h - angle_harmonics(sol.speed, m)).real / sigma,
                          (meas_h - angle_harmonics(sol.speed, m)).imag / sigma])
    tooth = meas.tooth_columns @ (proj @ r_w)  # the estimated tooth-error part of the measured harmonics
    meas_h = meas_h - tooth
    model_h = angle_harmonics(sol.speed, m)
    power = float(np.sum(np.abs(meas_h) ** 2))
    r2 = 1.0 - float(np.sum(np.abs(meas_h - model_h) ** 2)) / power if power > 0 else float("nan")
    coef = layout.coefficients(theta)
    trace = np.array([on_angle_grid(meas.grid, sol.theta_fly, f) for f in np.einsum("kl,lkt->kt", coef, sol.basis)])
    return BaselineResult(theta, coef, np.sum(coef * sol.basis_mean, axis=1), trace, meas.speed, sol.speed, r2, outer,
                          fits, nfev, cycles, calls, time.perf_counter() - t0, (theta, sol.y_end, sol.load))
