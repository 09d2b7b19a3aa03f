"""The plant's integrator: the cylinders evaluated once a step, the shaft line by RK4 between (design note 123).

A step [t, t + h] of the plant (core.plant.plant):
1. predictor: one RK4 step of the shaft line alone (``chain_accel``) with the cylinders' node quantities (torque,
   inertia, half its derivative: ``cylinder_forcing``) extrapolated linearly in time from t - h and t;
2. the cylinders evaluated once, at the predicted state at t + h (``cylinder_forcing``: the pressure lookups, the
   kinematics and the loss terms, ~80 % of a right-hand side's cost, design note 116);
3. corrector: the RK4 step again, the cylinders' quantities now on the parabola through t - h, t and t + h; the
   state at t + h is its result, and the cylinders' quantities at t + h stay those of step 2 for the next step.
The cylinders' powers (gas, loss terms, extra friction) and the shaft line's (load, dampers) are integrated over the
step on the same parabola in time (Adams-Moulton, third order); a cycle boundary inside the step takes the parabola's
integral up to it.

Why: RK4 on the whole plant evaluates the cylinders four times a step. Here they are evaluated once, and the shaft
line, whose fastest mode sets the step (0.5 / w_max), is still integrated by RK4 through its own stages, each a few
flops a node. What the cylinders put on the shaft varies with their throw's angle, which moves ~0.25 deg a step: a
parabola in time through three steps follows it to third order, as RK4 follows it to fourth, and both meet the
pressure trace's 0.25-deg linear pieces (kinks) the same way. The errors against RK4 at half the step are in design
note 123 (they are below today's RK4's own).

Events inside a step (cycle boundaries, the 1-deg grid, tooth and cam edges, pressure and load samples) are placed
on the cubic Hermite through the step's ends (``step_events``), as before; so is tick 0, the output's time origin
(the flywheel's crossing of ``sc[S_OUT_AT]``), so that no record's time depends on where the step grid falls.
"""

from __future__ import annotations

import numba
import numpy as np
from frictionwatch.core.model.jit import BORROWING
from frictionwatch.core.model.terms import N_FIELDS
from frictionwatch.core.plant.plant import (
    FOUR_PI,
    I_N_CAM,
    I_N_CYC,
    I_N_EDGE,
    I_N_EDGE2,
    I_N_GRID,
    I_N_LOAD,
    I_N_SAMPLE,
    I_NEXT_CAM,
    I_NEXT_CYCLE,
    I_NEXT_EDGE,
    I_NEXT_EDGE2,
    I_NEXT_GRID,
    I_NEXT_LOAD,
    I_NEXT_SAMPLE,
    I_STATUS,
    N_FQ,
    NQ_GLOBAL,
    OP_OMEGA,
    S_CAM,
    S_FLY,
    S_GRID,
    S_GRID_FRICTION,
    S_H,
    S_LPERIOD,
    S_NODE2,
    S_OUT_AT,
    S_PPERIOD,
    S_T0OUT,
    S_WHEEL_OFF,
    TWO_PI,
    chain_accel,
    cylinder_forcing,
    cylinder_terms,
    ensure_traces,
    extra_ripple,
    friction_torque,
    nq_cyl,
    trace_lookup,
)


@numba.njit(**BORROWING)
def herm(s, h, y0, d0, y1, d1):
    """Cubic Hermite value at fraction s of a step of length h (y, dy/dt at both ends)."""
    s2 = s * s
    s3 = s2 * s
    return (2 * s3 - 3 * s2 + 1) * y0 + (s3 - 2 * s2 + s) * h * d0 + (3 * s2 - 2 * s3) * y1 + (s3 - s2) * h * d1


@numba.njit(**BORROWING)
def herm_rate(s, h, y0, d0, y1, d1):
    """d/dt of ``herm`` at fraction s."""
    s2 = s * s
    return ((6 * s2 - 6 * s) * y0 + (3 * s2 - 4 * s + 1) * h * d0 + (6 * s - 6 * s2) * y1 + (3 * s2 - 2 * s) * h * d1) / h


