"""Bench exports as other plants and careless hands write them (design note 142): a crank-angle CSV saved by Excel
(a byte-order mark, quoted header), cut short mid-line, read from a dead or mis-scaled sensor, a header naming no
cylinder number; an xlsx sheet whose cells carry no reference. Each is read or refused in one line naming the file,
never a traceback and never an IMEP from a trace that cannot be a cylinder pressure."""

import zipfile

import numpy as np
import pytest
from frictionwatch.drivers.daq.angle_traces import read_angle_csv
from frictionwatch.drivers.daq.raw import read_daq_table
from frictionwatch.drivers.daq.xlsx import read_sheet
from frictionwatch.drivers.errors import CorruptLog
from numpy.testing import assert_allclose


def pressure_bar(theta_deg: np.ndarray) -> np.ndarray:
    """A plausible absolute cylinder pressure [bar]: 1 bar, a compression bump of 60 bar at firing TDC."""
    th = (theta_deg + 360.0) % 720.0 - 360.0
    return 1.0 + 60.0 * np.exp(-((th / 40.0) ** 2))


def csv_text(cycles: int = 2, header: str = "crank_angle_deg,p_cyl2_bar", scale: float = 1.0) -> str:
    ang = np.arange(-360.0, -360.0 + 720.0 * cycles, 0.5)
    rows = "\n".join(f"{a:g},{scale * p:.6g}" for a, p in zip(ang, pressure_bar(ang), strict=True))
    return f"{header}\n{rows}\n"


def write(tmp_path, text: str, name: str = "p.csv", encoding: str = "utf-8"):
    path = tmp_path / name
    path.write_bytes(text.encode(encoding))
    return path


def test_excel_utf8_bom_and_quoted_header_read_like_the_plain_file(tmp_path):
    plain = read_angle_csv(write(tmp_path, csv_text()))
    bom = read_angle_csv(write(tmp_path, csv_text(), "bom.csv", "utf-8-sig"))
    quoted = read_angle_csv(write(tmp_path, csv_text(header='"crank_angle_deg","p_cyl2_bar"'), "q.csv"))
    for pc in (bom, quoted):
        assert pc.cylinder == 2 and pc.cycles == plain.cycles == 2
        assert_allclose(pc.pressure_pa, plain.pressure_pa, rtol=1e-12)


def test_a_last_line_cut_short_costs_no_whole_cycle(tmp_path):
    text = csv_text(cycles=2) + "1080,1.5"  # a third cycle's first row, cut while the file was copied
    whole = read_angle_csv(write(tmp_path, csv_text(cycles=2), "w.csv"))
    cut = read_angle_csv(write(tmp_path, text[: len(text) - 4], "c.csv"))  # ends in "1080": one value of two
    assert cut.cycles == 2 and any("last line" in n and "dropped" in n for n in cut.notes)
    assert_allclose(cut.pressure_pa, whole.pressure_pa, rtol=1e-12)
    # a cut line that still reads as a row is kept (it is only the start of a cycle the file does not complete)
    kept = read_angle_csv(write(tmp_path, text[: len(text) - 2], "k.csv"))  # ends in "1080,1"
    assert kept.cycles == 2 and not any("last line" in n for n in kept.notes)


def test_a_bad_line_in_the_middle_is_still_refused(tmp_path):
    lines = csv_text().splitlines()
    lines[100] = "-310.5,"
    with pytest.raises(CorruptLog, match="p.csv: not a numeric"):
        read_angle_csv(write(tmp_path, "\n".join(lines) + "\n"))


@pytest.mark.parametrize("header", ["crank_angle_deg,p_cyl_bar", "crank_angle_deg,p_cylA_bar",
                                    "crank_angle_deg,p_cyl0_bar"])
def test_a_header_without_a_cylinder_number_names_the_file(tmp_path, header):
    with pytest.raises(CorruptLog, match="p.csv: .*p_cyl<k>_bar"):
        read_angle_csv(write(tmp_path, csv_text(header=header)))


def test_an_empty_file_is_one_line_without_a_numpy_warning(tmp_path, recwarn):
    for text in ("", "crank_angle_deg,p_cyl1_bar\n"):
        with pytest.raises(CorruptLog, match="p.csv"):
            read_angle_csv(write(tmp_path, text))
    assert not [w for w in recwarn if "loadtxt" in str(w.message)]


@pytest.mark.parametrize("scale,why", [(-1.0, "below 0 bar"), (0.0, "flat"), (1e-6, "flat"), (1e300, "above")])
def test_a_trace_that_is_no_absolute_cylinder_pressure_gives_no_imep(tmp_path, scale, why):
    """A gauge trace stored negated, a dead sensor (zeros), volts or Pa mistaken for bar: refused, not an IMEP."""
    with pytest.raises(CorruptLog, match=f"p.csv: .*{why}"):
        read_angle_csv(write(tmp_path, csv_text(scale=scale)))


