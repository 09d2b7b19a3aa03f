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