@numba.njit(**BORROWING)
def crossing(target, h, y0, d0, y1, d1):
    """Fraction s in [0, 1] where the (monotone) Hermite angle reaches ``target`` (Newton from the chord)."""
    s = (target - y0) / (y1 - y0)
    for _ in range(4):
        r = herm(s, h, y0, d0, y1, d1) - target
        d = herm_rate(s, h, y0, d0, y1, d1) * h
        if d <= 0.0:
            break
        s -= r / d
        s = min(max(s, 0.0), 1.0)
    return s


@numba.njit(**BORROWING)
def _state_at(s, h, th0, om0, a0, th1, om1, a1, ths, oms):
    for i in range(th0.shape[0]):
        ths[i] = herm(s, h, th0[i], om0[i], th1[i], om1[i])
        oms[i] = herm(s, h, om0[i], a0[i], om1[i], a1[i])


@numba.njit(**BORROWING)
def full_buffer(ist, outs, two_wheels):
    """True when an output buffer may not hold one more step's events."""
    o_cyc, o_grid, o_edge, o_cam, o_samp, o_load, o_edge2 = outs
    return (ist[I_N_CYC] + 2 > o_cyc.shape[0] or ist[I_N_GRID] + 8 > o_grid.shape[0] or
            ist[I_N_EDGE] + 8 > o_edge.shape[0] or ist[I_N_CAM] + 2 > o_cam.shape[0] or
            ist[I_N_SAMPLE] + 16 > o_samp.shape[0] or ist[I_N_LOAD] + 2 > o_load.shape[0] or
            (two_wheels and ist[I_N_EDGE2] + 8 > o_edge2.shape[0]))


