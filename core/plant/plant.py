"""Time-domain plant: the torsional chain of physics.md §11 integrated by fixed-step RK4 (numba).

Conventions (SI, radians inside):
- Node angles theta_i [rad] are crank angles in cylinder 1's convention (0 = its firing TDC), unwrapped; omega_i [rad/s].
  Twist theta_i - theta_(i+1) > 0 means node i leads.
- Cylinder k sits on node ``cyl_node[k]`` at local angle theta_k = theta_node - phase_k (0 = its firing TDC), so its
  pressure, kinematics and friction follow its OWN throw (twist shifts their phase).
- Each throw obeys the exact Lagrange equation of its variable inertia (physics.md §3, R1):
      J_j(theta_j) alpha_j + 1/2 J_j'(theta_j) omega_j^2 = sum_cyl (T_g - T_f) + shaft torques,
      J_j = J_rot,j + sum_(cyl on j) m_rec x'(theta_k)^2,  1/2 J_j' = sum m_rec x' x''.
  With variable inertia off, ``node_inertia`` already holds the mean reciprocating inertia and 1/2 J' omega^2 = 0.
- Gas torque T_g = (p - p_cc) A x' (positive = driving); friction T_f = sum_l a_kl F_kl + extra, a magnitude that
  opposes rotation; the load torque T_L acts on the load node and opposes rotation.
- Load law ``load`` = [kind, c, k, s, T0, Ke, De, delta0, Omega_g, ripple_nm, ripple_order, ripple_phase]:
  kind 0: T_L = c + k omega_L^s; kind 1 (grid): T_L = T0 + Ke (theta_L - Omega_g t - delta0) + De (omega_L - Omega_g);
  both plus ripple_nm sin(ripple_order theta_L + ripple_phase).

Friction: the L terms of the model's loss-term library (core.model.terms), evaluated by their own kernels on the
sample rows ``fill_sample`` forms; they come in ``cylinders`` = (cyl_node, phase, coef (z, L), extra, kernels) as a
tuple of first-class functions of one type (terms.KERNEL_SIGNATURE), so this cached kernel serves any library.

The kernels take their inputs in named records (core.plant.sim_run.PlantRun builds them): ``PlantArrays``, what the
right-hand side reads, built once per run and updated in place, with the ``PressureTraces`` inside it; ``Firing``,
what makes each cycle's pressure trace, rebuilt per ``advance`` call (its perturbation and leak arrays are replaced
between calls). The per-cylinder helpers take the record fields as plain arguments: unpacking a record per cylinder
and RK4 stage made the integrator ~40 % slower (measured), unpacking once per stage costs nothing measurable.

Integrated alongside the state by the same RK4 weights (so energy closes to the integrator's accuracy), per cylinder
k (``nq_cyl(L)`` values from k*nq_cyl(L)): gas power T_g omega, the L F_l omega, extra-friction power; then four globals:
load power T_L omega_L, relative-damper power sum c_i (omega_i - omega_(i+1))^2, int T_L dt, int (theta_L - Omega_g t) dt.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numba
import numpy as np
from frictionwatch.core.model.jit import BORROWING, sincos
from frictionwatch.core.model.terms import N_FIELDS, fill_sample, sample_rows
from frictionwatch.core.model.thermo import cycle_pressure_kernel
from frictionwatch.core.model.torques import gas_torque_sample
from numba.core.errors import NumbaExperimentalFeatureWarning

# the library's kernels reach the RK4 kernel as a tuple of first-class functions of one signature (numba calls that
# feature experimental; it is what lets one cached plant kernel serve any term library): said once here, not to a user
warnings.filterwarnings("ignore", message="First-class function type", category=NumbaExperimentalFeatureWarning)

NQ_GLOBAL = 4
# scalar layout ``sc``
(S_R, S_L, S_E, S_AREA, S_PCC, S_MREC, S_VARJ, S_FLY, S_LOAD, S_WHEEL_OFF, S_CAM, S_PPERIOD, S_T0OUT, S_LPERIOD,
 S_GRID, S_CMIN, S_H, S_QPERKG, S_NODE2, S_NSC) = range(20)
# operating point ``op`` (updated between calls): fuel [kg], SOC [rad], beta_p, p_IVC, p_int, p_exh [Pa], omega est
OP_FUEL, OP_SOC, OP_BETA, OP_PIVC, OP_PINT, OP_PEXH, OP_OMEGA, OP_N = range(8)
# integer state ``ist``
(I_NEXT_CYCLE, I_NEXT_GRID, I_NEXT_EDGE, I_NEXT_CAM, I_NEXT_SAMPLE, I_NEXT_LOAD, I_N_CYC, I_N_GRID, I_N_EDGE,
 I_N_CAM, I_N_SAMPLE, I_N_LOAD, I_STATUS, I_NEXT_EDGE2, I_N_EDGE2, I_NIST) = range(16)
TWO_PI = 2.0 * np.pi
FOUR_PI = 4.0 * np.pi
TRACE_LEAD = np.radians(30.0)  # next cycle's trace is made 30 deg before its gas-exchange TDC


class PressureTraces(NamedTuple):
    """Each cylinder's pressure over its last three combustion cycles: ``pressure`` (z, 3, n+1) [Pa] on the thermo
    grid -2 pi + i ``step`` [rad] of the local angle (core.model.thermo), slot c % 3 holding cycle ``cycle[k, slot]``
    (z, 3) int64."""

    pressure: np.ndarray
    cycle: np.ndarray
    step: float


class PlantArrays(NamedTuple):
    """What the plant's right-hand side reads: ``nodes`` = (inertia, stiffness, damping, and three (n,) work arrays),
    ``cylinders`` = (cyl_node, phase, coef (z, L), extra (z, 4), the library's kernels), ``scalars`` (S_* layout),
    ``friction`` the friction constants (EngineSpec.friction_params()), ``load`` the load law (12,) and ``traces``."""

    nodes: tuple
    cylinders: tuple
    scalars: np.ndarray
    friction: np.ndarray
    load: np.ndarray
    traces: PressureTraces


class Firing(NamedTuple):
    """What makes each cycle's pressure trace: operating point ``op`` (OP_* layout), per cylinder-cycle perturbations
    ``pert`` (z, cycles, 3) = (fuel factor, SOC shift rad, premixed factor), ``leak`` (z,) areas [m^2], and the
    cylinder model's constants, vol_half, dvol_half (core.model.thermo.CylinderModel)."""

    op: np.ndarray
    pert: np.ndarray
    leak: np.ndarray
    constants: np.ndarray
    vol_half: np.ndarray
    dvol_half: np.ndarray


@numba.njit(cache=True)
def nq_cyl(n_terms):
    """Integrated powers per cylinder: gas, the n_terms friction terms, extra friction."""
    return n_terms + 2


def work_arrays(z: int, n_terms: int) -> tuple:
    """The per-cylinder work arrays of ``plant_rhs``: local angle, speed, gauge pressure, sample rows
    (N_FIELDS, z, 1), x', x'', pressure, basis (n_terms, z, 1) (a term may depend on the cylinder: one row each)."""
    return (np.zeros(z), np.zeros(z), np.zeros(z), np.zeros((N_FIELDS, z, 1)), np.zeros(z), np.zeros(z), np.zeros(z),
            np.zeros((n_terms, z, 1)))


@numba.njit(**BORROWING)
def _trace_lookup(traces, slot_cycle, k, theta, tstep):
    """Pressure [Pa] of cylinder k at unwrapped local angle theta from the trace of its cycle (linear interpolation);
    traces, slot_cycle, tstep: the fields of PressureTraces (plain arguments: this runs per cylinder and RK4 stage)."""
    c = math.floor((theta + TWO_PI) / FOUR_PI)
    slot = c % 3
    if slot_cycle[k, slot] != c:
        return np.nan
    u = (theta - FOUR_PI * c + TWO_PI) / tstep
    i = int(u)
    n = traces.shape[2] - 1
    if i >= n:
        i = n - 1
    f = u - i
    return traces[k, slot, i] * (1.0 - f) + traces[k, slot, i + 1] * f


@numba.njit(**BORROWING)
def _ensure_traces(th, model, firing, q):
    """Make sure every cylinder holds the trace of its current combustion cycle, and of the next one once it is
    within ``TRACE_LEAD`` of the gas-exchange TDC that starts it (so a load step reaches the next intake).
    q (8,) is work space for the cycle parameters (core.model.thermo.cycle_params layout)."""
    sc = model.scalars
    cyl_node, phase = model.cylinders[0], model.cylinders[1]
    traces, slot_cycle = model.traces.pressure, model.traces.cycle
    op, pert, leak = firing.op, firing.pert, firing.leak
    z = phase.shape[0]
    cmin = int(sc[S_CMIN])
    for k in range(z):
        loc = th[cyl_node[k]] - phase[k]
        cnow = math.floor((loc + TWO_PI) / FOUR_PI)
        for c in (cnow, cnow + 1):
            slot = c % 3
            if slot_cycle[k, slot] == c or (c > cnow and loc < FOUR_PI * cnow + TWO_PI - TRACE_LEAD):
                continue
            ic = c - cmin
            ff, dsoc, fb = 1.0, 0.0, 1.0
            if 0 <= ic < pert.shape[1]:
                ff, dsoc, fb = pert[k, ic, 0], pert[k, ic, 1], pert[k, ic, 2]
            q[0] = sc[S_QPERKG] * op[OP_FUEL] * ff
            q[1] = op[OP_SOC] + dsoc
            q[2] = min(max(op[OP_BETA] * fb, 0.0), 1.0)
            q[3] = leak[k]
            q[4] = op[OP_OMEGA]
            q[5] = op[OP_PIVC]
            q[6] = op[OP_PINT]
            q[7] = op[OP_PEXH]
            cycle_pressure_kernel(firing.vol_half, firing.dvol_half, firing.constants, q, traces[k, slot])
            slot_cycle[k, slot] = c


@numba.njit(**BORROWING)
def _cylinder_terms(th, om, sc, cyl_node, phase, fprm, traces, slot_cycle, tstep, w, kernels):
    """Per-cylinder local angle, speed, pressure, sample rows, x', x'' and the library's friction basis into ``w``
    (the record fields as plain arguments: this runs once per RK4 stage)."""
    loc, omc, pg, samples, dx, ddx, pres, fb = w
    r = sc[S_R]
    inv_rod = 1.0 / sc[S_L]
    e = sc[S_E]
    for k in range(phase.shape[0]):
        j = cyl_node[k]
        loc[k] = th[j] - phase[k]
        omc[k] = om[j]
        pres[k] = _trace_lookup(traces, slot_cycle, k, loc[k], tstep)
        pg[k] = pres[k] - sc[S_PCC]
        sin_a, cos_a = sincos(loc[k])
        dx[k], ddx[k] = fill_sample(sample_rows(samples, k), 0, loc[k], sin_a, cos_a, omc[k], pg[k], r, inv_rod, e)
    for m in range(len(kernels)):
        kernels[m](samples, fprm, fb[m])


@numba.njit(**BORROWING)
def _extra_ripple(k, extra, loc):
    """extra_amp cos(order theta_k + phase) [N m]; no cosine where the amplitude is 0 (every cylinder but an
    extra-friction one: two cosines per cylinder and RK4 stage saved), which adds the same exact 0 to the sums."""
    if extra[k, 1] == 0.0:
        return 0.0
    return extra[k, 1] * math.cos(extra[k, 2] * loc[k] + extra[k, 3])


@numba.njit(**BORROWING)
def _friction_torque(k, coef, extra, fb, ripple):
    """T_f,k = sum_l a_kl F_kl + extra_mean + ripple [N m] (ripple = ``_extra_ripple``)."""
    s = 0.0
    for m in range(coef.shape[1]):
        s += coef[k, m] * fb[m, k, 0]
    return s + extra[k, 0] + ripple


@numba.njit(**BORROWING)
def _load_torque(t, th_l, om_l, lp):
    """T_L of the load law ``lp`` [N m]. The usual laws skip two libm calls a right-hand side with the same numbers:
    exponent s = 1 (pow(x, 1) is x exactly) and no ripple (tl + 0 sin(..) is tl; a -0.0 torque could only turn +0.0);
    ~5 % of deutz-1cyl's advance (design note 116)."""
    if lp[0] == 0.0:
        speed = max(om_l, 0.0)
        tl = lp[1] + lp[2] * (speed if lp[3] == 1.0 else speed ** lp[3])
    else:
        tl = lp[4] + lp[5] * (th_l - lp[8] * t - lp[7]) + lp[6] * (om_l - lp[8])
    if lp[9] == 0.0:
        return tl
    return tl + lp[9] * math.sin(lp[10] * th_l + lp[11])


@numba.njit(**BORROWING)
def plant_rhs(t, th, om, model, w, acc, pw):
    """Angular accelerations ``acc`` [rad/s^2] and integrand powers ``pw`` at (t, th, om) of the plant ``model``
    (PlantArrays); w = ``work_arrays(z, L)``."""
    inertia, stiff, damp, tq, jv, hdj = model.nodes
    cyl_node, phase, coef, extra, kernels = model.cylinders
    sc = model.scalars
    lp = model.load
    traces, slot_cycle, tstep = model.traces
    n = inertia.shape[0]
    n_terms = coef.shape[1]
    nq = nq_cyl(n_terms)
    _cylinder_terms(th, om, sc, cyl_node, phase, model.friction, traces, slot_cycle, tstep, w, kernels)
    loc, omc, pg, _samples, dx, ddx, _pres, fb = w
    for i in range(n):
        tq[i] = 0.0
        jv[i] = inertia[i]
        hdj[i] = 0.0
    pdamp = 0.0
    for i in range(n - 1):
        dw = om[i] - om[i + 1]
        s = stiff[i] * (th[i] - th[i + 1]) + damp[i] * dw
        tq[i] -= s
        tq[i + 1] += s
        pdamp += damp[i] * dw * dw
    varj = sc[S_VARJ] > 0.5
    m_rec = sc[S_MREC]
    for k in range(phase.shape[0]):
        j = cyl_node[k]
        tg = gas_torque_sample(pg[k], sc[S_AREA], dx[k])
        ripple = _extra_ripple(k, extra, loc)
        tf = _friction_torque(k, coef, extra, fb, ripple)
        tq[j] += tg - tf
        if varj:
            jv[j] += m_rec * dx[k] * dx[k]
            hdj[j] += m_rec * dx[k] * ddx[k]
        b = k * nq
        pw[b] = tg * omc[k]
        for m in range(n_terms):
            pw[b + 1 + m] = fb[m, k, 0] * omc[k]
        pw[b + n_terms + 1] = (extra[k, 0] + ripple) * omc[k]
    ln = int(sc[S_LOAD])
    tl = _load_torque(t, th[ln], om[ln], lp)
    tq[ln] -= tl
    for i in range(n):
        acc[i] = (tq[i] - hdj[i] * om[i] * om[i]) / jv[i]
    g = phase.shape[0] * nq
    pw[g] = tl * om[ln]
    pw[g + 1] = pdamp
    pw[g + 2] = tl
    pw[g + 3] = th[ln] - lp[8] * t


@numba.njit(**BORROWING)
def _herm(s, h, y0, d0, y1, d1):
    """Cubic Hermite value at fraction s of a step of length h (y, dy/dt at both ends)."""
    s2 = s * s
    s3 = s2 * s
    return (2 * s3 - 3 * s2 + 1) * y0 + (s3 - 2 * s2 + s) * h * d0 + (3 * s2 - 2 * s3) * y1 + (s3 - s2) * h * d1


@numba.njit(**BORROWING)
def _herm_rate(s, h, y0, d0, y1, d1):
    """d/dt of ``_herm`` at fraction s."""
    s2 = s * s
    return ((6 * s2 - 6 * s) * y0 + (3 * s2 - 4 * s + 1) * h * d0 + (6 * s - 6 * s2) * y1 + (3 * s2 - 2 * s) * h * d1) / h


@numba.njit(**BORROWING)
def _crossing(target, h, y0, d0, y1, d1):
    """Fraction s in [0, 1] where the (monotone) Hermite angle reaches ``target`` (Newton from the chord)."""
    s = (target - y0) / (y1 - y0)
    for _ in range(4):
        r = _herm(s, h, y0, d0, y1, d1) - target
        d = _herm_rate(s, h, y0, d0, y1, d1) * h
        if d <= 0.0:
            break
        s -= r / d
        s = min(max(s, 0.0), 1.0)
    return s


@numba.njit(**BORROWING)
def _state_at(s, h, th0, om0, a0, th1, om1, a1, ths, oms):
    for i in range(th0.shape[0]):
        ths[i] = _herm(s, h, th0[i], om0[i], th1[i], om1[i])
        oms[i] = _herm(s, h, om0[i], a0[i], om1[i], a1[i])


@numba.njit(cache=True)
def advance(model, firing, edges, state, ist, outs, theta_stop, t_stop):
    """Integrate the plant ``model`` (PlantArrays) with the cycles' pressure made from ``firing`` (Firing) until the
    flywheel angle reaches ``theta_stop`` [rad], t reaches ``t_stop`` [s] or a buffer fills.

    edges = (wheel edge angles [rad], their tooth index, the second wheel's edge angles [rad] and tooth index, both
    empty without one); state = (th, om, acc, cumulative integrals, powers, pmax, [t, last cycle time]), updated in
    place. Writes events into ``outs`` = (cycles, grid, edge, cam, samples, load, second-wheel edge) at the counters
    in ``ist``. The second wheel turns with node ``sc[S_NODE2]`` (its own frame: no wheel offset) and returns the status: 0 angle reached, 1 time reached, 2 a buffer is full,
    3 a pressure lookup failed (bug), 4 state not finite.
    """
    inertia = model.nodes[0]
    cyl_node, phase, coef, extra, kernels = model.cylinders
    sc = model.scalars
    fprm = model.friction
    traces, slot_cycle, tstep = model.traces
    op = firing.op
    edge_angle, edge_index, edge_angle2, edge_index2 = edges
    th, om, acc, cum, pw, pmax, tarr = state
    o_cyc, o_grid, o_edge, o_cam, o_samp, o_load, o_edge2 = outs
    n = inertia.shape[0]
    z = phase.shape[0]
    nq = cum.shape[0]
    h = sc[S_H]
    fly = int(sc[S_FLY])
    q = np.zeros(8)
    w = (np.zeros(z), np.zeros(z), np.zeros(z), np.zeros((N_FIELDS, z, 1)), np.zeros(z), np.zeros(z), np.zeros(z),
         np.zeros((coef.shape[1], z, 1)))
    th2, om2, th1, om1, a1, a2, a3, a4 = (np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n),
                                          np.zeros(n), np.zeros(n), np.zeros(n))
    ths, oms = np.zeros(n), np.zeros(n)
    pw2, pw3, pw4, pw1n = np.zeros(nq), np.zeros(nq), np.zeros(nq), np.zeros(nq)
    npres = edge_angle.shape[0]
    npres2 = edge_angle2.shape[0]
    node2 = int(sc[S_NODE2])
    t0out = sc[S_T0OUT]
    _ensure_traces(th, model, firing, q)
    t = tarr[0]
    if ist[I_STATUS] == 0:  # first call: derivative at the initial state
        plant_rhs(t, th, om, model, w, acc, pw)
        ist[I_STATUS] = 1
    while True:
        if th[fly] >= theta_stop:
            return 0
        if t >= t_stop:
            return 1
        if (ist[I_N_CYC] + 2 > o_cyc.shape[0] or ist[I_N_GRID] + 8 > o_grid.shape[0] or
                ist[I_N_EDGE] + 8 > o_edge.shape[0] or ist[I_N_CAM] + 2 > o_cam.shape[0] or
                ist[I_N_SAMPLE] + 16 > o_samp.shape[0] or ist[I_N_LOAD] + 2 > o_load.shape[0] or
                (npres2 > 0 and ist[I_N_EDGE2] + 8 > o_edge2.shape[0])):
            return 2
        # ---- RK4 step (k1 = (om, acc) and pw at the current state are known) ----
        for i in range(n):
            th2[i] = th[i] + 0.5 * h * om[i]
            om2[i] = om[i] + 0.5 * h * acc[i]
        plant_rhs(t + 0.5 * h, th2, om2, model, w, a2, pw2)
        for i in range(n):
            th1[i] = om2[i]  # k2 for theta
            th2[i] = th[i] + 0.5 * h * om2[i]
            om2[i] = om[i] + 0.5 * h * a2[i]
        plant_rhs(t + 0.5 * h, th2, om2, model, w, a3, pw3)
        for i in range(n):
            om1[i] = om2[i]  # k3 for theta
            th2[i] = th[i] + h * om2[i]
            om2[i] = om[i] + h * a3[i]
        plant_rhs(t + h, th2, om2, model, w, a4, pw4)
        for i in range(n):
            dth = om[i] + 2.0 * th1[i] + 2.0 * om1[i] + om2[i]
            dom = acc[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i]
            th1[i] = th[i] + h / 6.0 * dth
            om1[i] = om[i] + h / 6.0 * dom
        t1 = t + h
        _ensure_traces(th1, model, firing, q)
        plant_rhs(t1, th1, om1, model, w, a1, pw1n)
        pres = w[6]
        if not np.isfinite(om1[fly]):
            return 4
        for k in range(z):
            if not np.isfinite(pres[k]):
                return 3
        # ---- events inside [t, t1] ----
        # cycle boundaries theta_F = 4 pi n: cumulative integrals (linear within the step), pmax, speed estimate
        while FOUR_PI * ist[I_NEXT_CYCLE] <= th1[fly]:
            s = _crossing(FOUR_PI * ist[I_NEXT_CYCLE], h, th[fly], om[fly], th1[fly], om1[fly])
            row = o_cyc[ist[I_N_CYC]]
            row[0] = t + s * h
            for m in range(nq):
                row[1 + m] = cum[m] + s * h / 6.0 * (pw[m] + 2.0 * pw2[m] + 2.0 * pw3[m] + pw4[m])
            for k in range(z):
                row[1 + nq + k] = pmax[k]
                pmax[k] = 0.0
            if tarr[1] >= 0.0:
                op[OP_OMEGA] = FOUR_PI / (row[0] - tarr[1])
            tarr[1] = row[0]
            ist[I_N_CYC] += 1
            ist[I_NEXT_CYCLE] += 1
        for m in range(nq):
            cum_new = cum[m] + h / 6.0 * (pw[m] + 2.0 * pw2[m] + 2.0 * pw3[m] + pw4[m])
            pw2[m] = cum_new  # keep the step-end cumulative values for the load samples below
        for k in range(z):
            pmax[k] = max(pmax[k], pres[k])
        # 1-deg grid of the flywheel angle: total friction torque and flywheel speed (output phase only)
        while ist[I_NEXT_GRID] * sc[S_GRID] <= th1[fly]:
            target = ist[I_NEXT_GRID] * sc[S_GRID]
            s = _crossing(target, h, th[fly], om[fly], th1[fly], om1[fly])
            _state_at(s, h, th, om, acc, th1, om1, a1, ths, oms)
            _cylinder_terms(ths, oms, sc, cyl_node, phase, fprm, traces, slot_cycle, tstep, w, kernels)
            tf = 0.0
            for k in range(z):
                tf += _friction_torque(k, coef, extra, w[7], _extra_ripple(k, extra, w[0]))
            g = o_grid[ist[I_N_GRID]]
            g[0] = t + s * h
            g[1] = tf
            g[2] = oms[fly]
            ist[I_N_GRID] += 1
            ist[I_NEXT_GRID] += 1
        # tooth edges and cam edges on the wheel frame theta_W = theta_F + wheel offset
        off = sc[S_WHEEL_OFF]
        while True:
            e = ist[I_NEXT_EDGE]
            r = e // npres
            j = e - r * npres
            target = edge_angle[j] + TWO_PI * r - off
            if target > th1[fly]:
                break
            s = _crossing(target, h, th[fly], om[fly], th1[fly], om1[fly])
            o_edge[ist[I_N_EDGE], 0] = t + s * h
            o_edge[ist[I_N_EDGE], 1] = edge_index[j]
            ist[I_N_EDGE] += 1
            ist[I_NEXT_EDGE] += 1
        while npres2 > 0:  # the second wheel's edges, at its own node
            e = ist[I_NEXT_EDGE2]
            r = e // npres2
            j = e - r * npres2
            target = edge_angle2[j] + TWO_PI * r
            if target > th1[node2]:
                break
            s = _crossing(target, h, th[node2], om[node2], th1[node2], om1[node2])
            o_edge2[ist[I_N_EDGE2], 0] = t + s * h
            o_edge2[ist[I_N_EDGE2], 1] = edge_index2[j]
            ist[I_N_EDGE2] += 1
            ist[I_NEXT_EDGE2] += 1
        while sc[S_CAM] + FOUR_PI * ist[I_NEXT_CAM] - off <= th1[fly]:
            target = sc[S_CAM] + FOUR_PI * ist[I_NEXT_CAM] - off
            s = _crossing(target, h, th[fly], om[fly], th1[fly], om1[fly])
            o_cam[ist[I_N_CAM]] = t + s * h
            ist[I_N_CAM] += 1
            ist[I_NEXT_CAM] += 1
        # pressure samples at t0out + i * period (true pressure at each cylinder's own throw angle)
        while t0out + ist[I_NEXT_SAMPLE] * sc[S_PPERIOD] <= t1:
            ts = t0out + ist[I_NEXT_SAMPLE] * sc[S_PPERIOD]
            s = min(max((ts - t) / h, 0.0), 1.0)
            row = o_samp[ist[I_N_SAMPLE]]
            for k in range(z):
                j = cyl_node[k]
                thk = _herm(s, h, th[j], om[j], th1[j], om1[j]) - phase[k]
                row[k] = _trace_lookup(traces, slot_cycle, k, thk, tstep)
            ist[I_N_SAMPLE] += 1
            ist[I_NEXT_SAMPLE] += 1
        # load samples: cumulative int T_L dt and int T_L omega_L dt at t0out + i * period
        g0 = z * nq_cyl(coef.shape[1])
        while t0out + ist[I_NEXT_LOAD] * sc[S_LPERIOD] <= t1:
            tl = t0out + ist[I_NEXT_LOAD] * sc[S_LPERIOD]
            s = min(max((tl - t) / h, 0.0), 1.0)
            o_load[ist[I_N_LOAD], 0] = tl
            o_load[ist[I_N_LOAD], 1] = cum[g0 + 2] + s * (pw2[g0 + 2] - cum[g0 + 2])
            o_load[ist[I_N_LOAD], 2] = cum[g0] + s * (pw2[g0] - cum[g0])
            ist[I_N_LOAD] += 1
            ist[I_NEXT_LOAD] += 1
        # ---- accept the step ----
        for m in range(nq):
            cum[m] = pw2[m]
            pw[m] = pw1n[m]
        for i in range(n):
            th[i] = th1[i]
            om[i] = om1[i]
            acc[i] = a1[i]
        t = t1
        tarr[0] = t
