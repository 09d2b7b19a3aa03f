"""A share is never in a measurement field (issue 28 item 4): the API's cylinders[].fmep_bar and its siblings hold a
value only where the figure is measured, as `analyze --json`'s flat keys; a share's value is under share_*.

The demo (genset-v20: the speed cannot separate 20 cylinders in 40 cycles) shows every cylinder as a share; the
K9K log measures all four.
"""

from __future__ import annotations

import pytest
from frictionwatch.service.api_models import Losses
from frictionwatch.service.api_views import FIGURE_VALUES, cylinder_losses, losses_now, losses_window
from frictionwatch.service.pipeline import analyze_log
from frictionwatch.service.window_figures import figures_from_cycles
from numpy.testing import assert_allclose

from tests.service.serve_helpers import ROOT

LOGS = {"demo": "share", "k9k-4cyl": "measured"}  # what every cylinder's figure is at the log's end


@pytest.fixture(scope="module", params=sorted(LOGS))
def analysed(request):
    return request.param, analyze_log(ROOT / "replay_logs" / f"{request.param}.mcap")


def test_values_sit_under_the_name_of_what_they_are(analysed):
    name, a = analysed
    window = a.results[-10:]
    docs = {"now": losses_now(name, a.results, ()),
            "window": losses_window(name, window[-1], figures_from_cycles(window), ())}
    for kind, doc in docs.items():
        Losses.model_validate(doc)  # the contract's model takes the new keys
        statuses = {c["status"] for c in doc["cylinders"]}
        # the case this log stands for, or the test proves nothing (a window of each cycle's own estimates: shares
        # on both logs, no single cycle separates the cylinders)
        assert statuses == ({LOGS[name]} if kind == "now" else {"share"}), kind
        for c in doc["cylinders"]:
            measured = c["status"] == "measured"
            for key in FIGURE_VALUES:
                value, share = c[key], c["share_" + key]
                assert (value is not None) == measured and (share is not None) == (not measured), (kind, key)
                assert (value if measured else share) > 0
    for c in cylinder_losses(a.results[-1], ()):  # what a store keeps per cycle: the same rule
        assert (c["fmep_bar"] is None) == (c["status"] != "measured")
        assert (c["share_fmep_bar"] is None) == (c["status"] != "share")


def test_a_share_keeps_its_number_under_its_own_name(analysed):
    name, a = analysed
    if LOGS[name] != "share":
        pytest.skip("no share on this log")
    doc = losses_now(name, a.results, ())
    last = a.results[-1]
    per_nm = last.mep_per_nm() / 1e5  # bar per N m of one cylinder
    for c in doc["cylinders"]:
        assert_allclose(c["share_fmep_bar"], c["share_friction_torque_mean_nm"] * per_nm, rtol=1e-12)
        k = c["cylinder"] - 1  # the share rule's value (paper 000 Eq. 6), as analyze --json gives it
        assert_allclose(c["share_friction_torque_mean_nm"], last.smoothed.prior_friction_torque_mean[k], rtol=1e-12)
