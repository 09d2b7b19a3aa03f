"""The CLI refuses what it does not understand, in one line naming the cause (issue 20, 'Refuse what is not
understood'): unknown or misspelled engine keys, text where a number belongs, binary engine files, argparse errors,
a repeated effect, DAQ files whose wheel or channel count does not fit, an --engine that is not the logged one."""

import gzip
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.model.engine import PRESET_DIR, SpecError, load_engine, spec_from_toml_text
from frictionwatch.service.cli import main

REPLAY = Path(__file__).resolve().parents[2] / "replay_logs"
K9K = (PRESET_DIR / "k9k-4cyl.toml").read_text()


def one_line_error(args, capsys, *needles) -> str:
    rc = main(args)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err and "usage:" not in err, err
    for n in needles:
        assert n in err, err
    return err


def engine_file(tmp_path, text, name="eng.toml"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


# ---- engine files ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("old, new, needles", [
    ("bore_m = ", "bore_mm = ", ("unknown key 'geometry.bore_mm'", "nearest known: 'geometry.bore_m'")),
    ("[geometry]", "[geometry]\ncompresion_ratio = 9.5", ("'geometry.compresion_ratio'", "'geometry.compression_ratio'")),
    ("[sensors]", "[sensor]\nwheel_teeth = 60\n[sensors]", ("unknown key 'sensor'", "nearest known: 'sensors'")),
])
def test_unknown_key_names_it_and_the_nearest_known(tmp_path, capsys, old, new, needles):
    text = K9K.replace(old, new, 1)
    assert text != K9K
    with pytest.raises(SpecError, match="unknown key"):
        spec_from_toml_text(text)
    path = engine_file(tmp_path, text)
    out = str(tmp_path / "o.mcap")
    one_line_error(["simulate", "--engine", path, "--rpm", "1500", "--cycles", "2", "-o", out], capsys, *needles)
    one_line_error(["analyze", str(REPLAY / "k9k-4cyl.mcap"), "--engine", path], capsys, *needles)


def test_every_preset_has_only_known_keys():
    for path in PRESET_DIR.glob("*.toml"):
        load_engine(path)


@pytest.mark.parametrize("old, new, needle", [
    ("bore_m = 0.076", 'bore_m = "76 mm"', "geometry.bore_m = '76 mm': expected a number [m]"),
    ("count = 4", 'count = "4"', "cylinders.count = '4'; expected an integer"),
    ("firing_angles_deg = [0.0,", 'firing_angles_deg = ["0",', "firing_angles_deg[0] = '0': expected a number"),
])
def test_text_where_a_number_belongs_says_expected_a_number(tmp_path, capsys, old, new, needle):
    assert old in K9K
    err = one_line_error(["simulate", "--engine", engine_file(tmp_path, K9K.replace(old, new, 1)), "--rpm", "1500",
                          "-o", str(tmp_path / "o.mcap")], capsys, needle)
    assert "out of range" not in err


def test_a_binary_engine_file_is_one_line_naming_the_file(tmp_path, capsys):
    path = tmp_path / "engine.toml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff\xfe" + bytes(range(256)))
    one_line_error(["simulate", "--engine", str(path), "--rpm", "1500", "-o", str(tmp_path / "o.mcap")], capsys,
                   "engine.toml: not a TOML text file")
    one_line_error(["analyze", str(REPLAY / "k9k-4cyl.mcap"), "--engine", str(path)], capsys, "engine.toml")


# ---- argparse and option values ---------------------------------------------------------------------------------

