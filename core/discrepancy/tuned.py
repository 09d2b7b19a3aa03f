"""The discrepancy workflow's tuned numbers, each with where it came from (issue 26 item 5).

    TUNED = tuned_constants()        # name -> Tuned(value, tuned_by, on, figure, date), from tuned.json
    TUNED["NULL_OWN"].value

tuned.json is written by the bench run that tunes each number (``tuned_by``: bench/discrepancy_null.py --tune
--write, bench/discrepancy_sigma.py --write), never by hand; ``on`` names the logs it was tuned on (engine, operating
point, seed), which the tests check are none of the logs that validate it (tests/core/test_tuned_provenance.py).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

TUNED_PATH = Path(__file__).with_name("tuned.json")


@dataclass(frozen=True)
class Tuned:
    """One tuned number: its value, the command that tuned it, the logs it was tuned on and the figure it came from
    (what was measured, the margin), and the date of that run."""

    value: float
    tuned_by: str
    on: tuple[str, ...]
    figure: str
    date: str


def tuned_constants(path: Path = TUNED_PATH) -> dict[str, Tuned]:
    doc = json.loads(path.read_text())
    return {name: Tuned(float(e["value"]), e["tuned_by"], tuple(e["on"]), e["figure"], e["date"])
            for name, e in doc.items()}


def round_up(x: float, digits: int = 2) -> float:
    """``x`` rounded up (away from zero) to ``digits`` significant figures: a tuned floor is never made smaller by its
    rounding."""
    if x == 0 or not math.isfinite(x):
        return x
    scale = 10.0 ** (digits - 1 - math.floor(math.log10(abs(x))))
    return math.copysign(math.ceil(abs(x) * scale - 1e-9) / scale, x)


def write_tuned(updates: dict[str, Tuned], path: Path = TUNED_PATH) -> None:
    """Replace the named entries of tuned.json (the others kept), atomically: a reader never sees half a file."""
    doc = json.loads(path.read_text()) if path.exists() else {}
    doc.update({name: {**asdict(t), "on": list(t.on)} for name, t in updates.items()})
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tuned-", suffix=".json")
    with os.fdopen(fd, "w") as f:
        json.dump(dict(sorted(doc.items())), f, indent=1)
        f.write("\n")
    os.replace(tmp, path)


__all__ = ["TUNED_PATH", "Tuned", "round_up", "tuned_constants", "write_tuned"]
