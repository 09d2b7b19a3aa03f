"""The cycle's mean torque balance (design.md §4 step 5's last row), per cycle and across cycles: the grid's
geometry, the cycle's angle-averaged kinetic energy (one kernel beside its numpy reference), the transient balance
of two consecutive cycles, each cylinder's indicated torque per radian of its TDC (the calibration's sensitivity),
and, from a run's per-cycle transient balances, its inertia and friction against speed (transient_friction).

Across cycles (transient_friction): inertia and friction against speed from a run whose speed changes (a coast-down,
a load step, a fired -> motored transition), from the monitor's per-cycle results (transient_balance above).

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

import math
from dataclasses import dataclass

import numba
import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.indicated import piston_positions, tdc_centres, window_starts, works_with_alone
from frictionwatch.core.model.kinematics import cylinder_kinematics_kernel, kinematics, variable_inertia
from frictionwatch.core.monitor.balance.coastdown import CoastdownFit, fit_inertia_friction
from frictionwatch.core.monitor.state import EnergyWeights, GridGeometry, PreviousCycle
from frictionwatch.core.types import Cycle

FOUR_PI = 4.0 * np.pi


@dataclass(frozen=True)
class MeanBalance:
    """This cycle's mean torque balance [N m]: indicated (sum over cylinders, the cycle's own window), load
    (measured, plus the load's own ripple work), coupling_loss (modelled damper/coupling dissipation), kinetic =
    the change of the cycles' angle-averaged kinetic energy / 4 pi from the cycle before to this one
    (``transient_balance``) and friction = indicated_window - the two cycles' mean load and coupling loss - kinetic
    (NaN without a load measurement or without the previous cycle); imep_centred (z,) [Pa] over each cylinder's own
    firing window, None without the previous cycle; acceleration [rad/s^2] kinetic / J(2 pi) and indicated_window
    [N m] the two cycles' indicated torque under the balance's triangular weight;
    tdc_sensitivity (z,) [N m/rad] each cylinder's dT_iM/dDelta (core.monitor.balance.mean_balance.indicated_tdc_sensitivity),
    None where not computed (then the calibration adds no TDC term); load_from_power: the load was read as electrical
    power over the generator's efficiency and the speed, not as a shaft torque (the calibration's load sigma is that
    reading's: core.model.calibration.Calibration.load_variance)."""

    indicated: float
    load: float
    coupling_loss: float
    friction: float
    kinetic: float = float("nan")
    imep_centred: np.ndarray | None = None
    acceleration: float = float("nan")
    indicated_window: float = float("nan")
    tdc_sensitivity: np.ndarray | None = None
    load_from_power: bool = False


def shaft_load(load_torque: float, load_power: float, omega: float, efficiency: float) -> tuple[float, bool]:
    """(the load torque on the shaft [N m], whether it was read as electrical power): the measured torque where
    finite, else the electrical power over the generator's efficiency and the speed (NaN: neither measured). A genset
    seldom has a torque flange; without the efficiency its generator's losses would be booked as friction
    (core.model.calibration: generator_efficiency, load_power_sigma)."""
    if math.isfinite(load_torque):
        return load_torque, False
    return load_power / (omega * efficiency), True


def mid_cycle_speed(spec: EngineSpec, cycle: Cycle) -> float:
    """Speed [rad/s] at the middle of the cycle (cylinder 1's gas-exchange TDC, theta = 2 pi): 1 / (dt/dtheta) of a
    quadratic in angle fitted (one least-squares solve) to the edge times within +-MID_SPEED_HALF_WIDTH (about 30
    edges of a 60-2 wheel). Two edges +-18 deg apart quantised the speed to 1 timer tick in 2 ms (simulated Deutz
    at 1 MHz: J a in steps of 0.115 N m on 7.6); the fit averages that down ~10x. A tooth-spacing error and the
    speed ripple repeat every cycle at this angle and drop out of a difference of two cycles; the quadratic keeps
    the linear deceleration out of the slope at the centre. The commissioning's inertia window uses it
    (core.monitor.calibration.inertia); the monitor's balance takes each cycle's mean energy (design note 69)."""
    ang = cycle.tooth_angle - 2.0 * np.pi
    near = np.abs(ang) <= MID_SPEED_HALF_WIDTH
    if np.count_nonzero(near) < 5:
        return float("nan")
    t = (cycle.tooth_ticks[near] - cycle.tooth_ticks[near][0]) / cycle.tick_hz
    a = ang[near]
    dt_dtheta = np.linalg.lstsq(np.stack([np.ones_like(a), a, a * a], axis=1), t, rcond=None)[0][1]
    return float(1.0 / dt_dtheta) if dt_dtheta > 0 else float("nan")


MID_SPEED_HALF_WIDTH = np.radians(90.0)


def mid_cycle_inertia(spec: EngineSpec) -> float:
    """J(theta) [kg m^2] at theta = 2 pi: the rotating inertia plus each reciprocating mass times x'(theta)^2."""
    local = np.mod(2.0 * np.pi - spec.firing_angles, 4.0 * np.pi)
    _, dx, _ = kinematics(local, spec.kinematics_params())
    return spec.total_inertia + spec.reciprocating_mass * float(np.sum(dx * dx))


def grid_geometry(spec: EngineSpec, grid: np.ndarray) -> GridGeometry:
    """The piston positions of every cylinder on the cycles' grid, J at theta = 2 pi, each cylinder's own firing
    window and the triangular weights of the transient balance's indicated torque (made once per grid)."""
    positions = piston_positions(grid, spec.firing_angles, spec.kinematics_params())
    z, n = spec.n_cyl, grid.shape[0]
    dx, ddx = np.empty((z, n)), np.empty((z, n))
    cylinder_kinematics_kernel(np.ascontiguousarray(grid, dtype=np.float64),
                               np.ascontiguousarray(spec.firing_angles, dtype=np.float64),
                               np.ascontiguousarray(spec.kinematics_params(), dtype=np.float64), dx, ddx)
    centres = tdc_centres(spec.firing_angles)[None, :]
    central = np.ascontiguousarray(0.5 * (np.roll(positions, -1, axis=1) - np.roll(positions, 1, axis=1)))
    return GridGeometry(float(grid[0]), int(n), positions, mid_cycle_inertia(spec), ddx,
                        window_starts(grid, centres), window_starts(grid, np.zeros((1, z))),
                        *triangle_weights(grid, positions, spec.piston_area), central)


def triangle_weights(grid: np.ndarray, positions: np.ndarray, area: float) -> tuple[np.ndarray, np.ndarray]:
    """(previous, current) (z, n) [m^2/rad]: the coefficients that take two consecutive cycles' pressures [Pa] to
    the transient balance's indicated torque beyond the two cycles' plain mean [N m]:
    sum(previous_p * previous) + sum(current_p * current) = (1/4 pi) [int over the previous cycle of T (phi/4 pi - 1/2)
    + int over the current one of T (1/2 - phi/4 pi)] dphi, T = sum_k p_k A x_k' the gas torque, by the trapezoid
    rule on the grid (each interval's weight at its middle; the previous cycle's last interval ends on the current
    cycle's first sample, the current cycle's closes on its own first). The weights have zero mean over each cycle,
    so the grid's trapezoid bias (~0.5 % of a work) enters only this small difference."""
    n = grid.shape[0]
    step = FOUR_PI / n
    mid = (grid + 0.5 * step) / FOUR_PI  # each interval's middle, a fraction of the cycle
    dx = np.roll(positions, -1, axis=1) - positions  # x is 4 pi periodic: the last interval ends on x[0]
    g_prev, g_cur = (mid - 0.5) * dx, (0.5 - mid) * dx  # (z, n) an interval's weight x its dx
    scale = 0.5 * area / FOUR_PI
    prev = np.ascontiguousarray(scale * (g_prev + np.concatenate((np.zeros_like(g_prev[:, :1]), g_prev[:, :-1]), 1)))
    cur = scale * (g_cur + np.roll(g_cur, 1, axis=1))
    cur[:, 0] += scale * g_prev[:, -1]  # the previous cycle's last interval ends on the current cycle's first sample
    return prev, np.ascontiguousarray(cur)


def triangle_weights_reference(grid: np.ndarray, positions: np.ndarray, area: float, previous: np.ndarray,
                               current: np.ndarray) -> float:
    """``triangle_weights``' sum by the plain trapezoid of the weighted gas-torque work along [previous | current]
    (its reference, tests/core/test_transient_balance.py)."""
    n = grid.shape[0]
    step = FOUR_PI / n
    frac = (grid + 0.5 * step) / FOUR_PI
    total = 0.0
    for k in range(positions.shape[0]):
        x_next = np.roll(positions[k], -1)
        p_prev_next = np.append(previous[k, 1:], current[k, 0])
        p_cur_next = np.roll(current[k], -1)
        total += np.sum((frac - 0.5) * 0.5 * (previous[k] + p_prev_next) * (x_next - positions[k]))
        total += np.sum((0.5 - frac) * 0.5 * (current[k] + p_cur_next) * (x_next - positions[k]))
    return float(total * area / FOUR_PI)


def energy_weights(spec: EngineSpec, tooth_angle: np.ndarray) -> EnergyWeights:
    """The weights of ``cycle_energy`` at a cycle's edges (fixed by their nominal angles): per tooth interval,
    1/2 J over the interval's part inside [0, 4 pi) (Simpson's rule over that part; J(theta) the rotating inertia
    plus every reciprocating mass times x'^2, as ``mid_cycle_inertia`` at one angle) x its nominal pitch^2 x that
    part's length / 4 pi, so that the interval's speed pitch / dt gives its share of the cycle's mean energy."""
    a = np.array(tooth_angle, dtype=np.float64)
    lo, hi = np.clip(a[:-1], 0.0, FOUR_PI), np.clip(a[1:], 0.0, FOUR_PI)
    pts = np.concatenate((lo, 0.5 * (lo + hi), hi))
    j = variable_inertia(pts, spec.firing_angles, spec.kinematics_params(), spec.reciprocating_mass,
                         spec.total_inertia)[0].reshape(3, -1)
    j_mean = (j[0] + 4.0 * j[1] + j[2]) / 6.0
    pitch = a[1:] - a[:-1]
    return EnergyWeights(a, np.ascontiguousarray(0.5 * j_mean * pitch * pitch * (hi - lo) / FOUR_PI))


@numba.njit(numba.float64(numba.int64[::1], numba.float64[::1], numba.float64), cache=True)
def cycle_energy_kernel(ticks, weights, tick_hz):
    """sum_i weights[i] (tick_hz / (ticks[i+1] - ticks[i]))^2 [J]; NaN when an interval is not positive."""
    total = 0.0
    for i in range(weights.shape[0]):
        d = float(ticks[i + 1] - ticks[i])
        if not d > 0.0:
            return numba.float64(float("nan"))
        total += weights[i] / (d * d)
    return total * tick_hz * tick_hz


def cycle_energy(cycle: Cycle, weights: EnergyWeights) -> float:
    """The cycle's angle-averaged kinetic energy (1/4 pi) int_0^4pi 1/2 J(theta) w(theta)^2 dtheta [J], w in each
    tooth interval its pitch over its measured time (``energy_weights``). An edge time's error enters two adjacent
    intervals with opposite signs and telescopes to first order: of the cycle's ~120 edges only the two boundary
    ones count, as in a difference of two speeds. NaN when an interval is not positive. One kernel call
    (``cycle_energy_kernel`` above); ``cycle_energy_reference`` is its numpy."""
    ticks = cycle.tooth_ticks
    if ticks.dtype != np.int64 or not ticks.flags.c_contiguous or ticks.shape[0] != weights.weights.shape[0] + 1:
        return cycle_energy_reference(cycle, weights)
    return float(cycle_energy_kernel(ticks, weights.weights, float(cycle.tick_hz)))


def cycle_energy_reference(cycle: Cycle, weights: EnergyWeights) -> float:
    """``cycle_energy`` in numpy (its reference)."""
    dt = np.diff(np.asarray(cycle.tooth_ticks)).astype(np.float64) / cycle.tick_hz
    if dt.shape != weights.weights.shape or not np.all(dt > 0):
        return float("nan")
    return float(weights.weights @ (1.0 / (dt * dt)))


def transient_balance(spec: EngineSpec, cycle: Cycle, pressure: np.ndarray, indicated_cycle: np.ndarray,
                      energy: float, previous: PreviousCycle | None, load: float, coupling_loss: float,
                      geometry: GridGeometry, load_early: float) -> tuple[float, float, float, float,
                                                                          np.ndarray | None, np.ndarray]:
    """(friction, kinetic, acceleration, indicated, imep_centred, tdc_sensitivity) of one cycle and the cycle just
    before it (``previous``; None when that cycle is not at hand: NaN and None, but tdc_sensitivity, this cycle's
    ``indicated_tdc_sensitivity``, always: with a previous cycle taken in the balance's one pass over the pressure,
    without it by ``indicated_tdc_sensitivity`` itself); indicated_cycle (z,) [N m] the
    cylinders' work means over this cycle's own window (``Excitation.indicated_mean``); energy [J] this cycle's
    angle-averaged kinetic energy (``cycle_energy``).

    The rigid shaft line's energy balance with each cycle's angle-averaged energy Ebar = (1/4 pi) int E dtheta,
    E = 1/2 J(theta) w^2, over its own [0, 4 pi): (Ebar_c - Ebar_c-1) / 4 pi is exactly the mean net torque
    under a triangular weight over the two cycles (phi / 4 pi on the previous cycle at its angle phi, 1 - phi / 4 pi
    on this one; half the weight on each, centred on cylinder 1's firing TDC between them). So the indicated torque
    is the two cycles' gas torque under that weight, the load and the coupling loss the two cycles' mean, and the
    friction the two cycles' mean friction. Why the mean energy and not E at one angle: every engine order is
    periodic in 4 pi, so the shaft's speed ripple drops out of Ebar to first order; E at theta = 2 pi holds the
    ripple there, which repeats from cycle to cycle only at a steady speed: while the speed settles near a shaft
    mode it does not (maruti 4000 -> 1500 rpm: the one-angle term was off by -0.34 N m, 5x the balance's floor;
    design note 69). And why the triangle and not the plain cycle means: within a fired single-cylinder cycle E
    swings by ~13 %, so plain cycle-mean speeds against the torques of one window were off at a fired -> motored
    step (simulated TU/e: 1.5 N m on 0.8); weighting the torques as the energies weight them is exact for a rigid
    shaft. Measured energies and no fitted drift (which biased an earlier per-cycle estimate, design notes §3): the
    term telescopes over a run, a steady run gets no bias, a coast-down or a load step gets the torque that changed
    the speed. acceleration [rad/s^2] is the kinetic term over J(2 pi) (kinetic = J(2 pi) a, as the transient fit
    and the coast-down report take it: transient_friction below).

    The load under the same triangle: the previous cycle's late half (``previous.load_late``) and this cycle's
    early half (``load_early``), each from the load readings' own spans (drivers.assembly.cycle_parts.load_mean;
    the caller puts the cycle's mean there where they are not given). When the cycles' means step by more than
    2 % of the rated torque the window's load is still not known well enough (where in a reading's span the step
    fell; the coupling's wind-up) and friction is NaN (that cycle): a step late in this cycle, in the reading after
    its end, now shows in its mean and voids it (deutz two-point s9 cycle 145: +11.8 N m before, design note 76)."""
    nan = float("nan")
    # the windows' first samples and the triangle's weights are fixed by the grid (GridGeometry); the pressures
    # are the monitor's checked ones
    if geometry.window_starts is None or geometry.central_dx is None or geometry.triangle_previous is None:
        geometry = grid_geometry(spec, cycle.grid)
    if previous is None or not (math.isfinite(previous.energy) and math.isfinite(energy)):
        # no balance without the cycle before; this cycle's TDC sensitivity all the same (a run's first cycle)
        return nan, nan, nan, nan, None, indicated_tdc_sensitivity(cycle.grid, pressure, geometry.piston_acceleration,
                                                                   spec.piston_area)
    cur = np.ascontiguousarray(pressure, dtype=np.float64)
    prev = np.ascontiguousarray(previous.pressure, dtype=np.float64)
    own, alone, triangle, sensitivity = balance_sums(geometry, prev, cur, spec.piston_area, cycle.grid)
    kinetic = (energy - previous.energy) / FOUR_PI
    ind = np.asarray(indicated_cycle)
    # the grid's works enter only as the triangle's zero-mean weighting; the two cycles' accurate means carry the
    # level: the 720-point trapezoid reads ~0.5 % below the work the monitor's time grid takes (K9K 1100 rpm:
    # 0.28 N m of indicated torque, 2 % of the friction), a bias the weighting's zero mean cancels
    indicated = 0.5 * (float(ind.sum()) + previous.indicated) + triangle
    imep = (ind * FOUR_PI + own - alone) / spec.displacement_cyl
    load_stepped = abs(load - previous.load) > LOAD_STEP_FRACTION * spec.rated_torque_nm
    window_load = 0.5 * (previous.load_late + load_early)
    friction = nan if load_stepped else indicated - window_load - 0.5 * (coupling_loss + previous.coupling_loss) - kinetic
    return friction, kinetic, kinetic / geometry.inertia_mid, indicated, imep, sensitivity


LOAD_STEP_FRACTION = 0.02  # of the rated torque: a larger load change between two cycles voids that balance


def indicated_tdc_sensitivity(grid: np.ndarray, pressure: np.ndarray, piston_acceleration: np.ndarray,
                              area: float) -> np.ndarray:
    """(z,) [N m/rad] d T_iM,k / d Delta_k for a cylinder whose true TDC lies Delta_k later than its stated one.

    T_iM,k = A/(4 pi) ∮ p_k x'(theta - phi_k) dtheta; the stated phase is Delta_k early, so the work taken moves by
    -A/(4 pi) ∮ p_k x''(theta - phi_k) dtheta per radian (a constant part of p does no work: ∮ x'' = 0). The cycle's
    pressure (z, n) [Pa] on its uniform grid (n,) [rad] closes on itself (the last sample's neighbour is the first):
    a steady cycle's compression of the next cycle is this one's. piston_acceleration (z, n) [m/rad^2]: x'' of each
    cylinder on the grid (core.monitor.state.GridGeometry)."""
    step = float(grid[1] - grid[0])
    return -area * step / (4.0 * np.pi) * np.einsum("kn,kn->k", pressure, piston_acceleration)


def balance_sums(geometry: GridGeometry, previous: np.ndarray, current: np.ndarray, area: float,
                 grid: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """The transient balance's pressure sums of two consecutive cycles' pressures (z, n) [Pa] (C-contiguous
    float64, finite) on the grid (n,) [rad] ``geometry`` was made for, in one pass over them: (own (z,) [J]
    each cylinder's work over its own firing window in [previous | current], alone (z,) [J] over this cycle's closed
    loop, the triangle's indicated torque beyond the two cycles' mean [N m], tdc_sensitivity (z,) [N m/rad]) --
    ``balance_sums_reference``'s (works_with_alone, two np.vdot, indicated_tdc_sensitivity's einsum: ~0.15-0.3 ms
    a genset-v20 cycle, four passes over the (20, 720) pressures) by ``balance_sums_kernel``.

    The works by parts: a closed trapezoid over n samples of an n-periodic x, (1/2) sum (p_a + p_a+1)(x_a+1 - x_a),
    is sum p_a (x_a+1 - x_a-1) / 2, each sample's weight its central difference (``GridGeometry.central_dx``)
    whatever the window's start; a window from s in [previous | current] is previous's samples from s on and
    current's before s. The same sum, its terms grouped otherwise: rounding only."""
    own, alone, sensitivity = np.empty((3, current.shape[0]))
    triangle = balance_sums_kernel(previous, current, geometry.central_dx, geometry.window_starts[0],
                                   geometry.triangle_previous, geometry.triangle_current,
                                   geometry.piston_acceleration, own, alone, sensitivity)
    return own * area, alone * area, float(triangle), -area * float(grid[1] - grid[0]) / FOUR_PI * sensitivity


def balance_sums_reference(geometry: GridGeometry, previous: np.ndarray, current: np.ndarray, area: float,
                           grid: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """``balance_sums`` as the balance took them before its kernel: core.model.indicated's window works, numpy's
    dot products and ``indicated_tdc_sensitivity`` (tests/core/test_transient_balance.py compares the two)."""
    (own,), (alone,) = works_with_alone(geometry.positions, previous, current, geometry.window_starts,
                                        geometry.alone_starts, area)
    triangle = float(np.vdot(previous, geometry.triangle_previous) + np.vdot(current, geometry.triangle_current))
    return own, alone, triangle, indicated_tdc_sensitivity(grid, current, geometry.piston_acceleration, area)


_ROW = numba.float64[:, ::1]


@numba.njit(numba.float64(_ROW, _ROW, _ROW, numba.int64[::1], _ROW, _ROW, _ROW, numba.float64[::1],
                          numba.float64[::1], numba.float64[::1]), cache=True, fastmath={"reassoc", "nsz"})
def balance_sums_kernel(previous, current, central_dx, starts, tri_previous, tri_current, ddx, own, alone,
                        sensitivity):
    """Per cylinder k: own[k] = sum of previous[k, s:] and current[k, :s] times central_dx (s = starts[k] in
    [0, n]), alone[k] = sum current[k] central_dx, sensitivity[k] = sum current[k] ddx[k]; returns sum previous
    tri_previous + sum current tri_current. Two loops per cylinder (before and from s), each reading both cycles
    once; the flags let the sums be reordered (vectorised), the pressures being finite (checked_pressure)."""
    z, n = current.shape
    tri_prev = 0.0
    tri_cur = 0.0
    for k in range(z):
        s = min(max(starts[k], 0), n)
        head = 0.0  # current before s: in both windows
        tail = 0.0  # current from s: this cycle's loop only
        before = 0.0  # previous from s: the own window only
        sens = 0.0
        for a in range(s):
            p = current[k, a]
            head += p * central_dx[k, a]
            sens += p * ddx[k, a]
            tri_cur += p * tri_current[k, a]
            tri_prev += previous[k, a] * tri_previous[k, a]
        for a in range(s, n):
            p = current[k, a]
            q = previous[k, a]
            tail += p * central_dx[k, a]
            before += q * central_dx[k, a]
            sens += p * ddx[k, a]
            tri_cur += p * tri_current[k, a]
            tri_prev += q * tri_previous[k, a]
        own[k] = before + head
        alone[k] = head + tail
        sensitivity[k] = sens
    return tri_prev + tri_cur


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
