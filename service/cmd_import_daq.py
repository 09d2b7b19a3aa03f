"""`frictionwatch import-daq FILE -o OUT.mcap`: raw DAQ voltage table (wheel + pressure) -> replay log.

The log is written whole or not at all (a temporary beside OUT renamed into place, service.output_files), and an
unwritable OUT is refused before the table is read."""

from __future__ import annotations

import argparse
from pathlib import Path

from frictionwatch.core.model.engine import load_engine
from frictionwatch.drivers.daq.raw import daq_to_records
from frictionwatch.drivers.logs.mcap_log import LogWriter
from frictionwatch.service.output_files import atomic_path, check_output_path


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import-daq", help="convert a raw DAQ table (crank-wheel and pressure volts) to a replay log")
    p.add_argument("file", type=Path, help="tab-separated table, optionally .gz")
    p.add_argument("--engine", default="tue-4gb10", help="engine preset or TOML file stored in the log")
    p.add_argument("--wheel", default="60-2", help="crank wheel as TEETH-MISSING, e.g. 60-2")
    p.add_argument("--tdc-deg", type=float, default=None,
                   help="crank angle of cylinder-1 firing TDC after the first tooth past the gap [deg] (TU/e: 244.5)")
    p.add_argument("--gain-bar-per-v", type=float, default=None,
                   help="pressure sensor gain [bar/V] (TU/e: 12.4); with --self-calibrate it is fitted per cycle")
    p.add_argument("--self-calibrate", action="store_true", help="fit the gain from the compression stroke")
    p.add_argument("--peg", choices=("polytropic", "bdc"), default="polytropic", help="pressure pegging method")
    p.add_argument("--peg-bar", type=float, default=1.0, help="intake-BDC pressure for --peg bdc [bar]")
    p.add_argument("--n-poly", type=float, default=1.32, help="compression polytropic exponent for pegging")
    p.add_argument("-o", "--output", required=True, type=Path)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not args.file.exists():
        raise FileNotFoundError(f"no such file: {args.file}")
    spec = load_engine(args.engine)
    options: dict = {"peg": args.peg, "peg_pa": args.peg_bar * 1e5, "n_poly": args.n_poly}
    if args.tdc_deg is not None:
        options["tdc_deg"] = args.tdc_deg
    if args.self_calibrate:
        options["gain_pa_per_v"] = None
    elif args.gain_bar_per_v is not None:
        options["gain_pa_per_v"] = args.gain_bar_per_v * 1e5
    check_output_path(args.output)  # before reading and converting the table, not after
    info, records = daq_to_records(args.file, wheel=args.wheel, engine=spec, **options)
    try:
        with atomic_path(args.output) as tmp, LogWriter(tmp, spec.source_text, info) as writer:
            for record in records:
                writer.write(record)
    except OSError as exc:  # a full disk, a vanished folder: the temporary is gone, the target untouched
        raise OSError(f"could not write {args.output}, nothing was written: {exc.strerror or exc}") from exc
    print(f"wrote {args.output}: {len(records)} records")
    return 0
