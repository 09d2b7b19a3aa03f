"""identify_step_kernel (one call a cycle: accumulation, shares, both posteriors, both estimates, the pull check)
against its reference identify_step_reference (the files' wrappers one after another) on real cycles: k9k-4cyl
with a worn ring and genset-v20 (design note 115)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.identify import identification, step
from frictionwatch.core.monitor.identify.estimate import ModelErrorFloor
from frictionwatch.core.monitor.identify.posterior import posterior_from_normal
from frictionwatch.core.monitor.pipeline import CyclePipeline
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles

RTOL = 1e-9  # the same calls on the same arrays: seen equal to the last bits but ddot's (mean_row @ params)

CASES = {"k9k-4cyl": (3000.0, 0.8, {"ring_wear": {"cylinder": 2, "gain": 1.3}}), "genset-v20": (1500.0, 0.7, None)}


def _steps(name: str, n: int = 40) -> list[tuple]:
    """Every identify_step call's arguments and answer over ``n`` cycles of the engine's case."""
    rpm, load, effects = CASES[name]
    spec = load_engine(name)
    sim = simulate(spec, rpm, load, n, seed=3, effects=effects)
    cycles, _ = assembled_cycles(spec, sim.info, sim.records)
    seen, fallbacks, bounded = [], [], []
    reference, posterior = step.identify_step_reference, step.posterior_from_normal

    def recording(*args):
        out = step.identify_step(*args)
        seen.append((args, out))
        return out

    def counted(*args):
        fallbacks.append(len(seen))
        return reference(*args)

    def decided(*args):  # a posterior the kernel left to NNLS or LAPACK's general path
        bounded.append(len(seen))
        return posterior(*args)

    mp = pytest.MonkeyPatch()
    mp.setattr(identification, "identify_step", recording)
    mp.setattr(step, "identify_step_reference", counted)
    mp.setattr(step, "posterior_from_normal", decided)
    try:
        pipe = CyclePipeline(spec)
        for c in cycles:
            pipe.process(c)
    finally:
        mp.undo()
    assert not fallbacks, f"the kernel left cycles {fallbacks} to the reference"  # else nothing would be compared
    return seen, bounded


def _compare(got, want, where: str) -> int:
    """Every number of two answers (named tuples, dataclasses, arrays, floats) within RTOL; the count compared."""
    if dataclasses.is_dataclass(want) or hasattr(want, "_fields"):
        names = [f.name for f in dataclasses.fields(want)] if dataclasses.is_dataclass(want) else want._fields
        return sum(_compare(getattr(got, k), getattr(want, k), f"{where}.{k}") for k in names)
    if want is None or isinstance(want, str):
        assert got == want, where
        return 0
    w, g = np.asarray(want), np.asarray(got)
    assert g.shape == w.shape and g.dtype.kind == w.dtype.kind, where
    if w.dtype.kind == "b":
        np.testing.assert_array_equal(g, w, err_msg=where)
    else:
        np.testing.assert_allclose(g, w, rtol=RTOL, atol=0.0, equal_nan=True, err_msg=where)
    return w.size


@pytest.mark.parametrize("name", sorted(CASES))
def test_kernel_against_reference_on_real_cycles(name):
    seen, bounded = _steps(name)
    assert len(seen) >= 35
    # the kernel's whole answer on most cycles; whether a posterior's free friction scale goes below zero (a bound
    # active) is the noise's draw: k9k seed 3 on the former integrator 8 of 40 cycles, on today's none (nor seeds 1,
    # 2, 4, 5 on either), genset-v20 none on the former, cycle 26 on today's (design note 123); so the bounded path
    # is run below on purpose
    assert len(bounded) < len(seen) // 2, bounded
    numbers = 0
    for i, (args, got) in enumerate(seen):
        numbers += _compare(got, step.identify_step_reference(*args), f"{name} cycle {i}")
    assert numbers > 35 * 100
    # the warm-up's unfolded cycles were compared too
    assert not seen[0][0][-1].fold and seen[-1][0][-1].fold
    # a bound active in both posteriors of every cycle, whatever the draw: the last 8 steps again with every friction
    # scale held at or above 1.3 (the truth's are 1, the worn ring's 1.3 in k9k's cylinder 2; the tooth nuisances stay
    # free): the kernel's partial answer, NNLS, then report_kernel, against the reference
    decided, writable = [], []
    kernel = step.identify_step_kernel

    def kernel_seen(rows, acc, model, *rest):
        writable.append(model.lower.flags.writeable)
        return kernel(rows, acc, model, *rest)

    for i, (args, _) in enumerate(seen[-8:]):
        lower = np.where(np.isfinite(args[3]), 1.3, args[3])
        held = (*args[:3], lower, *args[4:])
        with pytest.MonkeyPatch.context() as mp:  # the kernel's calls counted, not the reference's own
            mp.setattr(step, "posterior_from_normal", lambda *a: decided.append(1) or posterior_from_normal(*a))
            mp.setattr(step, "identify_step_kernel", kernel_seen)
            got = step.identify_step(*held)
        _compare(got, step.identify_step_reference(*held), f"{name} held cycle {i}")
    assert len(decided) == 2 * 8, len(decided)
    # the held bound is writable (np.where's), the state's read-only: the kernel gets it read-only either way, so one
    # specialisation, not a second for the same numbers (design note 130). Asked of the call, not of the kernel's
    # signatures: `make test`'s kernel manifest may have compiled the writable one up front in this process
    assert writable == [False] * 8, writable


def test_kernel_against_reference_floor_and_calibration_branches():
    """The floor's branches the monitor's defaults do not take on a healthy log (an indicated_rel, a misfit beyond
    misfit_free with a coupling loss; no floor) and a commissioned calibration with a kinetic term and the load read
    as a torque or as electrical power, on 8 genset-v20 cycles' steps: the kernel within RTOL of its reference, and the branches move the sigmas."""
    seen = _steps("genset-v20", 14)[0][-8:]
    done = Calibration(status="commissioned", tdc_wheel_sigma_deg=0.15, tdc_cylinder_sigma_deg=0.04)
    for i, (args, _) in enumerate(seen):
        *head, inp, cfg = args
        sig = {}
        for f, floor in enumerate((None, ModelErrorFloor(indicated_rel=0.05), cfg.floor)):
            for cal in (cfg.calibration, done):
                settings = cfg._replace(floor=floor, calibration=cal)
                moved = inp._replace(misfit=inp.misfit + 3.0, coupling_loss=inp.coupling_loss + 4.0, kinetic=2.5,
                                     load_from_power=bool(i % 2))  # the load read as power on every other cycle
                got = step.identify_step(*head, moved, settings)
                _compare(got, step.identify_step_reference(*head, moved, settings), f"cycle {i} floor {f} {cal.status}")
                sig[f, cal.status] = got.cycle_estimate.total_friction_torque_sigma
        assert sig[1, "uncalibrated"] > sig[0, "uncalibrated"] and sig[2, "uncalibrated"] > sig[0, "uncalibrated"]
        assert sig[0, "commissioned"] != sig[0, "uncalibrated"]
