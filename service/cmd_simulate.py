"""`frictionwatch simulate`: run the time-domain plant simulator and write OUT.mcap plus OUT.truth.json."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from frictionwatch.core.model.effects import parse_effect
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.drivers.logs.mcap_log import LogWriter
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
    p.add_argument("-o", "--output", required=True, type=Path, help="OUT.mcap (truth goes to OUT.truth.json)")
    p.set_defaults(func=run)


def truth_path(log: Path) -> Path:
    return log.with_name(log.name.removesuffix(".mcap") + ".truth.json")


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
    with progress_bar(total=1.0, desc=f"simulate {spec.name}") as bar:
        result = simulate(
            spec, args.rpm, args.load, args.cycles, args.seed, effects=effects, without=set(args.without),
            progress=bar.set_fraction, **kwargs,
        )
    args.output.parent.mkdir(parents=True, exist_ok=True)
    with LogWriter(args.output, spec.source_text, result.info) as writer:
        for record in result.records:
            writer.write(record)
    truth_path(args.output).write_text(json.dumps(result.truth, indent=1))
    print(f"wrote {args.output} and {truth_path(args.output).name}: {args.cycles} cycles, FMEP {result.truth['fmep_bar']:.3f} bar")
    print("effects active: " + (", ".join(e["name"] + (f" (cylinder {e['params']['cylinder']})" if "cylinder" in e["params"] else "") for e in result.truth["effects"]) or "none"))
    return 0
