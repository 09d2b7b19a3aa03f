"""The alert engine on short simulated K9K logs the monitor is not told about (all default effects, 3 % COV of
IMEP): a worn ring with a small leak growing in cylinder 2 from mid-run is alerted on cylinder 2 and on no other; a
healthy log with a load step raises nothing. The long runs (20,000 cycles, genset-v20) are bench/alert_detection.py."""

import pytest
from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.alerts import RING_KINDS, AlertConfig, AlertEngine
from frictionwatch.service.pipeline import run

K9K = load_engine("k9k-4cyl")
RPM, LOAD = 1700.0, 0.69
CONFIG = AlertConfig(baseline_cycles=100)  # a short commissioning: the log is short


def _alerts(cycles, effects=(), load_steps=None):
    sim = simulate(K9K, RPM, LOAD, cycles, seed=11, cov_imep=0.03, effects=[parse_effect(e) for e in effects],
                   load_steps=load_steps)
    alerts, raised = AlertEngine(K9K, CONFIG), []
    for outcome in run(K9K, sim.info, sim.records):  # the one pipeline: assembler, monitor, calibration watches
        assert outcome.ok or outcome.stage == "assembly", outcome  # the monitor refuses no cycle
        if not outcome.ok:
            continue
        raised += [e.alert for e in alerts.update(outcome.result) if e.kind == "raised"]
    return raised, alerts


@pytest.mark.slow
@pytest.mark.timeout(1800)  # 300 K9K cycles simulated and monitored: ~7 min on a loaded 2-core box
def test_a_ring_wear_onset_is_alerted_on_its_cylinder():
    onset = 130
    raised, alerts = _alerts(300, [f"ring_wear:cylinder=2,gain=1.3,mass_loss=0.03,from_cycle={onset},ramp_cycles=40"])
    assert alerts.baseline is not None and alerts.baseline.last_cycle < onset
    ring = [a for a in raised if a.kind in RING_KINDS]
    assert ring and all(a.cylinder == 2 for a in ring), [(a.kind, a.cylinder, a.raised_cycle) for a in raised]
    assert onset <= ring[0].raised_cycle <= onset + 150  # the bench's target is 200 cycles
    assert ring[0].evidence["n_expansion_change"] > 0 > ring[0].evidence["n_compression_change"]


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_a_healthy_log_with_a_load_step_raises_nothing():
    raised, alerts = _alerts(300, load_steps=[(170 * 120.0 / RPM, 0.6 * LOAD)])
    assert alerts.baseline is not None
    assert raised == [], [(a.kind, a.cylinder, a.raised_cycle, a.message) for a in raised]
