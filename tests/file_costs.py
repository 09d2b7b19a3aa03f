"""Each test file's measured cost, so that `make test`'s two workers are dealt the longest files first.

Why: xdist's --dist loadfile deals whole files in collection order to whichever worker is nearly idle (it asks for
the next file when its current one has two tests left). A long file dealt late runs alone at the end while the other
worker waits: the suite's tail. Dealing the files longest first (the "longest processing time" rule) leaves only
short files for the end, so the two workers end within about one short file of each other.

The costs (``file_costs.json``: seconds of test time per file, setup and teardown included, from one run's JUnit
XML) only order the files; no test reads them, and a stale table costs time, never a result. A file missing from
the table (a new one) is dealt after the table's longest files when it holds a test marked ``slow``, else with the
short ones (tests/conftest.py). Made again, from a whole run of the suite (its JUnit report), by

    .venv/bin/python -m tests.file_costs JUNIT.xml "what run it was (commit, cache, load)"
"""

from __future__ import annotations

import json
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

COSTS = Path(__file__).with_name("file_costs.json")
REPO = Path(__file__).resolve().parents[1]


def load(path: Path = COSTS) -> dict[str, float]:
    """{test file's path from the repository root: seconds}; empty where there is no table."""
    try:
        return json.loads(path.read_text())["seconds"]
    except (OSError, ValueError, KeyError):
        return {}


def file_of(classname: str, root: Path = REPO) -> str | None:
    """The test file a JUnit classname (``tests.core.test_x`` or ``tests.core.test_x.TestClass``) names: its longest
    dotted prefix that is a file under ``root``."""
    parts = classname.split(".")
    for n in range(len(parts), 0, -1):
        rel = "/".join(parts[:n]) + ".py"
        if (root / rel).is_file():
            return rel
    return None


def costs_from_junit(report: Path, root: Path = REPO) -> dict[str, float]:
    """Seconds per test file from a JUnit XML report (pytest's testcase time: setup, call and teardown)."""
    seconds: dict[str, float] = defaultdict(float)
    for case in ET.parse(report).getroot().iter("testcase"):
        rel = file_of(case.get("classname", ""), root)
        if rel is not None:
            seconds[rel] += float(case.get("time", 0.0))
    return {rel: round(s, 1) for rel, s in sorted(seconds.items(), key=lambda kv: -kv[1])}


def write(report: Path, provenance: str, path: Path = COSTS) -> int:
    seconds = costs_from_junit(report)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({"provenance": provenance, "seconds": seconds}, indent=1) + "\n")
    tmp.replace(path)
    return len(seconds)


if __name__ == "__main__":
    print(f"{write(Path(sys.argv[1]), sys.argv[2])} files in {COSTS}")
