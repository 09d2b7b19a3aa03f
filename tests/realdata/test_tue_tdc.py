"""TDC from the TU/e group14 files' own pressure (issue 25; service/daq_tdc.py, core/monitor/calibration/tdc.py) and
what import-daq does with it.

What the files say (measured, this branch): the motored cycles (ENGINEOFF*, the ignition-off part of the *EngineOff
files) give 243.8-244.1 deg +- 0.12-0.20, i.e. 0.0-0.3 deg after their pressure peak (243.8 deg); the fired cycles
give 246.6-247.9 at full and half load and 240.4-242.9 at no load with sigma 1.7-5.8 deg (the fired fit depends on a
wall heat and a blow-by this engine's model does not know). The stated 244.5 deg (drivers/daq/raw.py TUE_TDC_DEG) is
the motored peak plus an assumed 0.7 deg loss angle. Issue 25 asks for 244.5 +- 0.3 deg on all 19 files: not met (the
strict xfail below says so and fails the day it is met).
"""

from __future__ import annotations

import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.drivers.daq.raw import read_daq_table
from frictionwatch.service.cli import main
from frictionwatch.service.daq_tdc import find_tdc

pytestmark = pytest.mark.slow  # collected first (tests/conftest.py): one of the suite's longest files

FOLDER = "tue-4gb10-si-encoder-pressure"
MOTORED = ("ENGINEOFF", "ENGINEOFF2", "ENGINEOFF3", "ENGINEOFF4", "ENGINEOFF5", "ENGINEOFF6", "E5FULLOAD4EngineOff",
           "E0FULLOAD4EngineOff")
FIRED = ("E0FULLOAD1", "E0FULLOAD2", "E0FULLOAD3", "E0HALFLOAD1", "E0HALFLOAD2", "E0HALFLOAD3", "E0HALFLOAD4",
         "E0NOLOAD1", "E0NOLOAD2", "E0NOLOAD3", "E0NOLOAD4")
MOTORED_PEAK_DEG = 243.8  # the motored pressure peak after tooth 0 (drivers/daq/raw.py)
LOSS_ANGLE_DEG = (0.0, 1.3)  # TDC lies this far after the motored peak (heat loss; 0.4-1.3 deg in the literature)


def found(realdata, name: str):
    trace = read_daq_table(realdata / FOLDER / f"group14_{name}.txt.gz")
    return find_tdc(trace, load_engine("tue-4gb10"), "60-2", None, gain_pa_per_v=12.4e5)


@pytest.mark.parametrize("name", MOTORED)
def test_motored_cycles_put_tdc_just_after_the_motored_peak(realdata, name):
    """From the peak, without --tdc-deg: the motored fit lands after the motored pressure peak by a loss angle in
    the physical range, with a sigma under 0.25 deg, in every file with motored cycles."""
    tdc, why = found(realdata, name)
    assert tdc is not None, why
    assert tdc.motored_cycles >= 3 and tdc.method.startswith("rohr-motored")
    assert LOSS_ANGLE_DEG[0] <= tdc.tdc_deg - MOTORED_PEAK_DEG <= LOSS_ANGLE_DEG[1], tdc.describe()
    assert tdc.sigma_deg < 0.25, tdc.describe()


@pytest.mark.parametrize("name", FIRED)
def test_fired_files_are_not_imported_on_a_tdc_the_fit_cannot_pin(realdata, name, tmp_path, capsys):
    """The fired fit's sigma on this engine is degrees: without --tdc-deg the import is refused (one line, exit 2,
    nothing written), and the stated 244.5 lies within 2 sigma of what the fit says."""
    tdc, why = found(realdata, name)
    assert tdc is not None, why
    assert tdc.fired_cycles >= 3 and abs(tdc.tdc_deg - 244.5) <= 2 * tdc.sigma_deg, tdc.describe()
    out = tmp_path / "o.mcap"
    rc = main(["import-daq", str(realdata / FOLDER / f"group14_{name}.txt.gz"), "--engine", "tue-4gb10",
               "--gain-bar-per-v", "12.4", "-o", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "state it with --tdc-deg" in err, err
    assert not out.exists()


@pytest.mark.xfail(strict=True, reason="measured 243.8-244.1 (motored), 240.4-247.9 (fired): see the module docstring")
def test_issue_target_every_file_within_0_3_deg_of_244_5(realdata):
    misses = []
    for name in MOTORED + FIRED:
        tdc, why = found(realdata, name)
        if tdc is None or abs(tdc.tdc_deg - 244.5) > 0.3:
            misses.append((name, tdc.describe() if tdc else why))
    assert not misses, misses


def test_import_daq_without_tdc_prints_it_and_warns_on_a_stated_one(realdata, tmp_path, capsys):
    path = str(realdata / FOLDER / "group14_ENGINEOFF3.txt.gz")
    base = ["import-daq", path, "--engine", "tue-4gb10", "--gain-bar-per-v", "12.4"]
    assert main([*base, "-o", str(tmp_path / "a.mcap")]) == 0
    said = capsys.readouterr().out
    assert "TDC 244.0" in said and "(1 sigma) from the pressure, method rohr-motored" in said, said
    assert main([*base, "--tdc-deg", "244.6", "-o", str(tmp_path / "b.mcap")]) == 0
    warned = [line for line in capsys.readouterr().out.splitlines() if line.startswith("warning:")]
    assert len(warned) == 1 and "--tdc-deg 244.6 against 244.0" in warned[0], warned
    assert (tmp_path / "a.mcap").stat().st_size > 0 and (tmp_path / "b.mcap").stat().st_size > 0


@pytest.mark.parametrize("tdc_deg", ["259.5", "229.5", "30"])
def test_import_daq_refuses_a_tdc_the_pressure_contradicts(realdata, tmp_path, capsys, tdc_deg):
    """15 deg late, 15 deg early (motored file: the peak window) and a TDC where every cycle is refused: exit 2,
    one line on stderr, nothing written."""
    out = tmp_path / "o.mcap"
    rc = main(["import-daq", str(realdata / FOLDER / "group14_ENGINEOFF2.txt.gz"), "--engine", "tue-4gb10",
               "--tdc-deg", tdc_deg, "--gain-bar-per-v", "12.4", "-o", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert ("which the pressure contradicts" in err) or ("every cycle was refused" in err), err
    assert not out.exists()


def test_self_calibrate_prints_its_gain_and_refuses_a_throttled_file(realdata, tmp_path, capsys):
    motored = ["import-daq", str(realdata / FOLDER / "group14_ENGINEOFF4.txt.gz"), "--engine", "tue-4gb10",
               "--self-calibrate", "-o", str(tmp_path / "m.mcap")]
    assert main(motored) == 0
    said = capsys.readouterr().out
    gain = float(said.split("--self-calibrate: gain ")[1].split()[0])
    assert abs(gain - 12.4) < 0.6, said  # the motored coast-downs' 12.4 bar/V (drivers/daq/raw.py)
    fired = ["import-daq", str(realdata / FOLDER / "group14_E0HALFLOAD2.txt.gz"), "--engine", "tue-4gb10",
             "--tdc-deg", "244.5", "--self-calibrate", "-o", str(tmp_path / "f.mcap")]
    assert main(fired) == 2
    said = capsys.readouterr()
    assert "--self-calibrate: gain" in said.out and "throttled" in said.err and len(said.err.splitlines()) == 1
    assert not (tmp_path / "f.mcap").exists()
