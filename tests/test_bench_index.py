"""bench/ stays walkable: every script is listed in bench/README.md by what it measures, and the recorded outputs
the design notes quote live in bench/results/, not beside the scripts (221 of them once made bench/ a flat folder
of 300 entries)."""

from __future__ import annotations

import re
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "bench"


def test_every_bench_script_is_in_the_index():
    listed = set(re.findall(r"^\| `(\w+)` \|", (BENCH / "README.md").read_text(), flags=re.M))
    scripts = {p.stem for p in BENCH.glob("*.py")} - {"__init__"}
    assert scripts - listed == set(), "bench scripts missing from bench/README.md"
    assert listed - scripts == set(), "bench/README.md lists scripts that do not exist"


def test_recorded_outputs_live_in_results():
    assert sorted(p.name for p in BENCH.glob("*.json")) == []
    assert len(list((BENCH / "results").glob("*.json"))) > 0
