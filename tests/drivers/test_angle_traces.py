"""drivers/daq/angle_traces.py and xlsx.py on files made here with a known pressure curve: an encoder table whose TDC
marker falls between two encoder edges and whose time stamps were rounded, a crank-angle CSV, broken workbooks."""

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.indicated import net_imep, peak_pressure
from frictionwatch.drivers.daq.angle_traces import cycle_grid, read_angle_csv, read_encoder_table
from frictionwatch.drivers.daq.pressure import cylinder_volume
from frictionwatch.drivers.daq.xlsx import read_sheet
from frictionwatch.drivers.errors import CorruptLog
from numpy.testing import assert_allclose

openpyxl = pytest.importorskip("openpyxl")
SPEC = load_engine("auth-4cyl")
N_POLY = 1.32


def true_pressure(theta_deg: np.ndarray) -> np.ndarray:
    """Absolute pressure [Pa] at angle from firing TDC (any real): polytropic compression/expansion from 0.9 bar at
    BDC (n = N_POLY, so the reader's pegging is exact), a combustion bump peaking after TDC, 0.9 bar in gas exchange."""
    th = (np.asarray(theta_deg) + 360.0) % 720.0 - 360.0
    v_bdc = float(cylinder_volume(np.array([180.0]), SPEC)[0])
    closed = np.abs(th) < 180.0
    p = np.full(th.shape, 0.9e5)
    p[closed] = 0.9e5 * (v_bdc / cylinder_volume(th[closed], SPEC)) ** N_POLY
    return p + 25e5 * np.exp(-(((th - 15.0) / 12.0) ** 2)) * closed


def write_xlsx(path, header, rows):
    wb = openpyxl.Workbook(write_only=True)
    ws = wb.create_sheet("run")
    ws.append(header)
    for r in rows:
        ws.append([float(x) for x in r])
    wb.save(path)


def encoder_table(path, rpm=1200.0, rate_hz=72e3, edge_offset_deg=0.37, seconds=0.2, start_deg=-500.03,
                  time_jitter=0.0, marker_deg=0.0):
    """Time (rounded to 1 us, as the AUTH export), pressure volts (10 bar/V, zero at +1.5 bar), a 360 ppr encoder
    whose rising zero-crossings fall ``edge_offset_deg`` after each whole degree, a 1-sample TDC marker whose rising
    mid-level crossing lies exactly at each TDC (0 and 360 deg of the cylinder's angle)."""
    n = round(seconds * rate_hz)
    t = np.arange(n) / rate_hz
    theta = start_deg + 6.0 * rpm * t
    volts = (true_pressure(theta) - 1.5e5) / 10e5
    encoder = 4.2 * np.sin(2 * np.pi * (theta - edge_offset_deg))
    marker = np.full(n, -0.37)
    for tdc in np.arange(np.ceil((start_deg - marker_deg) / 360.0) * 360.0 + marker_deg, theta[-1], 360.0):
        i = int(np.searchsorted(theta, tdc, side="right"))  # first sample after this TDC
        f = (tdc - theta[i - 1]) / (theta[i] - theta[i - 1])
        marker[i] = 4.0
        mid = -0.37 + 0.5 * (4.0 + 0.37)
        marker[i - 1] = (mid - f * 4.0) / (1.0 - f)  # so the interpolated crossing of mid is at the TDC time
    stamps = np.round(t + time_jitter * np.random.default_rng(1).standard_normal(n) / rate_hz, 6)
    write_xlsx(path, ["Time [s]", "Pressure [V]", "Crank position", "TDC"],
               np.column_stack([stamps, volts, encoder, marker]))
    return path


def truth(theta_deg):
    p = true_pressure(theta_deg)[None]
    th = np.radians(theta_deg)
    imep = net_imep(th, p, np.zeros(1), SPEC.kinematics_params(), SPEC.piston_area, SPEC.displacement_cyl)[0]
    pmax, ang = peak_pressure(th, p, np.zeros(1))
    return imep, pmax[0], np.degrees(ang[0])


