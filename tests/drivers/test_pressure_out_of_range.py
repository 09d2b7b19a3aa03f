"""A pressure sample no cylinder sensor can read (beyond +-1000 bar, or infinite) is an invalid sample like a NaN
(design note 142): its cycle is skipped as 'pressure_nan' and counted, and its neighbours come out as in a clean
run. Before, one glitched block of 1e30 Pa from a foreign log gave that cycle an IMEP of 1e22 bar, the run's mean
IMEP 7e37 bar, and overflowed the monitor's state for the next eight cycles."""

import numpy as np
import pytest
from frictionwatch.core.types import LoadSample, PressureBlock, PressureFrame
from frictionwatch.drivers.assembly.cycles import CycleAssembler
from frictionwatch.drivers.assembly.engine_buffers import LOAD_LIMIT_NM, LOAD_LIMIT_W, PRESSURE_LIMIT_PA, EngineBuffers

from tests.drivers.synth_stream import Motion, Stream


def run(records, stream):
    asm = CycleAssembler(stream.info(), len(stream.firing_deg), np.radians(stream.firing_deg),
                         speed_range_rpm=(500.0, 5000.0))
    out = []
    for r in records:
        out += asm.feed(r)
    return out + asm.flush(), asm


@pytest.fixture(scope="module")
def clean():
    s = Stream()
    recs = s.records(Motion(1500), 1.0)
    out, _ = run(recs, s)
    return s, recs, out


@pytest.mark.parametrize("glitch", [1e30, np.inf, -np.inf, -2e8, 1.5 * PRESSURE_LIMIT_PA])
def test_one_impossible_sample_skips_its_cycle_only(clean, glitch):
    s, recs, good = clean
    tmid = int(good[5].tooth_ticks[60])

    def hit(r):
        return (isinstance(r, PressureBlock) and r.cylinder == 3
                and r.t0_ticks <= tmid <= r.t0_ticks + r.period_ticks * r.values.size)
    bad = [PressureBlock(3, r.t0_ticks, r.period_ticks, np.where(np.arange(r.values.size) == 5, glitch, r.values))
           if hit(r) else r for r in recs]
    out, asm = run(bad, s)
    assert dict(asm.skipped) == {"pressure_nan": 1}
    assert asm.buf.rejected["pressure_out_of_range"] == 1
    assert [c.index for c in out] == [i for i in range(11) if i != 5]
    for c in out:
        np.testing.assert_array_equal(c.pressure, good[c.index].pressure)


def test_a_frame_keeps_its_own_values_and_the_ring_gets_nan():
    buf = EngineBuffers()
    values = np.array([[1e5, 2e5, 1e30, 3e5], [1e5, -np.inf, 2e5, 2e5]])
    frame = PressureFrame((1, 2), 0, 100.0, values)
    assert buf.add_frame(frame) == 8
    assert buf.rejected["pressure_out_of_range"] == 2
    assert np.array_equal(values[0], [1e5, 2e5, 1e30, 3e5])  # the record is not changed (it may be kept elsewhere)
    stored = np.stack([buf.pressure[c].view("p") for c in (1, 2)])
    np.testing.assert_array_equal(stored, [[1e5, 2e5, np.nan, 3e5], [1e5, np.nan, 2e5, 2e5]])


def test_values_within_the_limit_are_kept_exactly():
    buf = EngineBuffers()
    v = np.array([-PRESSURE_LIMIT_PA, -1e6, 0.0, 2.5e7, PRESSURE_LIMIT_PA, np.nan])  # NaN: already invalid
    buf.add_pressure(PressureBlock(1, 0, 100.0, v))
    np.testing.assert_array_equal(buf.pressure[1].view("p"), v)
    assert buf.rejected["pressure_out_of_range"] == 0


def test_a_one_cylinder_frame_shares_the_ring_and_the_check():
    buf = EngineBuffers()
    values = np.array([[1e5, np.inf, 2e5]])
    assert buf.add_frame(PressureFrame((3,), 0, 100.0, values)) == 3
    np.testing.assert_array_equal(buf.pressure[3].view("p"), [1e5, np.nan, 2e5])
    assert buf.rejected["pressure_out_of_range"] == 1 and values[0, 1] == np.inf


def test_a_load_reading_no_brake_can_give_is_not_measured(clean):
    """A torque of 1e300 N m (a foreign log's glitch) came out as the run's mean load torque; filed as NaN it is
    'not measured' like any missing reading. Readings within LOAD_LIMIT_NM / LOAD_LIMIT_W are kept exactly."""
    s, recs, good = clean
    assert any(isinstance(r, LoadSample) for r in recs)
    bad = [LoadSample(r.ticks, 1e300, -np.inf) if isinstance(r, LoadSample) else r for r in recs]
    out, asm = run(bad, s)
    assert [c.index for c in out] == [c.index for c in good]
    assert all(np.isnan(c.load_torque) and np.isnan(c.load_power) for c in out)
    assert asm.buf.rejected["load_out_of_range"] == 2 * sum(isinstance(r, LoadSample) for r in recs)
    buf = EngineBuffers()
    buf.add_load(LoadSample(1, -LOAD_LIMIT_NM, LOAD_LIMIT_W))
    assert buf.load.last("torque") == -LOAD_LIMIT_NM and buf.load.last("power") == LOAD_LIMIT_W
