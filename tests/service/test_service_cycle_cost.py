"""What serve does per cycle, made cheap without changing a number (design notes 31): a rule's message and evidence
are made only where the alert engine reads them (a raise, an open alert), and the metrics listener's figures equal
the cycle document's without making it."""

import math
from dataclasses import replace

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.service.alert_interface import Decision
from frictionwatch.service.alerts import AlertConfig, AlertEngine, default_rules
from frictionwatch.service.pipeline import analyze_log

from tests.service.test_alert_rules import _result

K9K = load_engine("k9k-4cyl")
CONFIG = AlertConfig(baseline_cycles=100, skip_cycles=0)


class CountedRule:
    """Cylinder 1 hot in cycles 5..11 (raised after 3, cleared after 2 cool ones); counts how often its message and
    evidence are made."""

    name, rests_on_baseline = "counted", False

    def __init__(self):
        self.made = []

    def update(self, result, ctx):
        hot = 5 <= result.index < 12
        return [Decision(1, "overheat", hot, not hot, 3, 2, "warning", detail=lambda i=result.index: self._made(i))]

    def _made(self, i):
        self.made.append(i)
        return f"hot at {i}", {"cycle": i}


def test_a_rule_s_message_and_evidence_are_made_only_at_a_raise_and_while_its_alert_is_open():
    rule = CountedRule()
    eng = AlertEngine(K9K, CONFIG, rules=(*default_rules(CONFIG, 4), (rule,)))
    events = [(i, e.kind) for i in range(30) for e in eng.update(_result(i)) if e.alert.kind == "overheat"]
    assert events == [(7, "raised"), (13, "cleared")]
    assert rule.made == [7, 8, 9, 10, 11, 12]  # the raise and the open alert's cycles; never while it is closed
    (alert,) = [a for a in eng.history() if a.kind == "overheat"]
    assert alert.message == "hot at 12" and alert.evidence["cycle"] == 12 and alert.evidence["first_evidence_cycle"] == 5


def test_a_decision_needs_its_message_and_evidence_or_a_detail():
    with pytest.raises(ValueError, match="message and evidence"):
        Decision(1, "overheat", True, False, 3, 2, "warning", "hot")


@pytest.fixture(scope="module")
def demo_results():
    return analyze_log("replay_logs/demo.mcap").results + analyze_log("replay_logs/k9k-4cyl.mcap").results[-2:]


def test_the_metrics_figures_are_the_documents_measured_fmep(demo_results):
    # genset-v20 and k9k as they are, k9k with a sensor flag on cylinder 3 (its figure withheld), and with no cycle before (the engine's)
    variants = [demo_results[5], demo_results[39], demo_results[-2], replace(demo_results[-1], flags=(*demo_results[-1].flags,
                                                                                  "sensor_tdc_offset_cyl3")),
                replace(demo_results[-1], flags=("no_previous_cycle",))]
    seen_measured = seen_nan = 0
    for r in variants:
        doc = r.to_json()
        engine, cylinders = r.measured_fmep_bar()
        want = [doc["friction"]] + [c["friction"] for c in doc["cylinders"]]
        got = [engine, *cylinders]
        assert len(got) == len(want) == r.n_cyl + 1
        for g, w in zip(got, want, strict=True):
            if w["status"] == "measured" and w["fmep_bar"] is not None:
                np.testing.assert_allclose(g, w["fmep_bar"], rtol=1e-15)
                seen_measured += 1
            else:
                assert math.isnan(g)
                seen_nan += 1
    # both paths met: k9k's cylinders are measured, most of genset-v20's 20 not in 40 cycles
    assert seen_measured >= 8 and seen_nan >= 20


def test_the_decision_example_runs():
    import doctest

    from frictionwatch.service import alert_interface

    result = doctest.testmod(alert_interface)
    assert result.failed == 0 and result.attempted >= 2
