"""core/monitor/report/figure_status.py: the compact status (each cylinder's code and data weight, the words made on
request; design note 100) against the status as it was made before, every cylinder's words and weight at once
(``_words_reference``, the function as it stood at d64be04), over seeded estimates that reach every branch."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from frictionwatch.core.monitor.report.figure_status import (
    NO_LOAD,
    STATUSES,
    FigureStatus,
    friction_status,
    split_flag,
    withholds,
)


def _words_reference(est, active_flags) -> tuple[FigureStatus, tuple[FigureStatus, ...]]:
    """friction_status before design note 100 (engine, cylinders), each cylinder's reason built in the loop."""
    z = int(np.shape(est.resolved)[0])
    engine_faults: list[str] = []
    cyl_faults: dict[int, list[str]] = {}
    no_load = False
    for flag in sorted(set(active_flags)):
        kind, cyl = split_flag(flag)
        if kind == NO_LOAD:
            no_load = True
        elif withholds(kind):
            (engine_faults if cyl is None else cyl_faults.setdefault(cyl, [])).append(flag)
    accumulated = est.weight > 0
    if no_load:
        engine = FigureStatus("unresolved", "no load measurement: nothing balances the indicated work (a measured "
                                            "load or a deceleration would), so the engine's friction is not known",
                              None)
    elif est.source != "data":
        engine = FigureStatus("unresolved", est.source.removeprefix("prior: "), None)
    elif engine_faults:
        engine = FigureStatus("withheld", "sensor fault flagged: " + ", ".join(engine_faults), None)
    elif not accumulated:
        engine = FigureStatus("prior", "no cycle accumulated yet (the monitor's warm-up): the engine model's prior "
                                       "friction, drawn toward the mean balance of the cycles so far; not an estimate "
                                       "from enough data", None)
    elif not math.isfinite(est.total_friction_torque):
        engine = FigureStatus("unresolved", "the data do not determine the engine's friction", None)
    else:
        engine = FigureStatus("measured", None, None)
    cylinders = []
    for k in range(z):
        gain = float(est.data_gain[k])
        weight = None if z == 1 or not math.isfinite(gain) else gain if accumulated else 0.0
        faults = engine_faults + cyl_faults.get(k + 1, [])
        share = float(est.prior_friction_torque_mean[k])
        if faults and engine.status != "unresolved":
            cylinders.append(FigureStatus("withheld", "sensor fault flagged: " + ", ".join(faults), weight))
        elif bool(est.resolved[k]) and math.isfinite(float(est.friction_torque_mean[k])):
            cylinders.append(FigureStatus("measured", None, weight))
        elif engine.status == "measured" and math.isfinite(share):
            w = "n/a" if weight is None else f"{weight:.2f}"
            pulled_mask = getattr(est, "pulled", None)
            pulled = pulled_mask is not None and bool(pulled_mask[k])
            why = (f"the speed data lead this cylinder's figure further from its share than their own scatter "
                   f"allows (data weight {w}): a repeated error of the engine model in the speed (the pull check)"
                   if pulled else
                   f"the speed data do not separate this cylinder from its siblings (data weight {w})")
            cylinders.append(FigureStatus(
                "share", why + ": the value is its share of the engine's measured friction in proportion to its "
                               "indicated work, not a measurement of this cylinder", weight))
        else:
            why = {"measured": "the data do not determine this cylinder's friction",
                   "prior": "no cycle accumulated yet (the monitor's warm-up): nothing from the data for this "
                            "cylinder"}.get(engine.status, engine.reason)
            cylinders.append(FigureStatus("unresolved", why, weight))
    return engine, tuple(cylinders)


@dataclass
class _Est:
    resolved: np.ndarray
    data_gain: np.ndarray
    friction_torque_mean: np.ndarray
    prior_friction_torque_mean: np.ndarray
    total_friction_torque: float
    weight: float
    source: str


@dataclass
class _PulledEst(_Est):
    pulled: np.ndarray = None  # type: ignore[assignment]


FLAG_POOL = ("misfire_cyl2", "sensor_gain_cyl1", "sensor_gain_cyl3", "sensor_tdc_offset_cyl3", "sensor_tdc_offset",
             "no_load_measurement", "operating_point_changed", "sensor_pegging_offset_cyl12", "sensor_gain_cyl40",
             "sensor_gain_cyl0",  # (no cylinder 0: split_flag reads it as an engine-wide flag, before and now)
             "model_misfit", "no_previous_cycle")


def _estimate(rng: np.random.Generator, z: int) -> _Est:
    def with_nan(x: np.ndarray, p: float) -> np.ndarray:
        return np.where(rng.random(z) < p, np.nan, x)

    parts = dict(resolved=rng.random(z) < 0.4, data_gain=with_nan(rng.random(z), 0.1),
                 friction_torque_mean=with_nan(rng.normal(5.0, 1.0, z), 0.3),
                 prior_friction_torque_mean=with_nan(rng.normal(5.0, 0.5, z), 0.1),
                 total_friction_torque=float(rng.choice([20.0, math.nan], p=[0.85, 0.15])),
                 weight=float(rng.choice([0.0, 37.5])),
                 source=str(rng.choice(["data", "prior: no mean balance (no load measurement)"], p=[0.8, 0.2])))
    if rng.random() < 0.5:
        return _PulledEst(**parts, pulled=rng.random(z) < 0.3)
    return _Est(**parts)


@pytest.mark.parametrize("z", [1, 3, 4, 20])
def test_status_and_words_as_before(z):
    rng = np.random.default_rng(100 + z)
    seen = set()
    for _ in range(400):
        est = _estimate(rng, z)
        flags = [f for f in FLAG_POOL if rng.random() < 0.15]
        engine, cylinders = _words_reference(est, flags)
        st = friction_status(est, flags)
        # the compact codes and weights, read before any words are asked for
        assert st.codes.tolist() == [STATUSES.index(c.status) for c in cylinders]
        expected_w = np.array([np.nan if c.data_weight is None else c.data_weight for c in cylinders])
        np.testing.assert_allclose(st.data_weight, expected_w, rtol=0, atol=0)  # NaN where None
        # the words on request: equal, weight by weight and letter by letter
        assert st.engine == engine
        assert st.cylinders == cylinders
        # equality is of the words: an engine-wide sensor flag changes them unless nothing balances the work
        balanced = "no_load_measurement" not in flags and est.source == "data"
        assert st == friction_status(est, flags) and (st != friction_status(est, [*flags, "sensor_x"])) == balanced
        seen.update((engine.status, c.status, c.reason.split(" (")[0] if c.reason else None) for c in cylinders)
    statuses = {s for _, s, _ in seen}
    assert statuses == {"measured", "share", "unresolved", "withheld"}
    assert len({r for _, s, r in seen if s == "share"}) == 2  # both share reasons (pulled and not) reached


def test_words_read_after_the_estimate_changes():
    """The words come from what the status kept, not from the estimate read again later."""
    est = _PulledEst(np.array([False, False, True]), np.array([0.2, 0.4, 0.9]), np.array([np.nan, np.nan, 5.0]),
                     np.array([4.0, 5.0, 6.0]), 20.0, 10.0, "data", pulled=np.array([True, False, False]))
    engine, cylinders = _words_reference(est, ["sensor_gain_cyl3"])
    st = friction_status(est, ["sensor_gain_cyl3"])
    est.pulled[:] = False
    est.data_gain[:] = 0.0
    assert st.cylinders == cylinders and st.engine == engine
    assert "pull check" in st.cylinders[0].reason and "0.20" in st.cylinders[0].reason
