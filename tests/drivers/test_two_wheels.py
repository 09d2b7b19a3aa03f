"""The second wheel cut into the flywheel's cycles (drivers/assembly/two_wheels.py, wheel2_cut.py).

On a simulated k9k with a 36-1 wheel at its pulley hub (its gap at 100 deg, the flywheel's 60-2 at -84 deg): every
cycle carries the second wheel's edges, bracketing [0, 4 pi] in its own nominal angle, with the simulator's tooth
indices, within a degree of the flywheel's angle at the same instants (the shaft's twist and the two wheels' tooth
errors). Then what the wheel does on data never seen: a dropped tooth, a wheel gone mid-run, a wrong stated angle,
a log whose acquisition states no second wheel: each a counted, typed outcome, never a crash.
"""

from dataclasses import replace

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.core.types import FreeEndToothBatch, WheelInfo
from frictionwatch.drivers.assembly import CycleAssembler, TwoWheelAssembler
from frictionwatch.drivers.source import StreamRestart
from frictionwatch.service.pipeline import assembled_cycles, cycle_assembler
from frictionwatch.service.record_merge import record_key
from numpy.testing import assert_allclose, assert_array_equal

from tests.core.test_second_wheel_sim import k9k_with_wheel

CYCLES = 8


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    spec = load_engine(k9k_with_wheel(tmp_path_factory.mktemp("eng")))
    return spec, simulate(spec, 2000, 0.8, CYCLES, 5, second_wheel=True)


def assemble(spec, info, records):
    asm = cycle_assembler(spec, info)
    cycles = [c for r in records for c in asm.feed(r)] + asm.flush()
    return asm, cycles


def test_every_cycle_carries_its_second_wheel(run):
    spec, sim = run
    asm, cycles = assemble(spec, sim.info, sim.records)
    assert isinstance(asm, TwoWheelAssembler)
    assert len(cycles) >= CYCLES - 1 and not asm.wheel2_missing
    ticks_all = np.concatenate([r.ticks for r in sim.records if isinstance(r, FreeEndToothBatch)])
    index_all = sim.diagnostics["edge2_index"]
    for c in cycles:
        w = c.wheel2
        assert w is not None and "no_second_wheel" not in c.flags
        assert w.angle[0] <= 0.0 < w.angle[1] and w.angle[-2] < 4 * np.pi <= w.angle[-1]
        assert np.all(np.diff(w.ticks) > 0)
        pitches = np.diff(w.angle) / (2 * np.pi / 36)
        assert_allclose(pitches, np.round(pitches), atol=1e-9)  # whole pitches of its own wheel
        assert set(np.round(pitches).astype(int)) <= {1, 2}  # one, or two across its gap
        assert_array_equal(w.index, index_all[np.searchsorted(ticks_all, w.ticks)])  # the simulator's teeth
        theta_f = np.interp(w.ticks, c.tooth_ticks, c.tooth_angle)  # the flywheel's nominal angle then
        inside = (w.ticks > c.tooth_ticks[0]) & (w.ticks < c.tooth_ticks[-1])
        assert np.max(np.abs(theta_f[inside] - w.angle[inside])) < np.radians(1.0)
    one = [c for c in assembled_cycles(spec, replace(sim.info, second_wheel=None), sim.records)[0]]
    assert [c.index for c in one] == [c.index for c in cycles]  # the flywheel's cycles unchanged
    assert all(c.wheel2 is None for c in one)
    for a, b in zip(one, cycles):
        assert_array_equal(a.tooth_ticks, b.tooth_ticks)
        assert_allclose(a.pressure, b.pressure, rtol=0, atol=0)


def test_a_dropped_tooth_costs_only_the_cycles_it_touches(run):
    spec, sim = run
    records, dropped = [], False
    for r in sim.records:
        if isinstance(r, FreeEndToothBatch) and not dropped and r.ticks[0] > 0.12 * spec.sensors.tick_hz:
            r = FreeEndToothBatch(np.delete(r.ticks, 10))
            dropped = True
        records.append(r)
    asm, cycles = assemble(spec, sim.info, records)
    lost = [c for c in cycles if c.wheel2 is None]
    assert 1 <= len(lost) <= 2 and asm.wheel2_missing["second_wheel_sync"] == len(lost)
    assert all("no_second_wheel" in c.flags for c in lost)
    assert sum(c.wheel2 is not None for c in cycles) >= len(cycles) - 2


