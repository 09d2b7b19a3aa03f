"""One definition of FMEP (issue 25 item 4): on small simulated logs of every engine preset, every friction figure
`analyze --json` prints has fmep_bar = friction_torque_mean_nm * 4 pi / V_d (and its 1-sigma likewise) to 1e-9, per
cylinder and for the engine, whatever the figure's status (measured, share, prior).

Before the fix the factor was the last cycle's IMEP over its indicated torque (two different 720 deg windows): a
genset-v20 log with a misfiring cylinder read FMEP -3.5 % against the truth where its torque read +1.5 %; the
misfire logs here are that case on every engine."""

from __future__ import annotations

import json

import pytest
from frictionwatch.core.model.engine import available_presets, load_engine
from frictionwatch.service.cli import main

from tests.analyze_doc import assert_fmep_is_torque_over_displacement

pytestmark = pytest.mark.slow  # collected first (tests/conftest.py): one of the suite's longest files

LOGS = {  # name: (speed as a fraction of the preset's range, load, cycles, effects); 8 cycles: the estimate is
    # still the prior; 24: measured
    "short": (0.3, "0.4", "8", []),
    "healthy": (0.6, "0.8", "24", []),
    "misfire": (0.5, "0.9", "24", ["--effect", "misfire:cylinder=1,probability=0.3"]),
}


@pytest.mark.parametrize("log", sorted(LOGS))
@pytest.mark.parametrize("engine", available_presets())
def test_every_fmep_is_the_torque_times_4pi_over_the_displacement(engine, log, tmp_path, capsys):
    where, load, cycles, effects = LOGS[log]
    spec = load_engine(engine)
    lo, hi = spec.speed_range_rpm
    rpm = f"{lo + where * (hi - lo):.0f}"
    out = tmp_path / f"{engine}-{log}.mcap"
    assert main(["simulate", "--engine", engine, "--rpm", rpm, "--load", load, "--cycles", cycles, "--seed", "5",
                 *effects, "-o", str(out)]) == 0
    capsys.readouterr()
    assert main(["analyze", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    checked = assert_fmep_is_torque_over_displacement(doc, spec)
    # not vacuous: the run mean balance is measured on every log; on the short one the engine's figure is the prior
    # (a value in its friction block); on the healthy 24 cycles it is measured (the flat keys too) and every
    # cylinder's figure has a value (measured or a share). The misfire logs may leave the engine unresolved (the
    # single-cylinder tue-4gb10's does).
    run_balance = doc["friction_run_mean_balance"]
    if log == "misfire" and spec.n_cyl == 1 and run_balance["status"] != "measured":
        # a misfiring single cylinder swings the speed, and tue-4gb10's speed-following load with it, by more than
        # the balance's step guard (2 % of its 6 N m rated) between every two cycles: no window's load is known,
        # no cycle balances, and the figure says why (design note 76; before, lagging load means hid the swings)
        assert run_balance["reason"].startswith("the load changed by more than")
    else:
        assert run_balance["status"] == "measured"
    if log == "short":
        assert doc["friction"]["status"] in ("prior", "measured") and checked >= 4
    elif log == "healthy":
        assert doc["friction"]["status"] == "measured" and checked >= 6 + 2 * spec.n_cyl
        # and nothing implausible on a healthy log (the speed-fit floor was set on other simulated logs)
        assert doc["implausible"] == [] and "speed_fit_poor" not in doc["flags"]["run"]
    elif run_balance["status"] == "measured":
        assert checked >= 2
