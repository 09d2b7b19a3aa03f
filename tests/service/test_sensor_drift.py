"""Issue 25 check "drift after commissioning": a TDC +0.5 deg or a gain -4 % on one cylinder from cycle 300 of 900
(the simulator's ``from_cycle``, tests/core/test_sensor_onset.py), analysed with the model `commission` wrote on a
healthy log of another seed at another operating point: no sensor flag before the onset, the cylinder's flag within
200 cycles of it and nothing else flagged at the end, that cylinder's friction withheld and no other.

k9k-4cyl, commissioning 2200 rpm / 0.7 seed 71 (120 cycles), runs 2000 rpm / 0.8 seeds 72 and 73; the watches'
thresholds (core.monitor.calibration.tdc_watch, gain_watch) were set on other engines, points and seeds (their
module docs), and bench/sensor_drift.py uses seeds 61 / 62. The TDC case moves cylinder 3, the gain case cylinder 2."""

from __future__ import annotations

import pytest
from frictionwatch.service.pipeline import analyze_log

from tests.sim_logs import commissioned_model, simulate_log, withheld_cylinders

pytestmark = pytest.mark.slow  # collected first (tests/conftest.py): one of the suite's longest files

ONSET, CYCLES, WITHIN = 300, 900, 200


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    return commissioned_model(tmp_path_factory.mktemp("drift"), "k9k-4cyl", 2200, 0.7, 71, 120)


@pytest.mark.parametrize("seed,effect,cylinder,flag", [
    (72, f"tdc_offset:deg=0.5,cylinder=3,from_cycle={ONSET}", 3, "sensor_tdc_offset_cyl3"),
    (73, f"pressure_gain:cylinder=2,gain=0.96,from_cycle={ONSET}", 2, "sensor_pressure_gain_cyl2"),
])
def test_a_drift_after_commissioning_is_flagged_on_its_cylinder_and_withheld(model_path, tmp_path, seed, effect,
                                                                             cylinder, flag):
    log = simulate_log(tmp_path / "drift.mcap", "k9k-4cyl", 2000, 0.8, seed, CYCLES, effect)
    analysis = analyze_log(log, engine=str(model_path))
    assert analysis.cycles_ok == CYCLES
    early = sorted({f for r in analysis.results if r.index < ONSET for f in r.flags if f.startswith("sensor_")})
    assert early == [], early
    first = next((r.index for r in analysis.results if flag in r.flags), None)
    assert first is not None and ONSET <= first <= ONSET + WITHIN, first
    last = analysis.results[-1]
    assert sorted(f for f in last.flags if f.startswith("sensor_")) == [flag]
    assert withheld_cylinders(analysis) == [cylinder]