def test_a_wheel_gone_mid_run_leaves_the_flywheel_cycles_flagged(run):
    spec, sim = run
    t_stop = 0.25 * spec.sensors.tick_hz
    records = [r for r in sim.records if not (isinstance(r, FreeEndToothBatch) and r.ticks[-1] > t_stop)]
    asm, cycles = assemble(spec, sim.info, records)
    _, full = assemble(spec, sim.info, sim.records)
    assert [c.index for c in cycles] == [c.index for c in full]
    gone = [c for c in cycles if c.wheel2 is None]
    assert gone and all(c.tooth_ticks[-1] > t_stop - 0.07 * spec.sensors.tick_hz for c in gone)
    assert sum(asm.wheel2_missing.values()) == len(gone)
    assert asm.wheel2_missing["second_wheel_absent"] >= 1


def test_a_wrong_stated_angle_is_refused_not_believed(run):
    spec, sim = run
    info = replace(sim.info, second_wheel=WheelInfo(36, 1, 100.0 + 90.0))
    asm, cycles = assemble(spec, info, sim.records)
    assert all(c.wheel2 is None for c in cycles) and asm.wheel2_missing["second_wheel_angle"] == len(cycles)


def test_without_a_stated_second_wheel_its_records_are_ignored(run):
    spec, sim = run
    info = replace(sim.info, second_wheel=None)
    asm = cycle_assembler(spec, info)
    assert type(asm) is CycleAssembler
    cycles = [c for r in sim.records for c in asm.feed(r)] + asm.flush()
    assert cycles and all(c.wheel2 is None and "no_second_wheel" not in c.flags for c in cycles)
    assert asm.stats["second_wheel_ignored"] > 0
    with pytest.raises(ValueError, match="without a missing-tooth gap"):
        TwoWheelAssembler(replace(sim.info, second_wheel=WheelInfo(36, 0, 0.0)), spec.n_cyl, spec.firing_angles)


def test_a_hole_in_the_second_wheels_source_restarts_its_cut_only(run):
    """A live session that dropped a stretch of a source giving the second wheel's edges alone (its own channel)
    marks it ``assembly="second_wheel"`` (service/live.py): the flywheel's cycles go on, numbered as without the
    hole; those whose free-end edges went are flagged, and the fresh cut syncs again after it (design note 124)."""
    spec, sim = run
    hz = spec.sensors.tick_hz
    t1, t2 = 0.2 * hz, 0.33 * hz  # ~2 cycles at 2000 rpm
    gone = [r for r in sim.records if isinstance(r, FreeEndToothBatch) and t1 <= r.ticks[-1] <= t2]
    mark = StreamRestart(int(max(r.ticks[-1] for r in gone)) + 1, "dropped_while_behind",
                         dropped_from_ticks=int(t1), dropped_records=len(gone), assembly="second_wheel")
    records = [r for r in sim.records if not any(r is g for g in gone)]
    at = next(i for i, r in enumerate(records) if record_key(r) > mark.ticks)
    records.insert(at, mark)
    cycles, skipped = assembled_cycles(spec, sim.info, records)
    full, _ = assembled_cycles(spec, sim.info, sim.records)
    assert [c.index for c in cycles] == [c.index for c in full] and not skipped
    lost = [c for c in cycles if c.wheel2 is None]
    assert lost and all("no_second_wheel" in c.flags for c in lost)
    assert all(c.tooth_ticks[-1] > t1 and c.tooth_ticks[0] < t2 + 0.07 * hz for c in lost)  # the hole's, at most
    assert cycles[-1].wheel2 is not None  # synced again after it
    # the same stretch marked as the flywheel's (a restart of the whole assembly) costs flywheel cycles too
    whole = [replace(r, assembly="all") if r is mark else r for r in records]
    assert len(assembled_cycles(spec, sim.info, whole)[0]) < len(cycles)
