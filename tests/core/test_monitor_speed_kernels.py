"""Kernels added for the monitor's speed (issue 26 item 7) against their numpy references: the TDC watch's per-cycle
step (``add_traces``: the take of both cycles' traces, the finiteness test and the block sum in one pass). A sum of
the same two numbers in the same order: equal to the last bit (rtol 0), and a NaN or inf sample anywhere in a taken
trace leaves the pair out in both."""

from __future__ import annotations

import types

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.calibration.tdc_watch import add_traces, add_traces_reference, trace_cut


@pytest.mark.parametrize("name", ["k9k-4cyl", "genset-v20"])
def test_add_traces_matches_its_reference(name):
    spec = load_engine(name)
    rng = np.random.default_rng(11)
    for n in (720, 1440):
        grid = np.linspace(0.0, 4 * np.pi, n, endpoint=False)
        cut = trace_cut(n, spec.firing_angles)
        prev = types.SimpleNamespace(pressure=rng.uniform(1e5, 1e7, (spec.n_cyl, n)))
        cur = types.SimpleNamespace(pressure=rng.uniform(1e5, 1e7, (spec.n_cyl, n)))
        block = rng.uniform(0.0, 1e9, (spec.n_cyl, cut.angle.shape[0]))
        got, ref = add_traces(block, prev, cur, cut), add_traces_reference(block, prev, cur, cut)
        np.testing.assert_allclose(got, ref, rtol=0.0, atol=0.0)
        assert got is not block and got.shape == block.shape and grid.shape == (n,)
        # a Fortran-ordered or float32 pressure is read as the reference reads it
        prev32 = types.SimpleNamespace(pressure=np.asfortranarray(prev.pressure.astype(np.float32)))
        np.testing.assert_allclose(add_traces(block, prev32, cur, cut), add_traces_reference(block, prev32, cur, cut),
                                   rtol=0.0, atol=0.0)
        # a non-finite sample inside a taken trace (from either cycle) leaves the pair out; outside it, it does not
        taken_prev = np.unravel_index(cut.from_prev[len(cut.from_prev) // 2], prev.pressure.shape)
        taken_cur = np.unravel_index(cut.from_cur[-1], cur.pressure.shape)
        for which, where, bad in ((prev, taken_prev, np.nan), (cur, taken_cur, np.inf)):
            p = which.pressure.copy()
            p[where] = bad
            other = types.SimpleNamespace(pressure=p)
            args = (other, cur) if which is prev else (prev, other)
            assert add_traces(block, *args, cut) is None
            assert add_traces_reference(block, *args, cut) is None
        untaken = np.setdiff1d(np.arange(prev.pressure.size), cut.from_prev)
        if untaken.size:
            p = prev.pressure.copy().reshape(-1)
            p[untaken[0]] = np.nan
            other = types.SimpleNamespace(pressure=p.reshape(prev.pressure.shape))
            np.testing.assert_allclose(add_traces(block, other, cur, cut), add_traces_reference(block, other, cur, cut),
                                       rtol=0.0, atol=0.0)


def _same_estimate(got, ref):
    """Every field of two FrictionEstimates equal: floats to the last bit (NaN where NaN), the rest exactly."""
    import dataclasses

    for f in dataclasses.fields(ref):
        a, b = getattr(got, f.name), getattr(ref, f.name)
        if isinstance(b, np.ndarray) and b.dtype.kind == "f" or isinstance(b, float):
            np.testing.assert_allclose(a, b, rtol=0.0, atol=0.0, equal_nan=True, err_msg=f.name)
        elif isinstance(b, np.ndarray):
            np.testing.assert_array_equal(a, b, err_msg=f.name)
        else:
            assert a == b, f.name


def test_reported_estimate_matches_estimate_floor_and_calibration(monkeypatch):
    """``reported_estimate`` (one kernel for the floor and the calibration) against its reference, friction_estimate ->
    ModelErrorFloor.apply -> with_calibration, on every estimate of 8 monitored k9k cycles (2000 rpm, load 0.8, seed
    3), with the monitor's floor (which adds nothing on a healthy log), a floor that adds (indicated_rel 0.05, a misfit
    beyond misfit_free with a coupling loss: cylinders become unresolved), no floor, and a commissioned calibration:
    every field equal to the last bit."""
    import frictionwatch.core.monitor.identify.identification as ident
    import frictionwatch.core.monitor.identify.step as step
    from frictionwatch.core.model.calibration import Calibration
    from frictionwatch.core.monitor.identify.estimate import (
        ModelErrorFloor,
        friction_estimate,
        reported_estimate,
        with_calibration,
    )
    from frictionwatch.core.monitor.pipeline import CyclePipeline
    from frictionwatch.core.plant.simulate import simulate
    from frictionwatch.service.pipeline import assembled_cycles

    spec = load_engine("k9k-4cyl")
    sim = simulate(spec, 2000.0, 0.8, 10, seed=3)
    cycles, _ = assembled_cycles(spec, sim.info, sim.records)
    calls = []

    def recording(*args):
        calls.append(args)
        return reported_estimate(*args)

    # the monitor's step by its reference (its kernel makes reported_estimate's numbers without calling it)
    monkeypatch.setattr(ident, "identify_step", step.identify_step_reference)
    monkeypatch.setattr(step, "reported_estimate", recording)
    pipe = CyclePipeline(spec)
    assert sum(pipe.process(c).ok for c in cycles[:8]) >= 6
    assert len(calls) >= 12
    done = Calibration(status="commissioned", tdc_wheel_sigma_deg=0.15, tdc_cylinder_sigma_deg=0.04)
    floors = (None, ModelErrorFloor(), ModelErrorFloor(indicated_rel=0.05))
    sigmas = {}
    for i, args in enumerate(calls):
        spec_, layout, post, basis, prior, limits, rows, _, check, cal, sens = args
        for f, floor in enumerate(floors):
            for j, chk in enumerate((check, check._replace(misfit=check.misfit + 3.0,
                                                            coupling_loss=check.coupling_loss + 4.0))):
                for c in (cal, done):
                    s = sens._replace(kinetic=2.5) if c is done else sens
                    got = reported_estimate(spec_, layout, post, basis, prior, limits, rows, floor, chk, c, s)
                    ref = with_calibration(friction_estimate(spec_, layout, post, basis, prior, limits, rows, floor,
                                                             chk), c, s, spec_)
                    _same_estimate(got, ref)
                    sigmas[i, f, j, c is done] = got.total_friction_torque_sigma
    # the floor's branches were taken: it adds to the sigma where it should, the calibration too
    assert all(sigmas[i, 2, 0, d] > sigmas[i, 0, 0, d] for i in range(len(calls)) for d in (False, True))
    assert all(sigmas[i, 1, 1, d] > sigmas[i, 1, 0, d] for i in range(len(calls)) for d in (False, True))
    assert any(sigmas[i, 0, 0, True] != sigmas[i, 0, 0, False] for i in range(len(calls)))
