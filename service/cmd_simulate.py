"""`frictionwatch simulate`: run the time-domain plant simulator and write OUT.mcap plus OUT.truth.json.

Both files are whole or absent: they are written to temporaries beside the targets while the simulation streams into
them chunk by chunk (memory independent of --cycles) and renamed into place, truth first, only when the whole run
succeeded (service.output_files.atomic_paths). An interrupted or failed run (Ctrl-C, a full disk, an error) leaves
nothing behind, and an unwritable output is refused before the simulation starts.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path
from typing import IO

from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import start_simulation
from frictionwatch.drivers.logs.mcap_log import LogWriter
from frictionwatch.service.output_files import atomic_paths, check_output_path
from frictionwatch.service.progress import progress_bar


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="simulate an engine and write a replay log with its sidecar truth")
    p.add_argument("--engine", required=True, help="preset name (k9k-4cyl, genset-v20, ...) or a TOML file")
    p.add_argument("--rpm", type=float, required=True, help="mean speed [rpm]")
    p.add_argument("--load", type=float, default=1.0, help="load as a fraction of full load, 0..1.1")
    p.add_argument("--cycles", type=int, default=50, help="engine cycles to write")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--cov-imep", type=float, default=None, help="cycle-to-cycle COV of IMEP (fraction)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME[:key=value,...]", help="turn an effect on (repeat it for another cylinder)")
    p.add_argument("--without", action="append", default=[], metavar="NAME", help="turn a default effect off")
    p.add_argument("--load-step", action="append", default=[], metavar="T:FRACTION[:RPM]",
                   help="at T seconds of the log the load becomes FRACTION of full load, and with RPM the speed that "
                        "(a dyno engine: the dyno holds it a few cycles) (repeat for more steps)")
    p.add_argument("--second-wheel", action="store_true",
                   help="log the engine file's second wheel too ([sensors.second_wheel], e.g. genset-v20's free end)")
    p.add_argument("-o", "--output", required=True, type=Path, help="OUT.mcap (truth goes to OUT.truth.json)")
    p.set_defaults(func=run)


def truth_path(log: Path) -> Path:
    return log.with_name(log.name.removesuffix(".mcap") + ".truth.json")


class TruthSpool:
    """The truth file assembled as the run goes: per-cycle entries are spooled, one JSON object a line, to an unnamed
    temporary file in the output folder (it vanishes with the process, however it ends); ``write`` then makes the
    file: the run's truth (indent 1) with its "cycles" list last."""

    def __init__(self, folder: Path):
        self._spool: IO[str] = tempfile.TemporaryFile("w+", encoding="utf-8", dir=folder)
        self._count = 0

    def add(self, entries: list[dict]) -> None:
        for entry in entries:
            self._spool.write(("  " if self._count == 0 else ",\n  ") + json.dumps(entry))
            self._count += 1

    def write(self, path: Path, truth: dict) -> None:
        head = json.dumps(truth, indent=1)
        with open(path, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(head[:-2] + ',\n "cycles": [\n')  # head ends with "\n}"
            self._spool.seek(0)
            shutil.copyfileobj(self._spool, fh)
            fh.write("\n ]\n}\n")

    def close(self) -> None:
        self._spool.close()


def _load_step(text: str) -> tuple[float, ...]:
    """'T:FRACTION' -> (T [s], fraction), 'T:FRACTION:RPM' -> a speed step too (a dyno engine); a clear one-line
    error on anything else (the range is the simulator's)."""
    parts = text.split(":")
    try:
        if len(parts) not in (2, 3):
            raise ValueError
        return tuple(float(x) for x in parts)
    except ValueError:
        raise ValueError(f"--load-step {text!r}: expected T:FRACTION[:RPM], e.g. 2.5:0.45 (seconds, fraction of full "
                         "load)") from None


def run(args: argparse.Namespace) -> int:
    spec = load_engine(args.engine)
    lo, hi = spec.speed_range_rpm
    if not lo <= args.rpm <= hi:
        raise ValueError(f"--rpm {args.rpm:g} is outside {spec.name}'s speed range {lo:g}..{hi:g} rpm")
    if not 0.0 <= args.load <= 1.1:
        raise ValueError(f"--load {args.load:g} must be a fraction of full load in 0..1.1")
    if not 1 <= args.cycles <= 100_000:
        raise ValueError(f"--cycles {args.cycles} must be 1..100000")
    if args.seed < 0:
        raise ValueError(f"--seed {args.seed} must be >= 0")
    effects = [parse_effect(text) for text in args.effect]  # several instances allowed (ring_wear in 1 and 2)
    kwargs = {} if args.cov_imep is None else {"cov_imep": args.cov_imep}
    if args.load_step:
        kwargs["load_steps"] = [_load_step(text) for text in args.load_step]
    log_path, truth_file = args.output, truth_path(args.output)
    for path in (truth_file, log_path):  # before the run, not after it
        check_output_path(path)
    sim = start_simulation(spec, args.rpm, args.load, args.cycles, args.seed, effects=effects,
                           without=set(args.without), second_wheel=args.second_wheel, **kwargs)
    try:
        with progress_bar(total=1.0, desc=f"simulate {spec.name}") as bar, \
                atomic_paths(truth_file, log_path) as (truth_tmp, log_tmp):
            truth = TruthSpool(log_path.parent)
            try:
                with LogWriter(log_tmp, spec.source_text, sim.info) as writer:
                    for chunk in sim.chunks(progress=bar.set_fraction):
                        for record in chunk.records:
                            writer.write(record)
                        truth.add(chunk.cycles)
                truth.write(truth_tmp, sim.truth)
            finally:
                truth.close()
    except OSError as exc:
        raise OSError(f"could not write {log_path} and {truth_file.name}, nothing was written: "
                      f"{exc.strerror or exc}") from exc
    print(f"wrote {log_path} and {truth_file.name}: {args.cycles} cycles, FMEP {sim.truth['fmep_bar']:.3f} bar")
    active = [e["name"] + (f" (cylinder {e['params']['cylinder']})" if "cylinder" in e["params"] else "")
              for e in sim.truth["effects"]]
    print("effects active: " + (", ".join(active) or "none"))
    return 0