@numba.njit(**BORROWING)
def step_events(model, op, edges, outs, ist, state, end, quad):
    """Record the events inside the step from ``state`` (th, om, acc, cum, pw, pmax, [t, ..]) to ``end`` = (th1,
    om1, a1, pressures at t + h) into ``outs`` at the counters ``ist``, all but the 1-deg grid (``grid_*``); quad
    (3, nq): the step's integrals up to fraction s are cum + s quad[0] + s^2 quad[1] + s^3 quad[2] (their sum at
    s = 1 goes into quad[0] for the caller)."""
    cyl_node, phase, coef = model.cylinders[0], model.cylinders[1], model.cylinders[2]
    sc = model.scalars
    traces, slot_cycle, tstep = model.traces
    edge_angle, edge_index, edge_angle2, edge_index2 = edges
    th, om, cum, pmax, tarr = state[0], state[1], state[3], state[5], state[6]
    th1, om1, pres = end[0], end[1], end[3]
    o_cyc, o_edge, o_cam, o_samp, o_load, o_edge2 = outs[0], outs[2], outs[3], outs[4], outs[5], outs[6]
    z = phase.shape[0]
    nq = cum.shape[0]
    h = sc[S_H]
    t = tarr[0]
    t1 = t + h
    fly = int(sc[S_FLY])
    npres, npres2 = edge_angle.shape[0], edge_angle2.shape[0]
    # tick 0 at the exact crossing of the armed angle inside this step, once (a step-grid tick 0 moved every record's
    # time by up to a step between two step sizes: design note 123, "landed"); edges are recorded from it on
    if sc[S_OUT_AT] <= th1[fly]:
        s = crossing(sc[S_OUT_AT], h, th[fly], om[fly], th1[fly], om1[fly])
        sc[S_T0OUT] = t + s * h
        sc[S_OUT_AT] = np.inf
    t0out = sc[S_T0OUT]
    # cycle boundaries theta_F = 4 pi n: cumulative integrals (the step's polynomial), pmax, speed estimate
    while FOUR_PI * ist[I_NEXT_CYCLE] <= th1[fly]:
        s = crossing(FOUR_PI * ist[I_NEXT_CYCLE], h, th[fly], om[fly], th1[fly], om1[fly])
        row = o_cyc[ist[I_N_CYC]]
        row[0] = t + s * h
        for m in range(nq):
            row[1 + m] = cum[m] + s * quad[0, m] + s * s * quad[1, m] + s * s * s * quad[2, m]
        for k in range(z):
            row[1 + nq + k] = pmax[k]
            pmax[k] = 0.0
        if tarr[1] >= 0.0:
            op[OP_OMEGA] = FOUR_PI / (row[0] - tarr[1])
        tarr[1] = row[0]
        ist[I_N_CYC] += 1
        ist[I_NEXT_CYCLE] += 1
    for m in range(nq):  # the step-end cumulative values, for the load samples below and the caller
        quad[0, m] = cum[m] + quad[0, m] + quad[1, m] + quad[2, m]
    cum_new = quad[0]
    for k in range(z):
        pmax[k] = max(pmax[k], pres[k])
    # tooth edges and cam edges on the wheel frame theta_W = theta_F + wheel offset
    off = sc[S_WHEEL_OFF]
    while True:
        e = ist[I_NEXT_EDGE]
        r = e // npres
        j = e - r * npres
        target = edge_angle[j] + TWO_PI * r - off
        if target > th1[fly]:
            break
        s = crossing(target, h, th[fly], om[fly], th1[fly], om1[fly])
        if t + s * h >= t0out:
            o_edge[ist[I_N_EDGE], 0] = t + s * h
            o_edge[ist[I_N_EDGE], 1] = edge_index[j]
            ist[I_N_EDGE] += 1
        ist[I_NEXT_EDGE] += 1
    node2 = int(sc[S_NODE2])
    while npres2 > 0:  # the second wheel's edges, at its own node
        e = ist[I_NEXT_EDGE2]
        r = e // npres2
        j = e - r * npres2
        target = edge_angle2[j] + TWO_PI * r
        if target > th1[node2]:
            break
        s = crossing(target, h, th[node2], om[node2], th1[node2], om1[node2])
        if t + s * h >= t0out:
            o_edge2[ist[I_N_EDGE2], 0] = t + s * h
            o_edge2[ist[I_N_EDGE2], 1] = edge_index2[j]
            ist[I_N_EDGE2] += 1
        ist[I_NEXT_EDGE2] += 1
    while sc[S_CAM] + FOUR_PI * ist[I_NEXT_CAM] - off <= th1[fly]:
        target = sc[S_CAM] + FOUR_PI * ist[I_NEXT_CAM] - off
        s = crossing(target, h, th[fly], om[fly], th1[fly], om1[fly])
        if t + s * h >= t0out:
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
            thk = herm(s, h, th[j], om[j], th1[j], om1[j]) - phase[k]
            row[k] = trace_lookup(traces, slot_cycle, k, thk, tstep)
        ist[I_N_SAMPLE] += 1
        ist[I_NEXT_SAMPLE] += 1
    # load samples: cumulative int T_L dt and int T_L omega_L dt at t0out + i * period
    g0 = z * nq_cyl(coef.shape[1])
    while t0out + ist[I_NEXT_LOAD] * sc[S_LPERIOD] <= t1:
        tl = t0out + ist[I_NEXT_LOAD] * sc[S_LPERIOD]
        s = min(max((tl - t) / h, 0.0), 1.0)
        o_load[ist[I_N_LOAD], 0] = tl
        o_load[ist[I_N_LOAD], 1] = cum[g0 + 2] + s * (cum_new[g0 + 2] - cum[g0 + 2])
        o_load[ist[I_N_LOAD], 2] = cum[g0] + s * (cum_new[g0] - cum[g0])
        ist[I_N_LOAD] += 1
        ist[I_NEXT_LOAD] += 1