@pytest.mark.parametrize("args, needles", [
    (["simulate", "--engine", "k9k-4cyl", "--rpm", "fast", "-o", "x.mcap"], ("argument --rpm", "'fast'")),
    (["simulate", "--rpm", "1500"], ("required", "--engine")),
    (["analyze"], ("required", "log")),
    (["frobnicate"], ("invalid choice", "frobnicate")),
    (["import-daq", "f.txt", "--engine", "tue-4gb10", "--tdc-deg", "244.5", "-o", "o.mcap"],
     ("--gain-bar-per-v", "--self-calibrate")),
    (["import-daq", "f.txt", "--engine", "tue-4gb10", "--tdc-deg", "244.5", "--self-calibrate",
      "--gain-bar-per-v", "12", "-o", "o.mcap"], ("not allowed with",)),
])
def test_argparse_errors_are_one_line_naming_the_option_exit_2(args, needles, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "usage:" not in err, err
    for n in needles:
        assert n in err, err


def test_import_daq_option_values_name_the_option(tmp_path, capsys):
    path = daq_file(tmp_path / "w.txt.gz", teeth=60, missing=2)
    base = ["import-daq", str(path), "--engine", "deutz-1cyl", "--gain-bar-per-v", "10", "-o", str(tmp_path / "o.mcap")]
    one_line_error([*base, "--tdc-deg", "900"], capsys, "--tdc-deg 900")
    one_line_error([*base, "--tdc-deg", "90", "--n-poly", "3"], capsys, "--n-poly 3")
    one_line_error(["import-daq", str(path), "--engine", "deutz-1cyl", "--tdc-deg", "90", "--gain-bar-per-v", "-2",
                    "-o", str(tmp_path / "o.mcap")], capsys, "--gain-bar-per-v -2")


def test_negative_seed_names_the_option(tmp_path, capsys):
    one_line_error(["simulate", "--engine", "k9k-4cyl", "--rpm", "1500", "--seed", "-1", "-o",
                    str(tmp_path / "o.mcap")], capsys, "--seed -1")


# ---- effects ------------------------------------------------------------------------------------------------------

def test_an_effect_in_two_cylinders_is_two_instances_and_said(tmp_path, capsys):
    out = tmp_path / "worn.mcap"
    assert main(["simulate", "--engine", "k9k-4cyl", "--rpm", "1500", "--cycles", "2", "--effect",
                 "ring_wear:cylinder=1", "--effect", "ring_wear:cylinder=2", "-o", str(out)]) == 0
    said = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("effects active:")]
    assert len(said) == 1 and "ring_wear (cylinder 1), ring_wear (cylinder 2)" in said[0], said
    one_line_error(["simulate", "--engine", "k9k-4cyl", "--rpm", "1500", "--cycles", "2", "--effect",
                    "ring_wear:cylinder=2", "--effect", "ring_wear:cylinder=2,gain=1.2", "-o", str(out)], capsys,
                   "effect 'ring_wear' is given twice for cylinder 2")


# ---- import-daq ---------------------------------------------------------------------------------------------------

def daq_file(path: Path, teeth: int = 36, missing: int = 1, revs: int = 8, rpm: float = 1500.0,
             rate_hz: float = 100e3) -> Path:
    """A time/wheel/pressure volt table: square tooth pulses (half a pitch wide) of a TEETH-MISSING wheel at
    constant speed, and a compression bump once per two revolutions on the pressure column."""
    t = np.arange(round(revs * 60.0 / rpm * rate_hz)) / rate_hz
    angle = (t * rpm / 60.0 * teeth) % teeth  # in pitches; teeth teeth-missing..teeth-1 are absent
    wheel = np.where((angle % 1.0 < 0.5) & (angle < teeth - missing), 4.0, -0.7)
    crank = np.radians((t * rpm * 6.0) % 720.0)
    pressure = 0.5 + 2.0 * np.exp(-(((crank - np.pi) / 0.4) ** 2))
    with gzip.open(path, "wt") as fh:
        np.savetxt(fh, np.column_stack([t, wheel, pressure]), fmt="%.6f", delimiter="\t")
    return path


DAQ_OPTS = ["--tdc-deg", "90", "--gain-bar-per-v", "10"]


def test_import_daq_reads_the_wheel_from_the_file_and_says_it(tmp_path, capsys):
    """The wheel is said first; the made-up bump is no compression, so every cycle is refused and, since issue 25,
    that is exit code 2 with nothing written (it used to write a log of NaN pressure and exit 0)."""
    path = daq_file(tmp_path / "wheel60.txt.gz", teeth=60, missing=2)
    assert main(["import-daq", str(path), "--engine", "deutz-1cyl", *DAQ_OPTS, "-o", str(tmp_path / "o.mcap")]) == 2
    said = capsys.readouterr()
    assert "wheel 60-2, read from the file: 58 teeth and a 2-tooth gap per revolution" in said.out, said.out
    assert "every cycle was refused" in said.err and said.err.count("\n") == 1, said.err
    assert not (tmp_path / "o.mcap").exists()


def test_import_daq_refuses_an_engine_whose_wheel_is_not_the_files(tmp_path, capsys):
    path = daq_file(tmp_path / "wheel36.txt.gz")
    err = one_line_error(["import-daq", str(path), "--engine", "deutz-1cyl", *DAQ_OPTS, "-o",
                          str(tmp_path / "o.mcap")], capsys, "--engine deutz-1cyl has a 60-2 wheel but the file's is 36-1")
    assert not (tmp_path / "o.mcap").exists(), err
    one_line_error(["import-daq", str(path), "--engine", "deutz-1cyl", "--wheel", "36-1", *DAQ_OPTS, "-o",
                    str(tmp_path / "o.mcap")], capsys, "60-2 wheel but the file's is 36-1")


def test_import_daq_refuses_a_wheel_the_file_does_not_have(tmp_path, capsys):
    path = daq_file(tmp_path / "wheel60.txt.gz", teeth=60, missing=2)
    one_line_error(["import-daq", str(path), "--engine", "deutz-1cyl", "--wheel", "36-1", *DAQ_OPTS, "-o",
                    str(tmp_path / "o.mcap")], capsys,
                   "--wheel 36-1 but the file's wheel has 58 teeth and a 2-tooth gap per revolution (60-2")
    assert not (tmp_path / "o.mcap").exists()


