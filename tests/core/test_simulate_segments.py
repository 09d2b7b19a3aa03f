"""A run split into segments chains exactly (core/plant/sim_stream.py ``Simulation.checkpoint`` / ``resume``).

Segment 1 runs some chunks and takes a checkpoint; segment 2 is a fresh ``start_simulation`` with the same arguments,
resumed from the (pickled) checkpoint. The records of both, in order, and the truth (entries of both, per-run summary
of the second) must equal the unsplit run's to the bit: the same arithmetic on the same state, so tolerance 0.
"""

import pickle

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import start_simulation

from tests.json_close import assert_json_close
from tests.sim_logs import assert_same_records


def run(engine, rpm, load, cycles, chunk, split=None, **kw):
    """(records, truth) of the whole run, or of segment 1 (``split`` chunks) then segment 2 from its checkpoint."""
    spec = load_engine(engine)
    sim = start_simulation(spec, rpm, load, cycles, 5, **kw)
    chunks = []
    for i, c in enumerate(sim.chunks(chunk_cycles=chunk)):
        chunks.append(c)
        if split is not None and i + 1 == split:
            saved = pickle.dumps(sim.checkpoint())
            break
    if split is not None:  # segment 2: a new simulation of the same arguments, from the checkpoint
        sim = start_simulation(spec, rpm, load, cycles, 5, **kw)
        sim.resume(pickle.loads(saved))
        chunks += list(sim.chunks(chunk_cycles=chunk))
    return [r for c in chunks for r in c.records], {**sim.truth, "cycles": [e for c in chunks for e in c.cycles]}


@pytest.mark.parametrize(("engine", "rpm", "load", "cycles", "kw"), [
    ("genset-v20", 1500, 0.75, 4, {}),  # flexible chain, 20 pressure channels, partial batches across the cut
    ("deutz-1cyl", 2600, 0.8, 6, {"load_steps": [(0.05, 0.6), (0.2, 0.5)]}),  # one step before, one after the cut
    ("maruti-3cyl", 3000, 1.0, 6, {"effects": {"ring_wear": {"cylinder": 2, "from_cycle": 4}}}),  # onset after it
    # a speed step down whose hold spans the cut: its release and the larger output buffers carried over
    ("deutz-1cyl", 2600, 0.8, 8, {"load_steps": [(0.05, 0.6, 1800.0)]}),
    # a channel gain switched before the cut: the switch carried over in the checkpoint
    ("k9k-4cyl", 1700, 1.0, 6, {"effects": {"pressure_gain": {"cylinder": 1, "gain": 1.03, "from_cycle": 1}}}),
], ids=["genset-v20", "deutz-steps", "maruti-ring-wear-from-4", "deutz-speed-step", "k9k-gain-from-1"])
def test_segments_chain_to_the_bit(engine, rpm, load, cycles, kw):
    want_records, want_truth = run(engine, rpm, load, cycles, 2, **kw)
    got_records, got_truth = run(engine, rpm, load, cycles, 2, split=1, **kw)
    assert_same_records(got_records, want_records)
    assert_json_close(got_truth, want_truth, rtol=0.0, atol=0.0)


def test_a_checkpoint_fits_only_its_own_run():
    spec = load_engine("deutz-1cyl")
    sim = start_simulation(spec, 2600, 0.8, 4, 1)
    next(sim.chunks(chunk_cycles=2))
    ck = sim.checkpoint()
    other = start_simulation(spec, 2600, 0.8, 4, 2)  # another seed
    with pytest.raises(ValueError, match="another run"):
        other.resume(ck)
    with pytest.raises(RuntimeError, match="between chunks"):
        start_simulation(spec, 2600, 0.8, 4, 1).checkpoint()
    assert np.isfinite(ck["plant"]["t_out0"])
