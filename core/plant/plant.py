"""Time-domain plant: the torsional chain of physics.md §11, its right-hand side in two parts (numba): what the
cylinders put on each node (``cylinder_forcing``, the costly part) and the shaft line's own (``chain_accel``);
core.plant.plant_advance integrates them (the cylinders once a step, the shaft line by RK4; design note 123).

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

Integrated alongside the state (core.plant.plant_advance: on the parabola in time through three steps' values), per
cylinder k (``nq_cyl(L)`` values from k*nq_cyl(L)): gas power T_g omega, the L F_l omega, extra-friction power; then
four globals:
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
N_FQ = 3  # the cylinders' node quantities (cylinder_forcing): torque, inertia, half its derivative
# scalar layout ``sc``
(S_R, S_L, S_E, S_AREA, S_PCC, S_MREC, S_VARJ, S_FLY, S_LOAD, S_WHEEL_OFF, S_CAM, S_PPERIOD, S_T0OUT, S_LPERIOD,
 S_GRID, S_CMIN, S_H, S_QPERKG, S_NODE2, S_OUT_AT, S_GRID_FRICTION, S_NSC) = range(22)
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
def trace_lookup(traces, slot_cycle, k, theta, tstep):
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
def ensure_traces(th, model, firing, q):
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
def cylinder_terms(th, om, sc, cyl_node, phase, fprm, traces, slot_cycle, tstep, w, kernels):
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
        pres[k] = trace_lookup(traces, slot_cycle, k, loc[k], tstep)
        pg[k] = pres[k] - sc[S_PCC]
        sin_a, cos_a = sincos(loc[k])
        dx[k], ddx[k] = fill_sample(sample_rows(samples, k), 0, loc[k], sin_a, cos_a, omc[k], pg[k], r, inv_rod, e)
    for m in range(len(kernels)):
        kernels[m](samples, fprm, fb[m])


@numba.njit(**BORROWING)
def extra_ripple(k, extra, loc):
    """extra_amp cos(order theta_k + phase) [N m]; no cosine where the amplitude is 0 (every cylinder but an
    extra-friction one: two cosines per cylinder and RK4 stage saved), which adds the same exact 0 to the sums."""
    if extra[k, 1] == 0.0:
        return 0.0
    return extra[k, 1] * math.cos(extra[k, 2] * loc[k] + extra[k, 3])


@numba.njit(**BORROWING)
def friction_torque(k, coef, extra, fb, ripple):
    """T_f,k = sum_l a_kl F_kl + extra_mean + ripple [N m] (ripple = ``extra_ripple``)."""
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
def cylinder_forcing(th, om, model, w, fq, pw):
    """What the cylinders put on the shaft line at (th, om): per node ``fq`` (N_FQ, n) = (gas minus friction
    torque [N m], inertia [kg m^2] = rotating + sum m_rec x'^2, half its angle derivative sum m_rec x' x'' [kg m^2]),
    and
    the per-cylinder powers pw[:z nq] (gas, each loss term, extra friction, each x its throw's speed) [W]; w =
    ``work_arrays(z, L)``. This is the simulator's costly part (per cylinder: a pressure lookup, a sincos, the
    library's kernels); the shaft line's own arithmetic is ``chain_accel``."""
    inertia = model.nodes[0]
    cyl_node, phase, coef, extra, kernels = model.cylinders
    sc = model.scalars
    traces, slot_cycle, tstep = model.traces
    n_terms = coef.shape[1]
    nq = nq_cyl(n_terms)
    cylinder_terms(th, om, sc, cyl_node, phase, model.friction, traces, slot_cycle, tstep, w, kernels)
    loc, omc, pg, _samples, dx, ddx, _pres, fb = w
    for i in range(inertia.shape[0]):
        fq[0, i] = 0.0
        fq[1, i] = inertia[i]
        fq[2, i] = 0.0
    varj = sc[S_VARJ] > 0.5
    m_rec = sc[S_MREC]
    for k in range(phase.shape[0]):
        j = cyl_node[k]
        tg = gas_torque_sample(pg[k], sc[S_AREA], dx[k])
        ripple = extra_ripple(k, extra, loc)
        tf = friction_torque(k, coef, extra, fb, ripple)
        fq[0, j] += tg - tf
        if varj:
            fq[1, j] += m_rec * dx[k] * dx[k]
            fq[2, j] += m_rec * dx[k] * ddx[k]
        b = k * nq
        pw[b] = tg * omc[k]
        for m in range(n_terms):
            pw[b + 1 + m] = fb[m, k, 0] * omc[k]
        pw[b + n_terms + 1] = (extra[k, 0] + ripple) * omc[k]


@numba.njit(**BORROWING)
def chain_accel(t, th, om, model, fq, acc, gp):
    """Node accelerations ``acc`` [rad/s^2] at (t, th, om) of the shaft line (its sections' springs and dampers, the
    load) under the cylinders' node quantities ``fq`` (N_FQ, n) (``cylinder_forcing``'s, or their interpolation in
    time), each throw by its Lagrange equation J alpha + 1/2 J' omega^2 = torque; the global powers into gp (4,):
    load power T_L omega_L, relative-damper power, T_L, theta_L - Omega_g t."""
    inertia, stiff, damp, tq, _jv, _hdj = model.nodes
    sc = model.scalars
    lp = model.load
    n = inertia.shape[0]
    for i in range(n):
        tq[i] = fq[0, i]
    pdamp = 0.0
    for i in range(n - 1):
        dw = om[i] - om[i + 1]
        s = stiff[i] * (th[i] - th[i + 1]) + damp[i] * dw
        tq[i] -= s
        tq[i + 1] += s
        pdamp += damp[i] * dw * dw
    ln = int(sc[S_LOAD])
    tl = _load_torque(t, th[ln], om[ln], lp)
    tq[ln] -= tl
    for i in range(n):
        acc[i] = (tq[i] - fq[2, i] * om[i] * om[i]) / fq[1, i]
    gp[0] = tl * om[ln]
    gp[1] = pdamp
    gp[2] = tl
    gp[3] = th[ln] - lp[8] * t


@numba.njit(cache=True)
def plant_rhs(t, th, om, model, w, acc, pw):
    """Angular accelerations ``acc`` [rad/s^2] and integrand powers ``pw`` (per cylinder, then the NQ_GLOBAL
    globals) at (t, th, om) of the plant ``model`` (PlantArrays): ``cylinder_forcing`` then ``chain_accel``, as the
    integrator composes them; w = ``work_arrays(z, L)``."""
    fq = np.zeros((N_FQ, th.shape[0]))
    gp = np.zeros(NQ_GLOBAL)
    cylinder_forcing(th, om, model, w, fq, pw)
    chain_accel(t, th, om, model, fq, acc, gp)
    g = pw.shape[0] - NQ_GLOBAL
    for m in range(NQ_GLOBAL):
        pw[g + m] = gp[m]
