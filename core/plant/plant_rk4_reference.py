"""REFERENCE ONLY, not the product's integrator: the former one, classical RK4 over the whole plant (the cylinders
evaluated at all four stages), kept so that the product's integrator (core.plant.plant_advance) can be measured
against it at half the step (tests/core/test_plant_integrator.py, bench/bench_plant_integrator.py; design note 123).

``advance_rk4`` takes the same arguments and state as ``plant_advance.advance`` (it ignores the state's history of
the cylinders' quantities) and records the same events: plug it into core.plant.sim_run.PlantRun in place of
``advance`` (a test's monkeypatch) to simulate with it.
"""

from __future__ import annotations

import numba
import numpy as np
from frictionwatch.core.model.jit import BORROWING
from frictionwatch.core.model.terms import N_FIELDS
from frictionwatch.core.plant.plant import (
    I_STATUS,
    N_FQ,
    NQ_GLOBAL,
    S_FLY,
    S_H,
    chain_accel,
    cylinder_forcing,
    ensure_traces,
)
from frictionwatch.core.plant.plant_advance import full_buffer, grid_points, step_events


@numba.njit(**BORROWING)
def _rhs(t, th, om, model, w, fq, gp, acc, pw):
    """The plant's right-hand side (core.plant.plant.plant_rhs) on work arrays owned by the caller."""
    cylinder_forcing(th, om, model, w, fq, pw)
    chain_accel(t, th, om, model, fq, acc, gp)
    g = pw.shape[0] - NQ_GLOBAL
    for m in range(NQ_GLOBAL):
        pw[g + m] = gp[m]


@numba.njit(cache=True)
def advance_rk4(model, firing, edges, state, ist, outs, theta_stop, t_stop):
    """``plant_advance.advance`` by classical RK4 on the whole plant (four right-hand sides a step)."""
    n = model.nodes[0].shape[0]
    z = model.cylinders[1].shape[0]
    sc = model.scalars
    th, om, acc, cum, pw, tarr = state[0], state[1], state[2], state[3], state[4], state[6]
    nq = cum.shape[0]
    h = sc[S_H]
    fly = int(sc[S_FLY])
    two_wheels = edges[2].shape[0] > 0
    q = np.zeros(8)
    w = (np.zeros(z), np.zeros(z), np.zeros(z), np.zeros((N_FIELDS, z, 1)), np.zeros(z), np.zeros(z), np.zeros(z),
         np.zeros((model.cylinders[2].shape[1], z, 1)))
    fq, gp = np.zeros((N_FQ, n)), np.zeros(NQ_GLOBAL)
    th2, om2, th1, om1, a1, a2, a3, a4 = (np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n),
                                          np.zeros(n), np.zeros(n), np.zeros(n))
    pw2, pw3, pw4, pw1n = np.zeros(nq), np.zeros(nq), np.zeros(nq), np.zeros(nq)
    quad, scratch = np.zeros((3, nq)), np.zeros((2, n))
    ensure_traces(th, model, firing, q)
    if ist[I_STATUS] == 0:
        _rhs(tarr[0], th, om, model, w, fq, gp, acc, pw)
        ist[I_STATUS] = 1
    while True:
        t = tarr[0]
        if th[fly] >= theta_stop:
            return 0
        if t >= t_stop:
            return 1
        if full_buffer(ist, outs, two_wheels):
            return 2
        for i in range(n):
            th2[i] = th[i] + 0.5 * h * om[i]
            om2[i] = om[i] + 0.5 * h * acc[i]
        _rhs(t + 0.5 * h, th2, om2, model, w, fq, gp, a2, pw2)
        for i in range(n):
            th1[i] = om2[i]
            th2[i] = th[i] + 0.5 * h * om2[i]
            om2[i] = om[i] + 0.5 * h * a2[i]
        _rhs(t + 0.5 * h, th2, om2, model, w, fq, gp, a3, pw3)
        for i in range(n):
            om1[i] = om2[i]
            th2[i] = th[i] + h * om2[i]
            om2[i] = om[i] + h * a3[i]
        _rhs(t + h, th2, om2, model, w, fq, gp, a4, pw4)
        for i in range(n):
            th1[i] = th[i] + h / 6.0 * (om[i] + 2.0 * th1[i] + 2.0 * om1[i] + om2[i])
            om1[i] = om[i] + h / 6.0 * (acc[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i])
        ensure_traces(th1, model, firing, q)
        _rhs(t + h, th1, om1, model, w, fq, gp, a1, pw1n)
        if not np.isfinite(om1[fly]):
            return 4
        pres = w[6]
        for k in range(z):
            if not np.isfinite(pres[k]):
                return 3
        for m in range(nq):  # RK4's weights: the integrals linear in the step's fraction
            quad[0, m] = h / 6.0 * (pw[m] + 2.0 * pw2[m] + 2.0 * pw3[m] + pw4[m])
            quad[1, m] = 0.0
            quad[2, m] = 0.0
        end = (th1, om1, a1, pres)
        step_events(model, firing.op, edges, outs, ist, state, end, quad)
        grid_points(model, ist, state, end, outs[1], w, scratch)
        for m in range(nq):
            cum[m] = quad[0, m]
            pw[m] = pw1n[m]
        for i in range(n):
            th[i] = th1[i]
            om[i] = om1[i]
            acc[i] = a1[i]
        tarr[0] = t + h
