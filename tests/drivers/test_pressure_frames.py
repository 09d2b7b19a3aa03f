"""PressureFrame (all cylinders on one clock) through the rings and the cycle assembler.

The bar: a cycle is the same ``Cycle`` (integers exactly, floats within a stated tolerance) whether its pressure
came as frames or as the equivalent ``PressureBlock`` s (one per cylinder), including skips (NaN, holes), refused
overlaps and ring overflow. The group kernel is tested against the one-cylinder kernel; a cylinder arriving in both
shapes is refused, counted and logged, never mixed.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from frictionwatch.core.types import Cycle, PressureBlock, PressureFrame, ToothBatch
from frictionwatch.drivers.assembly.cycles import CycleAssembler
from frictionwatch.drivers.assembly.engine_buffers import EngineBuffers
from frictionwatch.drivers.assembly.pressure_kernels import (
    ROW_HOLE,
    ROW_MISSING,
    ROW_NAN,
    ROW_OK,
    pressure_row,
    pressure_rows,
)
from frictionwatch.drivers.assembly.pressure_ring import PressureGroup, frame_blocks, write_frame
from frictionwatch.drivers.assembly.ringbuffer import RingBuffer, write_block
from frictionwatch.drivers.bridge import can_events

from tests.drivers.synth_stream import Motion, Stream

GENSET_FIRING = (0.0, 36.0, 216.0, 252.0, 72.0, 108.0, 288.0, 324.0, 144.0, 180.0,
                 504.0, 540.0, 648.0, 684.0, 432.0, 468.0, 576.0, 612.0, 360.0, 396.0)  # genset-v20.toml


def to_frames(records):
    """Consecutive blocks with the same (t0, period, length) and distinct cylinders -> one frame, placed where the
    last of them was (the order an indicating system delivers them in)."""
    out, group = [], []

    def flush():
        if group:
            out.append(PressureFrame(tuple(b.cylinder for b in group), group[0].t0_ticks, group[0].period_ticks,
                                     np.array([b.values for b in group])))
            group.clear()

    for r in records:
        if isinstance(r, PressureBlock):
            key = (r.t0_ticks, r.period_ticks, len(r.values))
            if group and ((group[0].t0_ticks, group[0].period_ticks, len(group[0].values)) != key
                          or r.cylinder in {b.cylinder for b in group}):
                flush()
            group.append(r)
            continue
        flush()
        out.append(r)
    flush()
    return out


def to_blocks(records):
    return [b for r in records for b in (frame_blocks(r) if isinstance(r, PressureFrame) else (r,))]


def identical(a: Cycle, b: Cycle) -> bool:
    """The same cycle: integers (ticks, indices) and metadata exactly; angles, grid and pressure within rtol 1e-12
    (frames and blocks are resampled by two kernels, the same interpolation: a few ulp); load exactly (the same
    rows, the same mean)."""
    for name in ("tooth_ticks", "tooth_angle", "tooth_index", "grid", "pressure"):
        x, y = getattr(a, name), getattr(b, name)
        if x.dtype != y.dtype or x.shape != y.shape:
            return False
    return (a.index, a.tick_hz, a.phase_source, a.flags) == (b.index, b.tick_hz, b.phase_source, b.flags) \
        and np.array_equal(a.tooth_ticks, b.tooth_ticks) and np.array_equal(a.tooth_index, b.tooth_index) \
        and all(np.allclose(getattr(a, n), getattr(b, n), rtol=1e-12, atol=0, equal_nan=True)
                for n in ("tooth_angle", "grid", "pressure")) \
        and np.array_equal([a.load_torque, a.load_power], [b.load_torque, b.load_power], equal_nan=True)


def assemble(records, info, firing_deg, **kw):
    kw.setdefault("speed_range_rpm", (500.0, 5000.0))
    asm = CycleAssembler(info, len(firing_deg), np.radians(firing_deg), **kw)
    out = []
    for r in records:
        out += asm.feed(r)
    return out + asm.flush(), asm


def assert_same_assembly(blocks, frames, info, firing_deg, **kw):
    a, asm_a = assemble(blocks, info, firing_deg, **kw)
    b, asm_b = assemble(frames, info, firing_deg, **kw)
    assert len(a) == len(b) and all(identical(x, y) for x, y in zip(a, b, strict=True))
    assert asm_a.skipped == asm_b.skipped and asm_a.stats == asm_b.stats
    assert asm_a.dropped() == asm_b.dropped()
    return a, asm_a


@pytest.fixture(scope="module")
def k4():
    s = Stream()
    return s, s.records(Motion(1500), 1.0)


@pytest.fixture(scope="module")
def genset():
    s = Stream(n_teeth=160, first_tooth_deg=-30.0, firing_deg=GENSET_FIRING, pressure_cyl=tuple(range(1, 21)),
               cam_deg=700.0)
    return s, s.records(Motion(1500, orders=(10.0, 20.0, 0.5), amps=(0.0015, 0.0003, 0.0002)), 0.6)


# ---- frames vs blocks: the same cycles ------------------------------------------------------------------------------
def test_frames_and_blocks_give_identical_cycles(k4, genset):
    for s, recs in (k4, genset):
        frames = to_frames(recs)
        assert sum(isinstance(r, PressureFrame) for r in frames) > 0
        assert not any(isinstance(r, PressureBlock) for r in frames)
        out, asm = assert_same_assembly(recs, frames, s.info(), s.firing_deg)
        assert len(out) >= 5 and not asm.skipped


def test_list_frames_give_the_cycles_of_array_frames(k4):
    """A frame whose values are nested lists (filed as a copy) moves the assembler's clock as its array does: the
    same cycles, skips and counts (the assembler reads an array's length off its shape, a list's through np.shape)."""
    s, recs = k4
    frames = to_frames(recs)
    lists = [PressureFrame(r.cylinders, r.t0_ticks, r.period_ticks, r.values.tolist())
             if isinstance(r, PressureFrame) else r for r in frames]
    out, asm = assert_same_assembly(frames, lists, s.info(), s.firing_deg)
    assert len(out) >= 5 and not asm.skipped


def test_same_skips_with_nan_hole_and_repeated_data(genset):
    s, recs = genset
    frames = to_frames(recs)
    idx = [i for i, r in enumerate(frames) if isinstance(r, PressureFrame)]
    # 4 ms frames; cycles start at ~80 ms and last 80 ms
    rep = frames[idx[110]]  # a repeated, overlapping frame (half old, half new samples of a later frame)
    half = rep.values.shape[1] // 2
    frames.insert(idx[110] + 1, PressureFrame(rep.cylinders, int(rep.t0_ticks + half * rep.period_ticks),
                                             rep.period_ticks, rep.values[:, half:] + 1.0))
    nan = frames[idx[45]]
    v = nan.values.copy()
    v[7, 40] = np.nan  # one saturated sample of cylinder 8
    frames[idx[45]] = PressureFrame(nan.cylinders, nan.t0_ticks, nan.period_ticks, v)
    del frames[idx[75]]  # a lost frame (4 ms): a hole in every cylinder
    blocks = to_blocks(frames)
    out, asm = assert_same_assembly(blocks, frames, s.info(), s.firing_deg)
    assert asm.skipped["pressure_nan"] >= 1 and asm.skipped["pressure_missing"] >= 1
    assert asm.dropped()["rejected_pressure"] == 20 * (rep.values.shape[1] - half)  # counted per cylinder sample


def test_same_overflow_with_a_small_ring(k4):
    s, recs = k4
    a, asm_a = assemble(recs, s.info(), s.firing_deg, buffers=EngineBuffers(pressure_capacity=600))
    b, asm_b = assemble(to_frames(recs), s.info(), s.firing_deg, buffers=EngineBuffers(pressure_capacity=600))
    assert len(a) == len(b) and all(identical(x, y) for x, y in zip(a, b, strict=True))
    assert asm_a.skipped == asm_b.skipped and asm_a.dropped() == asm_b.dropped()
    assert asm_a.skipped  # the ring (30 ms at 20 kHz) is shorter than a cycle: every cycle misses pressure


def test_frames_from_the_plant_simulator_match_their_blocks():
    simulate = pytest.importorskip("frictionwatch.core.plant.simulate").simulate
    from frictionwatch.core.model.engine import load_engine

    spec = load_engine("k9k-4cyl")
    res = simulate(spec, 1700.0, 0.7, 4, seed=4)
    assert all(r.cylinders == (1, 2, 3, 4) for r in res.records if isinstance(r, PressureFrame))
    kw = {"speed_range_rpm": spec.speed_range_rpm}
    a, asm = assert_same_assembly(to_blocks(res.records), res.records, res.info, np.degrees(spec.firing_angles), **kw)
    assert [c.index for c in a] == list(range(4)) and not asm.skipped


def test_cylinder_order_of_a_frame_does_not_matter(k4):
    s, recs = k4
    frames = to_frames(recs)
    perm = [PressureFrame(r.cylinders[::-1], r.t0_ticks, r.period_ticks, r.values[::-1].copy())
            if isinstance(r, PressureFrame) and i % 3 else r for i, r in enumerate(frames)]
    a, _ = assemble(frames, s.info(), s.firing_deg)
    b, asm = assemble(perm, s.info(), s.firing_deg)
    assert len(a) == len(b) and all(identical(x, y) for x, y in zip(a, b, strict=True)) and not asm.skipped


# ---- blocks and frames for one cylinder: refused, counted, logged ---------------------------------------------------
def test_a_cylinder_in_blocks_and_in_frames_is_never_mixed(caplog):
    buf = EngineBuffers(pressure_capacity=64)
    assert buf.add(PressureBlock(1, 0, 10.0, np.arange(4.0))) == 4
    with caplog.at_level(logging.WARNING):
        assert buf.add(PressureFrame((1, 2), 40, 10.0, np.ones((2, 3)))) == 0  # cylinder 1 came in blocks
        assert buf.add(PressureFrame((1, 2), 70, 10.0, np.ones((2, 3)))) == 0
    assert buf.rejected["pressure_conflict"] == 12 and "blocks vs frames" in caplog.text
    assert len([m for m in caplog.messages if "refused" in m]) == 1  # logged once per shape
    assert buf.add(PressureFrame((2, 3), 40, 10.0, np.ones((2, 3)))) == 6  # other cylinders: a new group
    assert buf.add(PressureBlock(3, 70, 10.0, np.ones(2))) == 0  # cylinder 3 comes in frames now
    assert buf.add(PressureFrame((3,), 70, 10.0, np.ones((1, 2)))) == 0  # another grouping of 3
    assert buf.rejected["pressure_conflict"] == 12 + 2 + 2
    np.testing.assert_array_equal(buf.pressure[1].view("p"), np.arange(4.0))  # untouched
    np.testing.assert_array_equal(buf.pressure[3].view("t"), [40.0, 50.0, 60.0])
    # a one-cylinder frame is the same shape as a block: they share the cylinder's ring
    assert buf.add(PressureFrame((1,), 40, 10.0, np.full((1, 2), 7.0))) == 2
    np.testing.assert_array_equal(buf.pressure[1].view("p"), [0.0, 1.0, 2.0, 3.0, 7.0, 7.0])


def test_assembler_counts_conflicts_and_survives_bad_frames(k4, caplog):
    s, recs = k4
    frames = to_frames(recs)
    i = next(i for i, r in enumerate(frames) if isinstance(r, PressureFrame))
    bad = [PressureFrame((1, 1, 2, 3), 0, 500.0, np.ones((4, 3))), PressureFrame((1, 2), 0, 500.0, np.ones((3, 3))),
           PressureFrame((0, 1, 2, 3), 0, 500.0, np.ones((4, 3))), PressureFrame((1, 2, 3, 4), 0, 500.0, np.ones(4)),
           PressureFrame((1, 2, 3, 4), 0, 0.0, np.ones((4, 3))), PressureFrame((1, 2, 3, 4), 0, 500.0, np.ones((4, 0))),
           PressureFrame(([1], 2), 0, 500.0, np.ones((2, 3))), PressureFrame(("a", 2), 0, 500.0, np.ones((2, 3)))]
    with caplog.at_level(logging.WARNING):
        out, asm = assemble(frames[:i] + bad + frames[i:] + [PressureBlock(2, 10**9, 500.0, np.ones(3))],
                            s.info(), s.firing_deg)
    ref, _ = assemble(frames, s.info(), s.firing_deg)
    assert len(out) == len(ref) and all(identical(x, y) for x, y in zip(out, ref, strict=True))
    d = asm.dropped()
    assert d["rejected_pressure_bad_frame"] == 6 and d["rejected_pressure"] == 12  # the zero period
    assert d["rejected_pressure_conflict"] == 3


# ---- the group kernels against the one-cylinder kernels --------------------------------------------------------------
@pytest.mark.parametrize("seed", range(4))
def test_write_frame_matches_write_block_per_row(seed):
    rng = np.random.default_rng(seed)
    cap, k = 97, 5
    t = np.zeros(2 * cap)
    p = np.zeros((k, 2 * cap))
    t_ref = [np.zeros(2 * cap) for _ in range(k)]
    p_ref = [np.zeros(2 * cap) for _ in range(k)]
    for _ in range(20):
        n = int(rng.integers(1, 60))
        v = rng.normal(size=(k, n))
        s0 = int(rng.integers(0, n))
        i = int(rng.integers(0, cap))
        t0, period = float(rng.uniform(0, 1e6)), float(rng.uniform(0.5, 600.0))
        write_frame(t, p, i, t0, period, v, s0)
        for r in range(k):
            write_block(t_ref[r], p_ref[r], i, t0, period, np.ascontiguousarray(v[r, s0:]))
            # times t0 + k period from two kernels (exact in practice; a few ulp allowed); samples copied: equal
            np.testing.assert_allclose(t, t_ref[r], rtol=1e-15, atol=0)
            np.testing.assert_array_equal(p[r], p_ref[r])


def _group(rng, cap, k, n_blocks, hole=False, nan=False):
    g = PressureGroup(tuple(range(1, k + 1)), cap)
    t = 1000.0
    for b in range(n_blocks):
        m = int(rng.integers(5, 40))
        vals = rng.normal(5e5, 1e5, (k, m))
        if nan and b == n_blocks - 3:  # late enough to stay retained
            vals[int(rng.integers(0, k)), m // 2] = np.nan
        i, skip = g.reserve(m)
        write_frame(g.t, g.p, i, t + skip * 10.0, 10.0, vals, skip)
        t += (m - 1) * 10.0 + (80.0 if hole and b == n_blocks - 3 else 10.0)
        g.discard_before(g.end - cap // 2)  # keep the ring wrapping, as the assembler's discard does
    return g


@pytest.mark.parametrize("seed", range(6))
def test_group_rows_match_the_one_row_kernel(seed):
    rng = np.random.default_rng(seed)
    k = 6
    g = _group(rng, 257, k, 60, hole=seed % 3 == 1, nan=seed % 3 == 2)
    t_all = g.t[g.start % g.capacity: g.start % g.capacity + len(g)]
    rows = np.array([3, -1, 0, 5, 2, 1], dtype=np.int64)  # row 1 not wanted
    seen = set()
    for _ in range(200):
        lo = rng.uniform(t_all[0] - 50.0, t_all[-1])
        hi = lo + rng.uniform(1.0, 1200.0)
        grid = np.sort(rng.uniform(lo, hi, 64))
        grid[0], grid[-1] = lo, hi
        if rng.random() < 0.1:  # grid ends exactly on samples
            grid[0] = t_all[rng.integers(0, t_all.size)]
            grid[-1] = grid[0] + 100.0
            grid = np.sort(grid)
        out = np.full((6, 64), -1.0)
        codes = np.zeros(k, dtype=np.int64)
        bad = pressure_rows(g.t, g.p, g.start, g.end, grid, rows, out, codes)
        n_bad = 0
        for r in range(k):
            if rows[r] < 0:
                assert codes[r] == ROW_OK
                continue
            ref = np.empty(64)
            code = pressure_row(g.t, np.ascontiguousarray(g.p[r]), g.start, g.end, grid, ref)
            assert codes[r] == code
            seen.add(code)
            n_bad += code != ROW_OK
            if code == ROW_OK:
                # the group kernel shares the window and weights of the rows: a few ulp of ~5e5 Pa
                np.testing.assert_allclose(out[rows[r]], ref, rtol=1e-12)
        assert bad == n_bad
        assert np.all(out[4] == -1.0)  # the unwanted row's target is untouched
    assert ROW_OK in seen and ROW_MISSING in seen
    assert ROW_HOLE not in seen if seed % 3 != 1 else ROW_NAN not in seen if seed % 3 != 2 else True
    whole = np.linspace(t_all[0], t_all[-1], 64)  # every retained sample: the injected fault shows
    codes = np.zeros(k, dtype=np.int64)
    pressure_rows(g.t, g.p, g.start, g.end, whole, np.arange(k, dtype=np.int64), np.empty((k, 64)), codes)
    if seed % 3 == 1:
        assert set(codes.tolist()) == {ROW_HOLE}
    elif seed % 3 == 2:
        assert ROW_NAN in codes.tolist()


def test_channel_has_the_ringbuffer_interface():
    buf = EngineBuffers(pressure_capacity=8)
    buf.add(PressureFrame((2, 5), 100, 10.0, np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])))
    ch = buf.pressure[5]
    assert isinstance(ch, RingBuffer) and len(ch) == 3 and ch.last("t") == 120.0 and ch.get("p", 1) == 5.0
    assert ch.searchsorted("t", 110.0) == 1
    ch.discard_before(1)  # releases the row of every cylinder of the group
    assert len(buf.pressure[2]) == 2
    with pytest.raises(ValueError):
        ch.extend(np.ones(1), np.ones(1))  # rows of a group are written together
    buf.add(PressureFrame((2, 5), 130, 10.0, np.ones((2, 8))))  # 2 + 8 unreleased rows into 8: two lost
    assert buf.dropped() == {"pressure_2": 2, "pressure_5": 2}


# ---- protocols with one cylinder per message ---------------------------------------------------------------------
def test_bridge_sends_a_frame_as_its_blocks(k4):
    s, recs = k4
    short = [r for r in recs if isinstance(r, PressureBlock)][:40]
    a = can_events(short, s.info())
    b = can_events(to_frames(short), s.info())
    assert len(a) == len(b) > 0
    assert all(x.tick == y.tick and bytes(x.payload.data) == bytes(y.payload.data)
               and x.payload.arbitration_id == y.payload.arbitration_id for x, y in zip(a, b, strict=True))


def test_tooth_only_record_list_is_unchanged_by_to_frames(k4):
    _, recs = k4
    assert [r for r in to_frames(recs) if isinstance(r, ToothBatch)] == [r for r in recs if isinstance(r, ToothBatch)]


def test_a_frame_that_is_not_a_plain_array_is_filed_as_one():
    """A Fortran-ordered, a read-only and a list frame are copied once into a plain array: the same rows, counts and
    stored samples (copied, never computed: equal) as the plain frame."""
    rng = np.random.default_rng(5)
    cyls = (1, 2, 3)
    plain = EngineBuffers(pressure_capacity=500)
    others = [EngineBuffers(pressure_capacity=500) for _ in range(3)]
    t = 1000.0
    for _ in range(40):
        v = rng.normal(5e5, 1e5, (3, int(rng.integers(1, 40))))
        ro = v.copy()
        ro.flags.writeable = False
        n = plain.add_frame(PressureFrame(cyls, t, 25.0, v))
        for buf, w in zip(others, (np.asfortranarray(v), ro, v.tolist()), strict=True):
            assert buf.add_frame(PressureFrame(cyls, t, 25.0, w)) == n
        t += v.shape[1] * 25.0 - (50.0 if rng.random() < 0.2 else 0.0)  # some overlap what came before
    for buf in others:
        assert buf.rejected == plain.rejected
        for c in cyls:
            a, b = plain.pressure[c], buf.pressure[c]
            assert (a.start, a.end, a.dropped) == (b.start, b.end, b.dropped)
            np.testing.assert_array_equal(a.view("p"), b.view("p"))
            np.testing.assert_array_equal(a.view("t"), b.view("t"))
