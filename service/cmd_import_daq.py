"""`frictionwatch import-daq FILE -o OUT.mcap`: raw DAQ voltage table (wheel + pressure) -> replay log."""

from __future__ import annotations

import argparse
from pathlib import Path

from core.engine import load_engine
from drivers.daq_raw import daq_to_records
from drivers.mcap_log import LogWriter


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import-daq", help="convert a raw DAQ table (crank-wheel and pressure volts) to a replay log")
    p.add_argument("file", type=Path, help="tab-separated table, optionally .gz")
    p.add_argument("--engine", default="tue-4gb10", help="engine preset or TOML file stored in the log")
    p.add_argument("--wheel", default="60-2", help="crank wheel as TEETH-MISSING, e.g. 60-2")
    p.add_argument("-o", "--output", required=True, type=Path)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not args.file.exists():
        raise FileNotFoundError(f"no such file: {args.file}")
    spec = load_engine(args.engine)
    info, records = daq_to_records(args.file, wheel=args.wheel)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    with LogWriter(args.output, spec.source_text, info) as writer:
        for record in records:
            writer.write(record)
    print(f"wrote {args.output}: {len(records)} records")
    return 0
