"""State is explicit (design.md §2, scipy's zi style): the monitor keeps nothing between calls outside the state it
is given and returns. Three different engines analysed in one process, interleaved cycle by cycle, give the same
results as each engine alone; and a state passed twice gives the same answer twice."""

from pathlib import Path

import pytest
from frictionwatch.core.model.engine import spec_from_toml_text
from frictionwatch.core.monitor.monitor import initial_state, process_cycle
from frictionwatch.drivers.assembly.cycles import CycleAssembler
from frictionwatch.drivers.logs.mcap_log import LogReader
from numpy.testing import assert_allclose

from tests.json_close import assert_json_close

LOGS = Path(__file__).resolve().parents[2] / "replay_logs"
ENGINES = ("deutz-1cyl", "maruti-3cyl", "k9k-4cyl")
CYCLES = 40


def cycles_of(name: str):
    with LogReader(LOGS / f"{name}.mcap") as log:
        spec = spec_from_toml_text(log.engine_toml, origin=name)
        asm = CycleAssembler(log.info, spec.n_cyl, spec.firing_angles, speed_range_rpm=spec.speed_range_rpm)
        cycles = [c for r in log.records() for c in asm.feed(r)] + asm.flush()
    return spec, cycles[:CYCLES]


def assert_same(a, b, where=""):
    """Two JSON documents of results: same code, same process, so equal to rounding."""
    assert_json_close(a, b, rtol=1e-12, where=where)


@pytest.fixture(scope="module")
def runs():
    return {name: cycles_of(name) for name in ENGINES}


def test_engines_interleaved_give_what_each_gives_alone(runs):
    alone = {}
    for name, (spec, cycles) in runs.items():
        state, out = initial_state(spec), []
        for c in cycles:
            state, res = process_cycle(spec, state, c)
            out.append(res)
        alone[name] = out
    states = {name: initial_state(spec) for name, (spec, _) in runs.items()}
    for i in range(CYCLES):
        for name, (spec, cycles) in runs.items():
            states[name], res = process_cycle(spec, states[name], cycles[i])
            assert_same(res.to_json(), alone[name][i].to_json(), f"{name} cycle {i}")
            assert_allclose(res.friction_torque, alone[name][i].friction_torque, rtol=1e-12, atol=0)


def test_a_state_used_twice_gives_the_same_answer(runs):
    spec, cycles = runs["k9k-4cyl"]
    state = initial_state(spec)
    for c in cycles[:25]:
        state, _ = process_cycle(spec, state, c)
    _, first = process_cycle(spec, state, cycles[25])
    _, again = process_cycle(spec, state, cycles[25])
    assert_same(first.to_json(), again.to_json())
