"""Tuned numbers with where they came from (issue 26 item 5): one record mechanism for the whole project.

    MONITOR = read_tuned(MONITOR_RECORD)      # name -> Tuned(value, tuned_by, on, figure, date, status)
    MONITOR["R_SQUARED_FLOOR"].value

Each concept keeps its numbers in one JSON record beside it (core/discrepancy/tuned.json, core/monitor/tuned.json,
service/alert_tuned.json); the code reads its defaults from there, never from a literal. An entry says:

- ``value``; ``tuned_by``: the command that wrote it (``python -m bench.calibrate_x --write``), or for a number not
  yet re-tuned apart from its tests, ``hand-set from ...`` and ``status`` "hand-set";
- ``on``: the cases it was tuned on, each ``"<engine> <rpm> rpm <load> seed <seed>[ <effect> ...]"`` (a simulated
  log; effects as the CLI writes them, ``-name`` for a default effect left out; ``seed ?`` where a hand-set
  number's seed was never recorded) or ``"log <name>"`` (a recorded one). tests/core/test_tuned_provenance.py
  fails where a test validates on one of them, unless the test is a self-consistency check named as such;
- ``figure``: what was measured and how the number follows from it; ``date`` of that run.

Written only by ``write_tuned`` (atomic: a reader never sees half a file), from the bench that tunes the number
(docs/design-notes.md, note 29).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import NamedTuple

MONITOR_RECORD = Path(__file__).parent / "monitor" / "tuned.json"
STATUSES = ("tuned", "hand-set")
UNKNOWN_SEED = -1  # written "seed ?": only a hand-set number may name a log whose seed was not recorded


class Case(NamedTuple):
    """One log a number was tuned (or is validated) on: a simulated one (engine, rpm, load, seed, effects as the CLI
    writes them) or a recorded one (``log``: its name; the rest empty)."""

    engine: str
    rpm: float
    load: float
    seed: int  # UNKNOWN_SEED: a hand-set number whose log's seed was never recorded
    effects: tuple[str, ...] = ()
    log: str = ""

    def __str__(self) -> str:
        if self.log:
            return f"log {self.log}"
        seed = "?" if self.seed == UNKNOWN_SEED else str(self.seed)
        return " ".join([f"{self.engine} {self.rpm:g} rpm {self.load:g} seed {seed}", *self.effects])


def parse_case(text: str) -> Case:
    """'k9k-4cyl 1700 rpm 0.69 seed 3 chain_mismatch:stiffness_scale=0.8' or 'log E0NOLOAD1' -> Case; a clear error
    on anything else."""
    words = text.split()
    if len(words) == 2 and words[0] == "log":
        return Case("", math.nan, math.nan, -1, (), words[1])
    if len(words) < 6 or words[2] != "rpm" or words[4] != "seed":
        raise ValueError(f"a tuning case reads '<engine> <rpm> rpm <load> seed <seed> [effects]' or 'log <name>': "
                         f"{text!r}")
    seed = UNKNOWN_SEED if words[5] == "?" else int(words[5])
    return Case(words[0], float(words[1]), float(words[3]), seed, tuple(words[6:]))


@dataclass(frozen=True)
class Tuned:
    """One tuned number: its value, the command that tuned it (or how it was hand-set), the cases it was tuned on,
    the figure it came from (what was measured, the margin), the date of that run, and whether a bench re-tuned it
    apart from its tests (``status`` "tuned") or it is still the hand-set value (``"hand-set"``)."""

    value: float
    tuned_by: str
    on: tuple[str, ...]
    figure: str
    date: str
    status: str = "tuned"

    def cases(self) -> tuple[Case, ...]:
        return tuple(parse_case(x) for x in self.on)


def read_tuned(path: Path) -> dict[str, Tuned]:
    """name -> Tuned, from one record; a clear error naming the file and entry where one is malformed."""
    doc = json.loads(Path(path).read_text())
    out = {}
    for name, e in doc.items():
        try:
            t = Tuned(float(e["value"]), e["tuned_by"], tuple(e["on"]), e["figure"], e["date"],
                      e.get("status", "tuned"))
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"{path}: entry {name!r} is malformed ({err})") from err
        out[name] = _check(name, t, path)
    return out


def _check(name: str, t: Tuned, path: Path) -> Tuned:
    if t.status not in STATUSES:
        raise ValueError(f"{path}: entry {name!r} has status {t.status!r}, not one of {STATUSES}")
    if t.status == "tuned" and any(not c.log and c.seed == UNKNOWN_SEED for c in t.cases()):
        raise ValueError(f"{path}: entry {name!r} is tuned but names a log without its seed")
    return t


def round_up(x: float, digits: int = 2) -> float:
    """``x`` rounded up (away from zero) to ``digits`` significant figures: a tuned floor is never made smaller by its
    rounding."""
    if x == 0 or not math.isfinite(x):
        return x
    scale = 10.0 ** (digits - 1 - math.floor(math.log10(abs(x))))
    return math.copysign(math.ceil(abs(x) * scale - 1e-9) / scale, x)


def write_tuned(updates: dict[str, Tuned], path: Path) -> None:
    """Replace the named entries of the record at ``path`` (the others kept), atomically."""
    path = Path(path)
    for name, t in updates.items():  # a malformed entry is refused before anything is written
        _check(name, t, path)
    doc = json.loads(path.read_text()) if path.exists() else {}
    doc.update({name: {**asdict(t), "on": list(t.on)} for name, t in updates.items()})
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tuned-", suffix=".json")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(dict(sorted(doc.items())), f, indent=1)
            f.write("\n")
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


__all__ = ["MONITOR_RECORD", "UNKNOWN_SEED", "Case", "Tuned", "parse_case", "read_tuned", "round_up", "write_tuned"]
