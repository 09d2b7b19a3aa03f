"""A cycle's window row made from the result's arrays (window_figures.result_row, what the API state makes every
cycle) against its reference, ``cycle_row`` of ``to_json(smoothed=False)``: equal, NaN as NaN, on every replay log's
results (shares, measured figures, a first cycle without a previous one) and on copies whose
flags withhold a cylinder, withhold the engine or take the load away."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from frictionwatch.service.pipeline import analyze_log
from frictionwatch.service.window_figures import cycle_row, layout_of, result_row
from numpy.testing import assert_array_equal

from tests.service.serve_helpers import ROOT

LOGS = ("demo", "k9k-4cyl", "maruti-3cyl", "deutz-1cyl")
# flags that change what a figure is: one cylinder's sensor fault (withheld), an engine-wide one, no load measured
FLAG_SETS = ((), ("sensor_tdc_offset_cyl2",), ("misfire_cyl1", "sensor_gain_cyl1"), ("sensor_crank_teeth",),
             ("no_load_measurement",))


@pytest.fixture(scope="module", params=LOGS)
def results(request):
    return analyze_log(ROOT / "replay_logs" / f"{request.param}.mcap").results


def assert_same_row(result) -> set[str]:
    doc = result.to_json(smoothed=False)
    layout = layout_of(doc)
    row, status = cycle_row(doc, layout)
    made_layout, made_row, made_status = result_row(result)
    assert made_layout == layout
    assert_array_equal(made_row, row)  # exact, NaN where the document has null
    assert made_row.dtype == row.dtype == np.float64
    assert_array_equal(made_status, status)
    return {c["friction"]["status"] for c in doc["cylinders"]} | {doc["friction"]["status"]}


def test_the_row_from_the_arrays_is_the_documents(results) -> None:
    seen: set[str] = set()
    picked = [*results[:3], *results[3::7]]  # the first cycles (no previous cycle), then a spread
    for r in picked:
        for flags in FLAG_SETS:
            seen |= assert_same_row(replace(r, flags=(*r.flags, *flags)))
    assert {"withheld", "unresolved"} <= seen  # the altered flags reached the statuses they are meant to


def test_every_status_is_met_over_the_logs() -> None:
    """The row covers every status the document can give (the logs together; the fixture's params each alone)."""
    seen: set[str] = set()
    for name in ("demo", "k9k-4cyl"):
        for r in analyze_log(ROOT / "replay_logs" / f"{name}.mcap").results[:40:3]:
            seen |= assert_same_row(r)
    assert {"measured", "share", "unresolved"} <= seen, seen  # a cycle's own estimate is never the warm-up's prior