def test_encoder_table_gives_the_true_cycle_with_the_marker_between_edges(tmp_path):
    pc = read_encoder_table(encoder_table(tmp_path / "run.xlsx"), SPEC, 10e5, n_poly=N_POLY)
    imep_true, pmax_true, ang_true = truth(cycle_grid())
    assert pc.cycles == 1  # firing TDCs at 0 and 720 deg; only the one at 0 has a whole [-360, 360) in 0.2 s
    th = np.radians(pc.angle_deg)
    imep = net_imep(th, pc.pressure_pa, np.zeros(1), SPEC.kinematics_params(), SPEC.piston_area, SPEC.displacement_cyl)
    pmax, ang = peak_pressure(th, pc.pressure_pa, np.zeros(1))
    assert_allclose(imep[0], imep_true, rtol=1e-4)
    assert_allclose(pmax[0], pmax_true, rtol=1e-4)  # pegged by the polytropic fit
    assert_allclose(np.degrees(ang[0]), ang_true, atol=0.01)
    assert_allclose(pc.rpm, 1200.0, rtol=1e-4)
    assert_allclose(pc.pressure_pa[0], true_pressure(pc.angle_deg), atol=0.02e5)


def test_a_marker_taken_on_the_next_edge_would_be_wrong_by_the_offset(tmp_path):
    """The convention matters: with the edges 0.37 deg off the marker, the true curve read 0.63 deg late (the next
    edge) differs from the reader's by more than the reader's own error."""
    pc = read_encoder_table(encoder_table(tmp_path / "run.xlsx"), SPEC, 10e5, n_poly=N_POLY)
    th = np.radians(pc.angle_deg)
    kin = SPEC.kinematics_params(), SPEC.piston_area, SPEC.displacement_cyl
    got = net_imep(th, pc.pressure_pa, np.zeros(1), *kin)[0]
    late = net_imep(th, true_pressure(pc.angle_deg + 0.63)[None], np.zeros(1), *kin)[0]
    imep_true = truth(cycle_grid())[0]
    assert abs(late / imep_true - 1.0) > 5 * abs(got / imep_true - 1.0)


def test_a_marker_that_is_not_the_measured_cylinders_tdc_is_refused(tmp_path):
    with pytest.raises(CorruptLog, match="marker is not the measured cylinder's TDC"):
        read_encoder_table(encoder_table(tmp_path / "m.xlsx", marker_deg=90.0), SPEC, 10e5)


def test_time_stamps_that_are_not_rounded_but_jittered_are_refused(tmp_path):
    with pytest.raises(CorruptLog, match="not uniformly sampled"):
        read_encoder_table(encoder_table(tmp_path / "j.xlsx", time_jitter=0.3), SPEC, 10e5)


def test_angle_csv_cycles_and_refusals(tmp_path):
    ang = np.arange(-360.0, 1080.0, 0.5)  # two cycles
    path = tmp_path / "p.csv"
    np.savetxt(path, np.column_stack([ang, true_pressure(ang) / 1e5]), delimiter=",",
               header="crank_angle_deg,p_cyl3_bar", comments="")
    pc = read_angle_csv(path)
    assert pc.cylinder == 3 and pc.cycles == 2
    assert_allclose(pc.pressure_pa, np.tile(true_pressure(pc.angle_deg), (2, 1)), rtol=2e-3)
    bad = tmp_path / "bad.csv"
    bad.write_text("angle,pressure\n0,1\n")
    with pytest.raises(CorruptLog, match="crank_angle_deg"):
        read_angle_csv(bad)
    binary = tmp_path / "bin.csv"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(CorruptLog, match="bin.csv"):
        read_angle_csv(binary)


def test_xlsx_reader_refuses_text_and_non_workbooks(tmp_path):
    write_xlsx(tmp_path / "ok.xlsx", ["a", "b"], [[1.0, 2.5], [3.0, -4.0]])
    header, data = read_sheet(tmp_path / "ok.xlsx")
    assert header == ["a", "b"] and data.tolist() == [[1.0, 2.5], [3.0, -4.0]]
    wb = openpyxl.Workbook()
    wb.active.append(["a", "b"])
    wb.active.append([1.0, "lots"])
    wb.save(tmp_path / "text.xlsx")
    with pytest.raises(CorruptLog, match="cell B2 holds text 'lots'"):
        read_sheet(tmp_path / "text.xlsx")
    (tmp_path / "zip.xlsx").write_bytes(b"not a zip at all")
    with pytest.raises(CorruptLog, match="zip.xlsx: not a readable xlsx workbook"):
        read_sheet(tmp_path / "zip.xlsx")
