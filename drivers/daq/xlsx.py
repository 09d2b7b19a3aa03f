"""One sheet of an .xlsx workbook as a header and a float table, with the standard library only.

An .xlsx file is a zip of XML parts (ECMA-376): ``xl/workbook.xml`` names the sheets, ``xl/_rels/workbook.xml.rels``
maps each to its part, ``xl/sharedStrings.xml`` holds the text cells, and a sheet part holds ``<row><c r="B7" t=..>
<v>..</v></c></row>``. A measurement export needs no more than that (no formulas are evaluated: a formula cell's cached
value ``<v>`` is read). Text in a data row is refused; empty cells and rows without data read as NaN and are dropped.
"""

from __future__ import annotations

import re
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
from frictionwatch.drivers.errors import CorruptLog

MAIN = "{http://schemas.openxmlformats.org/spreadsheetml/2006/main}"
REL = "{http://schemas.openxmlformats.org/officeDocument/2006/relationships}"
PKG_REL = "{http://schemas.openxmlformats.org/package/2006/relationships}"
_CELL = re.compile(r"([A-Z]+)(\d+)")


def _column(ref: str) -> int:
    """0-based column of a cell reference ('A1' -> 0, 'AB7' -> 27)."""
    letters = _CELL.match(ref).group(1)
    n = 0
    for ch in letters:
        n = 26 * n + ord(ch) - 64
    return n - 1


def _sheet_part(z: zipfile.ZipFile, sheet: str | None) -> tuple[str, str]:
    book = ElementTree.fromstring(z.read("xl/workbook.xml"))
    sheets = [(s.get("name"), s.get(f"{REL}id")) for s in book.iter(f"{MAIN}sheet")]
    if not sheets:
        raise CorruptLog("the workbook lists no sheet")
    names = [n for n, _ in sheets]
    if sheet is not None and sheet not in names:
        raise ValueError(f"no sheet {sheet!r}; the workbook has {', '.join(names)}")
    name, rid = sheets[0] if sheet is None else sheets[names.index(sheet)]
    rels = ElementTree.fromstring(z.read("xl/_rels/workbook.xml.rels"))
    target = next(r.get("Target") for r in rels.iter(f"{PKG_REL}Relationship") if r.get("Id") == rid)
    return name, target.lstrip("/") if target.startswith("/") else f"xl/{target}"


def _shared_strings(z: zipfile.ZipFile) -> list[str]:
    if "xl/sharedStrings.xml" not in z.namelist():
        return []
    root = ElementTree.fromstring(z.read("xl/sharedStrings.xml"))
    return ["".join(t.text or "" for t in si.iter(f"{MAIN}t")) for si in root.iter(f"{MAIN}si")]


def read_sheet(path: str | Path, sheet: str | None = None) -> tuple[list[str], np.ndarray]:
    """(header, data) of a sheet (default: the first): the first row's cells as text, and every later row with a
    value as floats (rows, columns of the header), NaN where a cell is empty. CorruptLog if the file is not an
    xlsx workbook or a data cell holds text."""
    p = Path(path)
    try:
        with zipfile.ZipFile(p) as z:
            name, part = _sheet_part(z, sheet)
            strings = _shared_strings(z)
            rows: dict[int, dict[int, object]] = {}
            row, col = 0, -1  # where a cell without a reference goes: after the one before it (ECMA-376 18.3.1.4)
            with z.open(part) as fh:
                for event, c in ElementTree.iterparse(fh, ("start", "end")):
                    if event == "start":
                        if c.tag == f"{MAIN}row":
                            row, col = int(c.get("r", row + 1)), -1
                        continue
                    if c.tag != f"{MAIN}c":
                        continue
                    ref = c.get("r")
                    row, col = (int(_CELL.match(ref).group(2)), _column(ref)) if ref else (row, col + 1)
                    v, kind = c.find(f"{MAIN}v"), c.get("t", "n")
                    if kind == "inlineStr":
                        value: object = "".join(t.text or "" for t in c.iter(f"{MAIN}t"))
                    elif v is None or v.text is None:
                        c.clear()
                        continue
                    elif kind == "s":
                        value = strings[int(v.text)]
                    elif kind in ("str", "e"):
                        value = v.text
                    else:
                        value = float(v.text)
                    rows.setdefault(row, {})[col] = value
                    c.clear()
    except (zipfile.BadZipFile, KeyError, ElementTree.ParseError, StopIteration, ValueError, IndexError,
            AttributeError) as exc:
        raise CorruptLog(f"{p.name}: not a readable xlsx workbook ({type(exc).__name__}: {exc})") from None
    if not rows:
        raise CorruptLog(f"{p.name}: sheet {name!r} is empty")
    first = min(rows)
    head = rows.pop(first)
    width = max(head) + 1
    header = [str(head.get(i, "")) for i in range(width)]
    data = np.full((len(rows), width), np.nan)
    for i, r in enumerate(sorted(rows)):
        for j, value in rows[r].items():
            if j >= width:
                continue
            if isinstance(value, str):
                raise CorruptLog(f"{p.name}: sheet {name!r} cell {chr(65 + j)}{r} holds text {value!r}, "
                                 "expected a number")
            data[i, j] = value
    return header, data[~np.all(np.isnan(data), axis=1)]