@numba.njit(**BORROWING)
def grid_points(model, ist, state, end, o_grid, w, scratch):
    """The 1-deg grid points of the flywheel angle inside the step (output phase only): time, the cylinders' total
    friction torque evaluated at the point's state on the Hermite (NaN with ``sc[S_GRID_FRICTION]`` 0: a third of
    the cylinders' evaluations, kept only where something reads it, design note 129), flywheel speed (a parabola in
    time through the step's ends was tried: up to 0.6 % of the peak off, design note 123); w: ``work_arrays``
    (overwritten), scratch (2, n)."""
    cyl_node, phase, coef, extra, kernels = model.cylinders
    sc = model.scalars
    traces, slot_cycle, tstep = model.traces
    th, om, acc, tarr = state[0], state[1], state[2], state[6]
    th1, om1, a1 = end[0], end[1], end[2]
    ths, oms = scratch[0], scratch[1]
    z = phase.shape[0]
    h = sc[S_H]
    t = tarr[0]
    fly = int(sc[S_FLY])
    with_friction = sc[S_GRID_FRICTION] > 0.5
    while ist[I_NEXT_GRID] * sc[S_GRID] <= th1[fly]:
        target = ist[I_NEXT_GRID] * sc[S_GRID]
        s = crossing(target, h, th[fly], om[fly], th1[fly], om1[fly])
        _state_at(s, h, th, om, acc, th1, om1, a1, ths, oms)
        tf = np.nan
        if with_friction:
            cylinder_terms(ths, oms, sc, cyl_node, phase, model.friction, traces, slot_cycle, tstep, w, kernels)
            tf = 0.0
            for k in range(z):
                tf += friction_torque(k, coef, extra, w[7], extra_ripple(k, extra, w[0]))
        g = o_grid[ist[I_N_GRID]]
        g[0] = t + s * h
        g[1] = tf
        g[2] = oms[fly]
        ist[I_N_GRID] += 1
        ist[I_NEXT_GRID] += 1


@numba.njit(**BORROWING)
def _chain_rk4(t, h, th, om, acc, model, fq, th1, om1, wk, gp):
    """One RK4 step of the shaft line from (th, om) at t, whose acceleration there is ``acc``, under the cylinders'
    node quantities fq (3, N_FQ, n) at t, t + h/2 and t + h: (th1, om1) at t + h. wk (5, n) work, gp (4,) scratch."""
    n = th.shape[0]
    ths, oms, a2, a3, a4 = wk[0], wk[1], wk[2], wk[3], wk[4]
    for i in range(n):
        ths[i] = th[i] + 0.5 * h * om[i]
        oms[i] = om[i] + 0.5 * h * acc[i]
    chain_accel(t + 0.5 * h, ths, oms, model, fq[1], a2, gp)
    for i in range(n):
        th1[i] = oms[i]  # k2 for theta
        ths[i] = th[i] + 0.5 * h * oms[i]
        oms[i] = om[i] + 0.5 * h * a2[i]
    chain_accel(t + 0.5 * h, ths, oms, model, fq[1], a3, gp)
    for i in range(n):
        om1[i] = oms[i]  # k3 for theta
        ths[i] = th[i] + h * oms[i]
        oms[i] = om[i] + h * a3[i]
    chain_accel(t + h, ths, oms, model, fq[2], a4, gp)
    for i in range(n):
        dth = om[i] + 2.0 * th1[i] + 2.0 * om1[i] + oms[i]
        dom = acc[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i]
        th1[i] = th[i] + h / 6.0 * dth
        om1[i] = om[i] + h / 6.0 * dom


