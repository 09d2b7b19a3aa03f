"""`frictionwatch import-daq FILE --engine E --tdc-deg A (--gain-bar-per-v G | --self-calibrate) -o OUT.mcap`: raw DAQ
voltage table (wheel + one pressure channel) -> replay log.

Nothing about the rig is assumed: the engine, the TDC angle and the sensor gain are stated by the user (they differ
from rig to rig and cannot be read from the file). The wheel is read from the file (teeth per revolution and the gap,
drivers.daq.teeth.wheel_pattern) and said; a --wheel that does not match it is refused, and so is an engine whose
cylinder count differs from the file's pressure channels (the monitor needs every cylinder's pressure).
The log is written whole or not at all (a temporary beside OUT renamed into place, service.output_files), and an
unwritable OUT is refused before the table is read.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from frictionwatch.core.model.engine import load_engine
from frictionwatch.drivers.daq.raw import read_daq_table, trace_to_records, trace_wheel
from frictionwatch.drivers.logs.mcap_log import LogWriter
from frictionwatch.service.output_files import atomic_path, check_output_path

PRESSURE_CHANNELS = 1  # a DAQ table holds time, wheel and one pressure column (drivers/daq/raw.py)
NOT_A_DAQ_TABLE = {".csv": "a crank-angle pressure table", ".xlsx": "a spreadsheet", ".mf4": "an MDF4 bus log"}


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import-daq", help="convert a raw DAQ table (crank-wheel and pressure volts) to a replay log")
    p.add_argument("file", type=Path, help="whitespace-separated table: time [s], wheel [V], pressure [V]; optionally .gz")
    p.add_argument("--engine", required=True, help="engine preset or TOML file stored in the log (TU/e: tue-4gb10)")
    p.add_argument("--wheel", default=None,
                   help="crank wheel as TEETH-MISSING, e.g. 60-2; default: read from the file (and printed)")
    p.add_argument("--tdc-deg", type=float, required=True,
                   help="crank angle of cylinder-1 firing TDC after the first tooth past the gap [deg] (TU/e group14: "
                        "244.5)")
    gain = p.add_mutually_exclusive_group(required=True)
    gain.add_argument("--gain-bar-per-v", type=float, default=None,
                      help="pressure sensor gain [bar/V] (TU/e group14: 12.4)")
    gain.add_argument("--self-calibrate", action="store_true",
                      help="fit the gain per cycle from p(intake BDC) = --peg-bar (wide-open throttle only)")
    p.add_argument("--peg", choices=("polytropic", "bdc"), default="polytropic", help="pressure pegging method")
    p.add_argument("--peg-bar", type=float, default=1.0, help="intake-BDC pressure for --peg bdc [bar]")
    p.add_argument("--n-poly", type=float, default=1.32, help="compression polytropic exponent for pegging")
    p.add_argument("-o", "--output", required=True, type=Path)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not args.file.exists():
        raise FileNotFoundError(f"no such file: {args.file}")
    kind = NOT_A_DAQ_TABLE.get(args.file.suffix.lower())
    if kind:
        raise ValueError(f"{args.file.name} looks like {kind}, not a DAQ voltage table; "
                         f"read it with `frictionwatch trace {args.file.name} --engine ENGINE`")
    spec = load_engine(args.engine)
    if spec.n_cyl != PRESSURE_CHANNELS:
        raise ValueError(f"--engine {args.engine} has {spec.n_cyl} cylinders but the file has {PRESSURE_CHANNELS} "
                         "pressure channel; the monitor needs the pressure of every cylinder")
    if args.gain_bar_per_v is not None and not args.gain_bar_per_v > 0:
        raise ValueError(f"--gain-bar-per-v {args.gain_bar_per_v:g} must be > 0")
    if not 0.0 <= args.tdc_deg < 720.0:
        raise ValueError(f"--tdc-deg {args.tdc_deg:g} must be in [0, 720) deg after the first tooth past the gap")
    if not args.peg_bar > 0 or not 1.0 < args.n_poly < 1.7:
        raise ValueError(f"--peg-bar {args.peg_bar:g} must be > 0 and --n-poly {args.n_poly:g} in (1, 1.7)")
    check_output_path(args.output)  # before reading and converting the table, not after
    trace = read_daq_table(args.file)
    wheel, seen = trace_wheel(trace, args.wheel)
    if args.wheel is None:
        print(f"wheel {wheel}, read from the file: {seen}")
    engine_wheel = f"{spec.sensors.wheel_teeth}-{spec.sensors.wheel_missing}"
    if wheel != engine_wheel:  # the monitor fits the teeth of the engine's wheel to the log's edges
        raise ValueError(f"--engine {args.engine} has a {engine_wheel} wheel but the file's is {wheel}")
    options: dict = {"peg": args.peg, "peg_pa": args.peg_bar * 1e5, "n_poly": args.n_poly, "tdc_deg": args.tdc_deg,
                     "gain_pa_per_v": None if args.self_calibrate else args.gain_bar_per_v * 1e5}
    info, records = trace_to_records(trace, wheel, engine=spec, **options)
    try:
        with atomic_path(args.output) as tmp, LogWriter(tmp, spec.source_text, info) as writer:
            for record in records:
                writer.write(record)
    except OSError as exc:  # a full disk, a vanished folder: the temporary is gone, the target untouched
        raise OSError(f"could not write {args.output}, nothing was written: {exc.strerror or exc}") from exc
    print(f"wrote {args.output}: {len(records)} records")
    return 0