def test_one_implausible_cycle_is_skipped_and_said_the_others_kept(tmp_path):
    lines = csv_text(cycles=3).splitlines()
    for i in range(1 + 1440, 1 + 2 * 1440):  # cycle 2 (of 0..2): a sensor that dropped to 0 V
        lines[i] = lines[i].split(",")[0] + ",0"
    pc = read_angle_csv(write(tmp_path, "\n".join(lines) + "\n"))
    assert pc.cycles == 2
    assert any("1 cycle(s) skipped" in n for n in pc.notes)


def sheet_without_cell_references(tmp_path, rows: list[list[float]]):
    """An xlsx whose <c> elements carry no r="B7" (optional in ECMA-376: a cell then follows the one before it,
    a row the row before it) -- what some streaming writers produce."""
    ns = "http://schemas.openxmlformats.org/spreadsheetml/2006/main"
    rel = "http://schemas.openxmlformats.org/officeDocument/2006/relationships"
    body = "".join("<row>" + "".join(f'<c t="inlineStr"><is><t>{v}</t></is></c>' if isinstance(v, str)
                                     else f"<c><v>{v!r}</v></c>" for v in row) + "</row>" for row in rows)
    parts = {
        "xl/workbook.xml": f'<workbook xmlns="{ns}" xmlns:r="{rel}"><sheets><sheet name="s" sheetId="1" r:id="rId1"/>'
                           "</sheets></workbook>",
        "xl/_rels/workbook.xml.rels": '<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/'
                                      'relationships"><Relationship Id="rId1" Target="worksheets/sheet1.xml"/>'
                                      "</Relationships>",
        "xl/worksheets/sheet1.xml": f'<worksheet xmlns="{ns}"><sheetData>{body}</sheetData></worksheet>',
    }
    path = tmp_path / "noref.xlsx"
    with zipfile.ZipFile(path, "w") as z:
        for name, text in parts.items():
            z.writestr(name, text)
    return path


def test_xlsx_cells_without_references_are_placed_in_order(tmp_path):
    header, data = read_sheet(sheet_without_cell_references(tmp_path, [["t", "p"], [0.0, 1.5], [1.0, 2.5]]))
    assert header == ["t", "p"]
    assert data.tolist() == [[0.0, 1.5], [1.0, 2.5]]


def test_xlsx_an_empty_cell_without_a_reference_still_takes_its_place(tmp_path):
    path = sheet_without_cell_references(tmp_path, [["t", "p", "q"], [0.0, 1.5, 7.0], [1.0, 2.5, 8.0]])
    with zipfile.ZipFile(path) as z:
        parts = {n: z.read(n) for n in z.namelist()}
    parts["xl/worksheets/sheet1.xml"] = parts["xl/worksheets/sheet1.xml"].replace(b"<c><v>1.5</v></c>", b"<c/>")
    with zipfile.ZipFile(path, "w") as z:
        for name, data in parts.items():
            z.writestr(name, data)
    _, data = read_sheet(path)
    assert_allclose(data, [[0.0, np.nan, 7.0], [1.0, 2.5, 8.0]])


def daq_text(rows: int = 400) -> str:
    t = np.arange(rows) * 1e-5
    return "".join(f"{a:.6e}\t{np.sin(a * 2e4):.6e}\t{np.cos(a * 1e3):.6e}\n" for a in t)


def test_a_daq_table_cut_mid_line_keeps_every_whole_row_and_says_so(tmp_path):
    text = daq_text()
    whole = read_daq_table(write(tmp_path, text, "whole.txt"))
    cut = read_daq_table(write(tmp_path, text + "4.000000e-03\t1.2", "cut.txt"))  # the next row, cut short
    assert cut.n == whole.n == 400 and not whole.notes
    assert_allclose(cut.wheel_v, whole.wheel_v, rtol=1e-12)
    assert_allclose(cut.pressure_v, whole.pressure_v, rtol=1e-12)
    assert any("last line" in n and "dropped" in n for n in cut.notes)


def test_a_daq_table_with_a_short_line_inside_is_still_refused(tmp_path):
    lines = daq_text().splitlines()
    lines[200] = lines[200].rsplit("\t", 1)[0]
    with pytest.raises(CorruptLog, match="bad.txt: not a numeric DAQ table"):
        read_daq_table(write(tmp_path, "\n".join(lines), "bad.txt"))
