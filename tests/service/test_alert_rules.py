"""The alert rules' one interface (service/alert_rules.py, service/alert_interface.py): a made-up rule added to the
engine's rules raises and clears its own alert through the engine's shared hysteresis and records (ids, events,
acknowledge, a Hold that freezes its latch), beside the default rules; each rule's docstring example runs."""

import doctest
from types import SimpleNamespace

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.service import alert_rules
from frictionwatch.service.alert_interface import Decision, Hold
from frictionwatch.service.alerts import AlertConfig, AlertEngine, default_rules

K9K = load_engine("k9k-4cyl")
CONFIG = AlertConfig(baseline_cycles=100, skip_cycles=0)


class CoolantRule:
    """Made up: cylinder 2's coolant too hot while the flag ``hot_cyl2`` is set (3 cycles raise it, 2 clear it),
    no value while ``coolant_sensor_lost`` is set; an alarm from the fifth hot cycle of a run."""

    name, rests_on_baseline = "coolant", False

    def __init__(self):
        self.run = 0  # its own state

    def update(self, result, ctx):
        if "coolant_sensor_lost" in ctx.engine_flags:
            return [Hold(2, {"coolant_sensor": "lost"})]
        hot = "hot" in ctx.cyl_flags[1]
        self.run = self.run + 1 if hot else 0
        return [Decision(2, "overheat", hot, not hot, 3, 2, "alarm" if self.run >= 5 else "warning",
                         f"cylinder 2 coolant hot for {self.run} cycles", {"hot_cycles": self.run})]


def _result(i, flags=()):
    est = SimpleNamespace(resolved=np.zeros(4, bool), data_gain=np.zeros(4), friction_torque_mean=np.full(4, np.nan),
                          friction_torque_mean_sigma=np.full(4, np.nan), prior_friction_torque_mean=np.full(4, 5.0),
                          total_friction_torque=20.0, weight=10.0, source="data", chi2_reduced=1.0)
    return SimpleNamespace(index=i, t_start=0.1 * i, flags=tuple(flags), ring=None, cycle=est, smoothed=est,
                           imep=np.full(4, 12e5))


def test_a_new_rule_is_one_class_and_one_line_and_goes_through_the_shared_hysteresis():
    eng = AlertEngine(K9K, CONFIG, rules=(*default_rules(CONFIG, 4), (CoolantRule(),)))
    # hot 10..15 (with a sensor flag on cylinder 1 10..14), the coolant sensor lost 16..17 (held), cool from 18
    flags = {i: ("hot_cyl2", "sensor_tdc_cyl1") if i < 15 else ("hot_cyl2",) for i in range(10, 16)}
    flags.update({16: ("coolant_sensor_lost",), 17: ("coolant_sensor_lost",)})
    events = [(i, e) for i in range(30) for e in eng.update(_result(i, flags.get(i, ())))]
    got = [(i, e.kind, e.alert.kind, e.alert.cylinder, e.alert.severity) for i, e in events]
    # the default sensor rule runs beside it, an earlier stage: its event comes first in the cycle; ids in raise order
    assert got == [(12, "raised", "overheat", 2, "warning"), (14, "raised", "sensor_fault", 1, "warning"),
                   (14, "updated", "overheat", 2, "alarm"), (19, "cleared", "overheat", 2, "alarm")]
    raised = events[0][1].alert
    assert raised.alert_id == 1 and raised.raised_cycle == 12 and raised.evidence["first_evidence_cycle"] == 10
    assert raised.message == "cylinder 2 coolant hot for 3 cycles" and raised.raised_at_s == 0.1 * 12
    assert events[1][1].alert.alert_id == 2
    overheat = next(a for a in eng.history() if a.kind == "overheat")
    # the hold froze its latch (16, 17 count neither way) and left its evidence on the open alert
    assert overheat.cleared_cycle == 19 and overheat.evidence["coolant_sensor"] == "lost"
    assert overheat.evidence["hot_cycles"] == 0 and overheat.state == "cleared"


def test_a_new_rule_s_alert_is_acknowledged_and_survives_a_rebaseline_unless_it_rests_on_the_baseline():
    rule = CoolantRule()
    eng = AlertEngine(K9K, CONFIG, rules=(*default_rules(CONFIG, 4), (rule,)))
    for i in range(5):
        eng.update(_result(i, ("hot_cyl2",)))
    (a,) = eng.active()
    assert eng.acknowledge(a.alert_id, "operator").state == "acknowledged"
    assert eng.rebaseline() == [] and [x.kind for x in eng.active()] == ["overheat"]
    rule.rests_on_baseline = True
    assert [(e.kind, e.alert.kind, e.alert.state) for e in eng.rebaseline()] == [("cleared", "overheat", "cleared")]


def test_the_default_rules_have_distinct_names_and_their_examples_run():
    names = [r.name for stage in default_rules(CONFIG, 4) for r in stage]
    assert len(names) == len(set(names)) == 9
    result = doctest.testmod(alert_rules, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0 and result.attempted >= 7