def test_import_daq_without_a_gap_asks_for_the_wheel(tmp_path, capsys):
    path = daq_file(tmp_path / "nogap.txt.gz", teeth=36, missing=0)
    one_line_error(["import-daq", str(path), "--engine", "deutz-1cyl", *DAQ_OPTS, "-o", str(tmp_path / "o.mcap")],
                   capsys, "no repeating missing-tooth gap", "--wheel")


def test_import_daq_refuses_an_engine_with_more_cylinders_than_channels(tmp_path, capsys):
    path = daq_file(tmp_path / "w.txt.gz")
    one_line_error(["import-daq", str(path), "--engine", "genset-v20", *DAQ_OPTS, "-o", str(tmp_path / "o.mcap")],
                   capsys, "--engine genset-v20 has 20 cylinders but the file has 1 pressure channel")


def test_import_daq_on_an_empty_file_is_one_line_without_a_numpy_warning(tmp_path, capsys):
    for name, content in (("empty.txt", b""), ("blank.txt", b"\n\n  \n")):
        (tmp_path / name).write_bytes(content)
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a numpy UserWarning would fail the test
            one_line_error(["import-daq", str(tmp_path / name), "--engine", "deutz-1cyl", *DAQ_OPTS, "-o",
                            str(tmp_path / "o.mcap")], capsys, f"{name}: empty file")


def test_import_daq_points_a_spreadsheet_to_trace(tmp_path, capsys):
    (tmp_path / "bench.xlsx").write_bytes(b"PK\x03\x04")
    one_line_error(["import-daq", str(tmp_path / "bench.xlsx"), "--engine", "deutz-1cyl", *DAQ_OPTS, "-o",
                    str(tmp_path / "o.mcap")], capsys, "frictionwatch trace")


# ---- analyze --engine against the logged engine ---------------------------------------------------------------------

def test_analyze_refuses_an_engine_that_is_not_the_logged_one(tmp_path, capsys):
    log = str(REPLAY / "k9k-4cyl.mcap")
    one_line_error(["analyze", log, "--engine", "maruti-3cyl"], capsys, "--engine maruti-3cyl does not match",
                   "wheel is 60-2, the engine's 36-1", "4 cylinders, the engine has 3")
    other_order = K9K.replace("firing_angles_deg = [0.0, 540.0, 180.0, 360.0]",
                              "firing_angles_deg = [0.0, 180.0, 540.0, 360.0]")
    assert other_order != K9K
    one_line_error(["analyze", log, "--engine", engine_file(tmp_path, other_order)], capsys,
                   "firing angles [0, 540, 180, 360] deg recorded", "[0, 180, 540, 360] deg in the engine")


def test_a_rigid_engine_may_list_no_couplings():
    text = (PRESET_DIR / "deutz-1cyl.toml").read_text().replace("[shaft]", "[shaft]\nstiffness_nm_per_rad = []", 1)
    assert spec_from_toml_text(text).n_nodes == 1


def test_a_log_whose_engine_record_and_acquisition_disagree_is_refused(tmp_path, capsys):
    """A log that says one wheel in its engine record (maruti-3cyl's 36-1) and another in its acquisition (the k9k
    log's 60-2) is refused in one line naming both, instead of being analysed on either silently."""
    from frictionwatch.drivers.logs.mcap_log import LogReader, LogWriter

    bad = tmp_path / "mixed.mcap"
    with LogReader(REPLAY / "k9k-4cyl.mcap") as reader, \
            LogWriter(bad, (PRESET_DIR / "maruti-3cyl.toml").read_text(), reader.info) as writer:
        for i, record in enumerate(reader.records()):
            writer.write(record)
            if i > 200:
                break
    one_line_error(["analyze", str(bad)], capsys, "mixed.mcap is inconsistent", "the log's wheel is 60-2",
                   "the engine's 36-1", "--engine")


def test_load_steps_change_the_logs_load_and_a_malformed_one_is_one_line(tmp_path, capsys):
    out = tmp_path / "steps.mcap"
    assert main(["simulate", "--engine", "k9k-4cyl", "--rpm", "2400", "--cycles", "12", "--load", "0.8",
                 "--load-step", "0.3:0.45", "-o", str(out)]) == 0
    loads = [c["load_torque_nm"] for c in json.loads(out.with_suffix(".truth.json").read_text())["cycles"]]
    assert loads[-1] < 0.7 * loads[0], loads  # 0.8 -> 0.45 of full load after 0.3 s (~6 cycles)
    one_line_error(["simulate", "--engine", "k9k-4cyl", "--rpm", "2400", "--load-step", "0.3", "-o", str(out)],
                   capsys, "--load-step '0.3': expected T:FRACTION")
    one_line_error(["simulate", "--engine", "k9k-4cyl", "--rpm", "2400", "--load-step", "0.3:7", "-o", str(out)],
                   capsys, "load step")