@numba.njit(cache=True)
def advance(model, firing, edges, state, ist, outs, theta_stop, t_stop):
    """Integrate the plant ``model`` (PlantArrays) with the cycles' pressure made from ``firing`` (Firing) until the
    flywheel angle reaches ``theta_stop`` [rad], t reaches ``t_stop`` [s] or a buffer fills.

    edges = (wheel edge angles [rad], their tooth index, the second wheel's edge angles [rad] and tooth index, both
    empty without one); state = (th, om, acc, cumulative integrals, powers, pmax, [t, last cycle time], the
    cylinders' node quantities (2, N_FQ, n) at the last two steps, the powers (nq,) at the step before), updated in
    place. Writes events into ``outs`` = (cycles, grid, edge, cam, samples, load, second-wheel edge) at the counters
    in ``ist``. The second wheel turns with node ``sc[S_NODE2]``. Returns the status: 0 angle reached, 1 time
    reached, 2 a buffer is full, 3 a pressure lookup failed (bug), 4 state not finite.
    """
    inertia = model.nodes[0]
    phase = model.cylinders[1]
    sc = model.scalars
    th, om, acc, cum, pw, pmax, tarr, fq_hist, pw_prev = state
    n = inertia.shape[0]
    z = phase.shape[0]
    nq = cum.shape[0]
    g = nq - NQ_GLOBAL
    h = sc[S_H]
    fly = int(sc[S_FLY])
    two_wheels = edges[2].shape[0] > 0
    q = np.zeros(8)
    w = (np.zeros(z), np.zeros(z), np.zeros(z), np.zeros((N_FIELDS, z, 1)), np.zeros(z), np.zeros(z), np.zeros(z),
         np.zeros((model.cylinders[2].shape[1], z, 1)))
    fq = np.zeros((3, N_FQ, n))  # the cylinders' node quantities at t, t + h/2, t + h of the step being made
    fq_prev, fq_now = fq_hist[0], fq_hist[1]
    th1, om1, a1, wk = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros((5, n))
    pw1, gp, quad, scratch = np.zeros(nq), np.zeros(NQ_GLOBAL), np.zeros((3, nq)), np.zeros((2, n))
    ensure_traces(th, model, firing, q)
    if ist[I_STATUS] == 0:  # first call: the cylinders and the derivative at the initial state, no history yet
        cylinder_forcing(th, om, model, w, fq_now, pw)
        chain_accel(tarr[0], th, om, model, fq_now, acc, gp)
        for m in range(NQ_GLOBAL):
            pw[g + m] = gp[m]
        fq_prev[:] = fq_now
        pw_prev[:] = pw
        ist[I_STATUS] = 1
    while True:
        t = tarr[0]
        if th[fly] >= theta_stop:
            return 0
        if t >= t_stop:
            return 1
        if full_buffer(ist, outs, two_wheels):
            return 2
        # ---- predictor: the cylinders' quantities on the line through t - h and t ----
        for r in range(N_FQ):
            for i in range(n):
                fq[0, r, i] = fq_now[r, i]
                fq[1, r, i] = 1.5 * fq_now[r, i] - 0.5 * fq_prev[r, i]
                fq[2, r, i] = 2.0 * fq_now[r, i] - fq_prev[r, i]
        _chain_rk4(t, h, th, om, acc, model, fq, th1, om1, wk, gp)
        # ---- the cylinders once, at the predicted state at t + h ----
        ensure_traces(th1, model, firing, q)
        cylinder_forcing(th1, om1, model, w, fq[2], pw1)
        # ---- corrector: their quantities on the parabola through t - h, t, t + h ----
        for r in range(N_FQ):
            for i in range(n):
                fq[1, r, i] = 0.375 * fq[2, r, i] + 0.75 * fq_now[r, i] - 0.125 * fq_prev[r, i]
        _chain_rk4(t, h, th, om, acc, model, fq, th1, om1, wk, gp)
        chain_accel(t + h, th1, om1, model, fq[2], a1, gp)
        for m in range(NQ_GLOBAL):
            pw1[g + m] = gp[m]
        if not np.isfinite(om1[fly]):
            return 4
        pres = w[6]
        for k in range(z):
            if not np.isfinite(pres[k]):
                return 3
        # the step's integrals on the parabola of the powers through t - h, t, t + h, as a polynomial of fraction s
        for m in range(nq):
            quad[0, m] = h * pw[m]
            quad[1, m] = 0.25 * h * (pw1[m] - pw_prev[m])
            quad[2, m] = h / 6.0 * (pw1[m] - 2.0 * pw[m] + pw_prev[m])
        end = (th1, om1, a1, pres)
        step_events(model, firing.op, edges, outs, ist, state, end, quad)
        grid_points(model, ist, state, end, outs[1], w, scratch)
        # ---- accept the step ----
        for m in range(nq):
            cum[m] = quad[0, m]
            pw_prev[m] = pw[m]
            pw[m] = pw1[m]
        for r in range(N_FQ):
            for i in range(n):
                fq_prev[r, i] = fq_now[r, i]
                fq_now[r, i] = fq[2, r, i]
        for i in range(n):
            th[i] = th1[i]
            om[i] = om1[i]
            acc[i] = a1[i]
        tarr[0] = t + h
