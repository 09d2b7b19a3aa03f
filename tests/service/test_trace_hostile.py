"""`frictionwatch trace` on options a careless hand types (design note 142): a brake torque or sensor gain that is
not a finite number is one line naming the option, never an FMEP of -inf printed with exit 0."""

import json

import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.service.cli import main
from numpy.testing import assert_allclose

from tests.drivers.test_bench_export_hostile import csv_text


@pytest.mark.parametrize("value", ["inf", "nan", "1e400"])
def test_a_brake_torque_that_is_no_finite_number_is_refused(tmp_path, capsys, value):
    path = tmp_path / "p.csv"
    path.write_text(csv_text())
    assert main(["trace", str(path), "--engine", "polito-4cyl", "--brake-torque-nm", value, "--json"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--brake-torque-nm" in err and "finite" in err, err


def test_a_finite_brake_torque_still_gives_imep_minus_bmep(tmp_path, capsys):
    path = tmp_path / "p.csv"
    path.write_text(csv_text())
    assert main(["trace", str(path), "--engine", "polito-4cyl", "--brake-torque-nm", "100", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    bmep_bar = load_engine("polito-4cyl").torque_to_mep(100.0) / 1e5
    assert_allclose(doc["brake"]["imep_minus_bmep_bar"], doc["imep_bar"] - bmep_bar, rtol=1e-12)


@pytest.mark.parametrize("value", ["inf", "1e400"])
def test_a_gain_that_is_no_finite_number_names_the_option(tmp_path, capsys, value):
    path = tmp_path / "e.xlsx"
    path.write_bytes(b"PK")  # refused on the option before the file is read
    assert main(["trace", str(path), "--engine", "auth-4cyl", "--gain-bar-per-v", value]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--gain-bar-per-v" in err and "finite" in err, err
