"""Where the discrepancy workflow's tuned numbers are recorded (core/discrepancy/tuned.json; the mechanism:
core.tuned, issue 26 item 5).

    TUNED = tuned_constants()        # name -> Tuned(value, tuned_by, on, figure, date, status)
    TUNED["NULL_OWN"].value

Written by the bench run that tunes each number (``tuned_by``: bench/discrepancy_null.py --tune --write,
bench/discrepancy_sigma.py --write), never by hand; ``on`` names the logs it was tuned on, which
tests/core/test_tuned_provenance.py checks are none of the logs that validate it.
"""

from __future__ import annotations

from pathlib import Path

from frictionwatch.core.tuned import Tuned, read_tuned, round_up
from frictionwatch.core.tuned import write_tuned as _write

TUNED_PATH = Path(__file__).with_name("tuned.json")


def tuned_constants(path: Path = TUNED_PATH) -> dict[str, Tuned]:
    return read_tuned(path)


def write_tuned(updates: dict[str, Tuned], path: Path = TUNED_PATH) -> None:
    _write(updates, path)


__all__ = ["TUNED_PATH", "Tuned", "round_up", "tuned_constants", "write_tuned"]
