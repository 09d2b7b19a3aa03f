"""The simulator's second wheel (issue 29 item 1): the engine file's ``[sensors.second_wheel]`` at its shaft node,
logged only when asked (``second_wheel=True``, ``simulate --second-wheel``).

Asked for, it adds ``FreeEndToothBatch`` records and leaves every other record the same to the bit (its tooth errors
and jitter come from a ninth generator); its edges follow the wheel's own gap and tooth errors; over whole cycles the
free end turns at the flywheel's mean speed (the shaft twists, it does not slip).
"""

from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.model.engine import PRESET_DIR, SpecError, load_engine
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.core.types import FreeEndToothBatch, ToothBatch, WheelInfo
from numpy.testing import assert_allclose

from tests.sim_logs import assert_same_records

WHEEL = '\n[sensors.second_wheel]\nteeth = 36\nmissing = 1\nfirst_tooth_deg = 100.0\nnode = "pulley_hub"\n'


def k9k_with_wheel(tmp_path: Path, table: str = WHEEL) -> Path:
    """k9k-4cyl's engine file with a second wheel table appended after its sensors (a 36-1 wheel at the pulley)."""
    text = (PRESET_DIR / "k9k-4cyl.toml").read_text()
    head, tail = text.split("[operating]")
    path = tmp_path / "k9k-wheel2.toml"
    path.write_text(head + table + "\n[operating]" + tail)
    return path


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    spec = load_engine(k9k_with_wheel(tmp_path_factory.mktemp("eng")))
    return spec, simulate(spec, 2000, 0.8, 4, 11), simulate(spec, 2000, 0.8, 4, 11, second_wheel=True)


def test_the_second_wheel_adds_its_records_and_changes_no_other(runs):
    spec, one, two = runs
    assert one.info.second_wheel is None
    assert two.info.second_wheel == WheelInfo(36, 1, 100.0)
    assert not any(isinstance(r, FreeEndToothBatch) for r in one.records)
    assert_same_records([r for r in two.records if not isinstance(r, FreeEndToothBatch)], one.records, rtol=0.0)
    assert "second_wheel" not in one.truth["wheel"]
    assert two.truth["wheel"]["second_wheel"]["node"] == "pulley_hub"


def test_its_edges_follow_its_own_wheel(runs):
    spec, _, two = runs
    ticks = np.concatenate([r.ticks for r in two.records if isinstance(r, FreeEndToothBatch)])
    assert np.all(np.diff(ticks) > 0)
    index = two.diagnostics["edge2_index"]
    assert ticks.size == index.size
    # 35 present teeth a revolution, in order, wrapping after tooth 34
    assert set(np.diff(index) % 35) == {1}
    # the gap (two pitches) is where the wheel says: before tooth 0; elsewhere one pitch (tooth errors, speed ripple)
    dt = np.diff(ticks).astype(float)
    ratio = dt[1:] / dt[:-1]
    at_gap = index[2:] == 0
    assert_allclose(ratio[at_gap], 2.0, rtol=0.15)
    assert np.all(np.abs(ratio[~at_gap & (index[1:-1] != 0)] - 1.0) < 0.3)
    err = np.array(two.truth["wheel"]["second_wheel"]["tooth_errors_deg"])
    assert err.shape == (35,)
    assert_allclose(err.mean(), 0.0, atol=1e-12)
    assert 0.005 < err.std() < 0.1  # the tooth_spacing_error effect's size (default on), its own draw


def test_over_whole_cycles_it_turns_with_the_flywheel(runs):
    spec, _, two = runs
    tick_hz = spec.sensors.tick_hz
    t1 = np.concatenate([r.ticks for r in two.records if isinstance(r, ToothBatch)])
    i1 = two.diagnostics["edge_index"]
    t2 = np.concatenate([r.ticks for r in two.records if isinstance(r, FreeEndToothBatch)])
    i2 = two.diagnostics["edge2_index"]
    rev1, rev2 = t1[i1 == 0] / tick_hz, t2[i2 == 0] / tick_hz  # once a revolution on each wheel
    n = min(rev1.size, rev2.size) - 2
    w1 = 4 * np.pi / (rev1[2:n + 2] - rev1[:n])
    w2 = 4 * np.pi / (rev2[2:n + 2] - rev2[:n])
    assert n >= 5
    assert_allclose(w2, w1, rtol=2e-3)  # twist changes by far less than 1.4 deg over a cycle


def test_a_second_wheel_must_be_declared_and_named_right(tmp_path):
    with pytest.raises(ValueError, match=r"no second wheel.*\[sensors.second_wheel\]"):
        simulate(load_engine("k9k-4cyl"), 2000, 0.8, 1, 1, second_wheel=True)
    with pytest.raises(SpecError, match="not in shaft.nodes"):
        load_engine(k9k_with_wheel(tmp_path, WHEEL.replace("pulley_hub", "pulley")))
    with pytest.raises(SpecError, match="too many"):
        load_engine(k9k_with_wheel(tmp_path, WHEEL.replace("missing = 1", "missing = 4").replace("36", "8")))
    spec = load_engine(k9k_with_wheel(tmp_path, WHEEL.replace('node = "pulley_hub"\n', "")))
    assert spec.sensors.second_wheel.node == 0  # default: the free end (the shaft's first node)
    assert load_engine("k9k-4cyl").sensors.second_wheel is None


def test_the_two_wheel_genset_file_is_the_preset_plus_its_wheel():
    """bench/genset-v20-two-wheels.toml (the benches' two-wheel genset) is the preset verbatim plus the table, so
    the two cannot drift apart; the preset itself has no second wheel (its logs embed its text)."""
    root = Path(__file__).resolve().parents[2]
    two = (root / "bench" / "genset-v20-two-wheels.toml").read_text()
    preset = (PRESET_DIR / "genset-v20.toml").read_text()
    body = two.split("\n", 2)[2]  # without its two comment lines
    start, end = body.index("\n[sensors.second_wheel]"), body.index("\n[operating]")
    assert body[:start] + body[end:] == preset
    spec = load_engine(root / "bench" / "genset-v20-two-wheels.toml")
    assert spec.sensors.second_wheel is not None and spec.node_names[spec.sensors.second_wheel.node] == "front_hub"
    assert load_engine("genset-v20").sensors.second_wheel is None
