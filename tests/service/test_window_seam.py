"""Window means across a replay's loop seam (issue 28 follow-up): the first cycle of the log and the first after
each seam have no cycle before them (``no_previous_cycle``), so no estimate of their own. A window mean leaves them
out and says how many, instead of calling the whole window 'unresolved' (on 2331c52 every window over a seam of the
looped demo read 'unresolved': 'measured in 49 of 50 cycles').

The demo looped three times (120 cycles, seams before cycles 40 and 80) is fed through the API's own path
(LatestState -> running sums -> api_views.losses_window); each figure is checked against the plain mean of the
counted cycles' own estimates, computed here from the cycles' documents.
"""

from __future__ import annotations

import numpy as np
import pytest
from frictionwatch.drivers.logs.mcap_replay import McapSource
from frictionwatch.service.api_models import Losses
from frictionwatch.service.api_views import losses_window
from frictionwatch.service.listeners import LatestState, ServiceEvent
from frictionwatch.service.pipeline import EnginePipeline, resolve_model
from frictionwatch.service.window_figures import figures_from_cycles

from tests.json_close import assert_json_close
from tests.service.serve_helpers import DEMO

PASSES = 3
LOG_CYCLES = 40  # the demo's cycles in one pass


@pytest.fixture(scope="module")
def looped():
    src = McapSource(DEMO, loop=True)
    try:
        pipe = EnginePipeline(resolve_model(src.engine_toml, None, DEMO.name, src.info), src.info)
        results = []
        while src.passes < PASSES:
            for record in src.read():
                results += [o.result for o in pipe.outcomes(record) if o.result is not None]
    finally:
        src.close()
    assert [r.index for r in results if "no_previous_cycle" in r.flags] == [0, LOG_CYCLES, 2 * LOG_CYCLES]
    return results


def window_doc(results, upto: int, cycles: int) -> dict:
    """GET .../losses?window_cycles=N as the API answers it after cycle ``upto``."""
    state = LatestState(max_results=5000)
    for r in results[: upto + 1]:
        state.on_message_received(ServiceEvent("demo", r, 0.0))
    last, figures = state.window(cycles)
    doc = losses_window("demo", last, figures, ())
    Losses.model_validate(doc)
    return doc


def plain_mean(results, first: int, last: int, pick) -> tuple[float, int]:
    """The mean of ``pick(doc)`` over the window's cycles with a previous cycle, and how many were left out."""
    docs = [r.to_json(smoothed=False) for r in results[first:last + 1] if "no_previous_cycle" not in r.flags]
    return float(np.mean([pick(d) for d in docs])), (last - first + 1) - len(docs)


@pytest.mark.parametrize(("upto", "cycles", "left"), [(119, 50, 1), (119, 100, 2), (119, 120, 3), (85, 10, 1)])
def test_a_window_over_a_seam_is_measured_without_the_seam_cycles(looped, upto, cycles, left):
    doc = window_doc(looped, upto, cycles)
    first = upto - cycles + 1
    assert doc["window"] == {"first_cycle": first, "last_cycle": upto, "cycles": cycles - left,
                             "cycles_left_out": left,
                             "left_out": f"{left} cycle{'s' if left > 1 else ''} without a previous cycle left out",
                             "cycles_missing": 0, "cycles_dropped": 0, "missing": None}  # a seam skips no index
    eng = doc["engine"]
    assert eng["status"] == "measured", eng["reason"]
    want, n_left = plain_mean(looped, first, upto, lambda d: d["fmep_bar"])
    assert n_left == left
    np.testing.assert_allclose(eng["fmep_bar"], want, rtol=1e-12)  # the same numbers summed: rounding only
    # the demo's cylinders are shares in every cycle (20 cylinders, one speed): the window's mean of each share
    for c in doc["cylinders"]:
        k = c["cylinder"] - 1
        assert c["status"] == "share" and c["fmep_bar"] is None, c["reason"]
        share, _ = plain_mean(looped, first, upto, lambda d, k=k: d["cylinders"][k]["friction"]["fmep_bar"])
        np.testing.assert_allclose(c["share_fmep_bar"], share, rtol=1e-12)
    assert "no_previous_cycle" not in doc["active_flags"]


def test_the_running_sums_equal_the_reference_over_a_seam(looped):
    upto, cycles = 119, 100
    doc = window_doc(looped, upto, cycles)
    window = looped[upto - cycles + 1: upto + 1]
    reference = losses_window("demo", window[-1], figures_from_cycles(window), ())
    assert_json_close(doc, reference, rtol=1e-9, atol=1e-12)


def test_a_window_ending_on_the_seam_cycle_reads_the_cycle_before(looped):
    """The newest cycle is the seam's: the statuses come from the newest cycle with a previous cycle (79), the
    window still ends at 80."""
    doc = window_doc(looped, 80, 10)
    assert doc["cycle_index"] == 80 and doc["window"]["last_cycle"] == 80 and doc["window"]["cycles_left_out"] == 1
    want, _ = plain_mean(looped, 71, 80, lambda d: d["fmep_bar"])
    assert doc["engine"]["status"] == "measured"
    np.testing.assert_allclose(doc["engine"]["fmep_bar"], want, rtol=1e-12)


def test_a_window_of_seam_cycles_only_says_so(looped):
    doc = window_doc(looped, 80, 1)
    assert doc["window"]["cycles"] == 0 and doc["window"]["cycles_left_out"] == 1
    assert doc["engine"]["status"] == "unresolved" and doc["engine"]["fmep_bar"] is None
    assert "1 cycle without a previous cycle left out" in doc["engine"]["reason"]
    assert {c["status"] for c in doc["cylinders"]} == {"unresolved"}
    assert all(c["share_fmep_bar"] is None and "left out" in c["reason"] for c in doc["cylinders"])
