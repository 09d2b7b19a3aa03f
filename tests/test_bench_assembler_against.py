"""The cycles check of bench/bench_assembler_against.py (base and this checkout's assembler on the same streams):
``differences`` must find any change of a Cycle's field, bit for bit (arrays by dtype, shape, contiguity and value;
NaN equal to NaN, nothing else), and the '-faulty' streams must hold the faults they are there for. Tried on cycles
the pipeline's assembler makes from a short simulated stream, so a check that can no longer fail shows."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.core.types import LoadSample, PressureFrame, ToothBatch
from frictionwatch.service.pipeline import assembled_cycles

from bench.bench_assembler_against import differences, faulty


@pytest.fixture(scope="module")
def stream():
    spec = load_engine("k9k-4cyl")
    sim = simulate(spec, 3000.0, 1.0, 6, seed=4)
    cycles, skipped = assembled_cycles(spec, sim.info, sim.records)
    assert len(cycles) >= 4 and not skipped
    return spec, sim, cycles


def test_the_same_cycles_show_no_difference(stream):
    _, _, cycles = stream
    copies = [dataclasses.replace(c, pressure=c.pressure.copy()) for c in cycles]
    assert differences(cycles, copies, "k9k") == []
    nan = dataclasses.replace(cycles[0], load_torque=float("nan"))
    assert differences([nan], [dataclasses.replace(nan)], "k9k") == []  # NaN where NaN is the same


@pytest.mark.parametrize("change", ["one ulp of pressure", "tooth_ticks as int32", "a Fortran-ordered pressure",
                                    "a flag", "the load power", "one cycle fewer"])
def test_any_change_of_a_cycle_is_found_where_it_is(stream, change):
    _, _, cycles = stream
    c = cycles[2]
    if change == "one ulp of pressure":
        p = c.pressure.copy()
        p[1, 100] = np.nextafter(p[1, 100], np.inf)
        other = [*cycles[:2], dataclasses.replace(c, pressure=p), *cycles[3:]]
    elif change == "tooth_ticks as int32":
        other = [*cycles[:2], dataclasses.replace(c, tooth_ticks=c.tooth_ticks.astype(np.int32)), *cycles[3:]]
    elif change == "a Fortran-ordered pressure":
        other = [*cycles[:2], dataclasses.replace(c, pressure=np.asfortranarray(c.pressure)), *cycles[3:]]
    elif change == "a flag":
        other = [*cycles[:2], dataclasses.replace(c, flags=(*c.flags, "no_cam_edge")), *cycles[3:]]
    elif change == "the load power":
        other = [*cycles[:2], dataclasses.replace(c, load_power=c.load_power * (1 + 1e-15) + 1e-9), *cycles[3:]]
    else:
        other = cycles[:-1]
    diffs = differences(cycles, other, "k9k")
    assert len(diffs) == 1
    assert diffs[0].startswith("k9k: ") if change == "one cycle fewer" else diffs[0].startswith("k9k[2].")


def test_the_faulty_stream_loses_repeats_and_reverses_records(stream):
    spec, sim, cycles = stream
    records = list(sim.records)
    bad = faulty(records)
    assert {type(r) for r in bad} == {type(r) for r in records}
    assert any(isinstance(r, ToothBatch) and np.any(np.diff(r.ticks) < 0) for r in bad)
    for kind in (LoadSample, PressureFrame):  # sent twice: the same record object next to itself
        assert any(a is b and isinstance(a, kind) for a, b in zip(bad, bad[1:]))
    lost, skipped = assembled_cycles(spec, sim.info, bad)
    assert sum(skipped.values()) > 0 or len(lost) < len(cycles)  # the faults cost cycles: skips are compared too
