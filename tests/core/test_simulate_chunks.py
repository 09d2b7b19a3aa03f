"""The simulator streamed chunk by chunk (core/plant/sim_stream.py) makes the same run whatever the chunk size.

One chunk of the whole run is what ``simulate`` returned before streaming existed; a run cut into chunks of 1 or 3
cycles must give the same records in the same order (tooth, cam and load ticks equal, pressures and load values within
1e-12 relative: the same arithmetic) and the same truth (per-run sums accumulated chunk by chunk: 1e-12 relative).
"""

from pathlib import Path

import frictionwatch.core.plant.sim_run as sim_run_mod
import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.sensors import to_ticks
from frictionwatch.core.plant.simulate import simulate, start_simulation
from frictionwatch.core.types import CamBatch, PressureFrame, ToothBatch
from numpy.testing import assert_allclose, assert_array_equal

from tests.json_close import assert_json_close
from tests.sim_logs import assert_same_records

RTOL = 1e-12


def streamed(engine: str, rpm: float, load: float, cycles: int, chunk_cycles: int, **kw):
    grid = kw.pop("friction_grid", None)
    sim = start_simulation(load_engine(engine), rpm, load, cycles, 7, **kw)
    if grid is not None:
        sim.run.record_friction_grid(grid)
    chunks = list(sim.chunks(chunk_cycles=chunk_cycles))
    return chunks, {**sim.truth, "cycles": [e for c in chunks for e in c.cycles]}


@pytest.mark.parametrize(("engine", "rpm", "load", "cycles", "kw"), [
    ("k9k-4cyl", 1700, 1.0, 7, {}),  # cam, 1-deg grid in the truth
    ("deutz-1cyl", 2600, 0.8, 6, {"load_steps": [(0.08, 0.5)]}),  # a load step inside a chunk
    ("genset-v20", 1500, 0.75, 4, {"friction_grid": True}),  # flexible chain, 20 pressure channels
    # the benches' two-wheel genset (the preset plus a free-end wheel): batches of that wheel's own revolution
    (str(Path(__file__).resolve().parents[2] / "bench" / "genset-v20-two-wheels.toml"), 1500, 0.75, 3,
     {"second_wheel": True}),
    ("maruti-3cyl", 3000, 1.0, 7, {"effects": {"ring_wear": {"cylinder": 2, "from_cycle": 4}}}),  # onset mid-chunk
], ids=["k9k", "deutz-step", "genset-v20", "genset-v20-second-wheel", "maruti-ring-wear-from-4"])
def test_chunked_run_equals_one_chunk(engine, rpm, load, cycles, kw):
    whole, truth = streamed(engine, rpm, load, cycles, chunk_cycles=cycles, **kw)
    assert len(whole) == 1
    for size in (1, 3):
        chunks, got = streamed(engine, rpm, load, cycles, chunk_cycles=size, **kw)
        assert len(chunks) == -(-cycles // size)
        assert sum(len(c.cycles) for c in chunks) == cycles
        assert all(len(c.cycles) == min(size, cycles - i * size) for i, c in enumerate(chunks))
        assert_same_records([r for c in chunks for r in c.records], whole[0].records, rtol=RTOL)
        assert_json_close(got, truth, rtol=RTOL, atol=1e-300, where=f"chunks of {size}")
        for key in ("pressure_true_pa", "edge_times_s", "friction_grid_nm", "cycle_increments"):
            assert_allclose(np.concatenate([c.diagnostics[key] for c in chunks]), whole[0].diagnostics[key],
                            rtol=RTOL, err_msg=key)
        if kw.get("second_wheel"):
            assert_allclose(np.concatenate([c.diagnostics["edge2_times_s"] for c in chunks]),
                            whole[0].diagnostics["edge2_times_s"], rtol=RTOL)


def test_simulate_collects_the_stream_and_records_arrive_in_order():
    spec = load_engine("k9k-4cyl")
    res = simulate(spec, 1700, 1.0, 5, 7)
    _, truth = streamed("k9k-4cyl", 1700, 1.0, 5, chunk_cycles=2)
    assert_json_close(res.truth, truth, rtol=RTOL, atol=1e-300)
    assert [c["index"] for c in res.truth["cycles"]] == list(range(5))
    last = [int(r.ticks[-1]) if isinstance(r, ToothBatch | CamBatch) else
            round(r.t0_ticks + (r.values.shape[1] - 1) * r.period_ticks) if isinstance(r, PressureFrame) else r.ticks
            for r in res.records]
    assert np.all(np.diff(last) >= 0)


def test_a_simulation_runs_once_and_checks_its_chunk_size():
    sim = start_simulation(load_engine("deutz-1cyl"), 2600, 0.8, 2, 1)
    with pytest.raises(ValueError, match="chunk_cycles"):
        next(sim.chunks(chunk_cycles=0))
    list(sim.chunks())
    assert sim.truth["cycles_count"] == 2
    with pytest.raises(RuntimeError, match="runs once"):
        next(sim.chunks())


def test_to_ticks_in_pieces_equals_one_piece_even_with_ties():
    """Ticks forced strictly increasing carry across pieces (``after``), the jitter is drawn in order."""
    times = np.repeat(np.linspace(0.0, 1e-3, 40), 2)  # every time twice: ties everywhere
    for jitter in (0.0, 2e-7):
        whole = to_ticks(times, 1e7, jitter, np.random.default_rng(3))
        rng, pieces, after = np.random.default_rng(3), [], -1
        for part in np.split(times, [1, 2, 17, 50]):
            pieces.append(to_ticks(part, 1e7, jitter, rng, after=after))
            after = int(pieces[-1][-1]) if pieces[-1].size else after
        assert_array_equal(np.concatenate(pieces), whole)
        assert np.all(np.diff(whole) > 0) and whole[0] >= 0
    assert_array_equal(to_ticks(np.array([0.0, 0.0, 5e-7, 1e-6]), 1e7, 0.0, None), [0, 1, 5, 10])


def test_the_kernels_call_length_and_the_friction_grid_leave_records_and_truth_as_they_are(monkeypatch):
    """Kernel calls of up to 4 cycles (sim_run.CALL_CYCLES: numba's dispatch paid once in 4 cycles, not once a
    cycle) make the run a call per cycle makes, and a 20-cylinder run without the 1-deg friction grid (its default:
    the truth keeps it only for <= 4 cylinders) the run with it, to the bit, but for that grid (design note 129)."""
    args = ("genset-v20", 1500, 0.75, 10)
    default, truth = streamed(*args, chunk_cycles=10)
    monkeypatch.setattr(sim_run_mod, "CALL_CYCLES", 1)
    per_cycle, truth_per_cycle = streamed(*args, chunk_cycles=10, friction_grid=True)
    assert_same_records(default[0].records, per_cycle[0].records, rtol=0.0)
    assert truth == truth_per_cycle
    d, p = default[0].diagnostics, per_cycle[0].diagnostics
    for key in ("pressure_true_pa", "edge_times_s", "flywheel_speed_grid_rad_s", "grid_time_s", "cycle_increments"):
        assert_array_equal(d[key], p[key], err_msg=key)
    assert np.all(np.isnan(d["friction_grid_nm"])) and np.all(np.isfinite(p["friction_grid_nm"]))
    assert d["friction_grid_nm"].shape == p["friction_grid_nm"].shape == (10, 720)
    k9k, _ = streamed("k9k-4cyl", 1700, 1.0, 1, chunk_cycles=1)
    assert np.all(np.isfinite(k9k[0].diagnostics["friction_grid_nm"]))  # <= 4 cylinders: in the truth, evaluated
