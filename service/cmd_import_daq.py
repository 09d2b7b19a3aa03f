"""`frictionwatch import-daq FILE --engine E [--tdc-deg A] (--gain-bar-per-v G | --self-calibrate) -o OUT.mcap`: raw
DAQ voltage table (wheel + one pressure channel) -> replay log.

Nothing about the rig is assumed: the engine and the sensor gain are stated by the user. The wheel is read from the
file (teeth per revolution and the gap, drivers.daq.teeth.wheel_pattern) and said; a --wheel that does not match it
is refused, and so is an engine whose cylinder count differs from the file's pressure channels (the monitor needs
every cylinder's pressure).

TDC (issue 25): found from the file's own pressure (service.daq_tdc: the ROHR fit of core.monitor.calibration.tdc,
motored cycles preferred) and printed with its 1 sigma and method. Without --tdc-deg that TDC is used, unless its
sigma exceeds ``MAX_FOUND_SIGMA_DEG`` (then the user must state it). A stated --tdc-deg more than 0.3 deg from the
data's is a one-line warning with both values; one the data contradict grossly (beyond daq_tdc.REFUSE_DEG and
REFUSE_SIGMAS of its sigma, e.g. 15 deg off on a motored file) is refused, exit code 2, nothing written. So is a file
whose every cycle the calibration refuses.

--self-calibrate (p at intake BDC = --peg-bar) prints the gain it chose, and is refused on a throttled file (the
exhaust stroke far above the intake stroke: daq_tdc.pumping_ratio), warned where the two differ less.

The log is written whole or not at all (a temporary beside OUT renamed into place, service.output_files), and an
unwritable OUT is refused before the table is read.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from frictionwatch.core.model.engine import load_engine
from frictionwatch.drivers.daq.raw import process_daq, read_daq_table, result_to_records, trace_wheel
from frictionwatch.drivers.logs.mcap_log import LogWriter
from frictionwatch.service.daq_tdc import REFUSE_DEG, REFUSE_SIGMAS, THROTTLED_RATIO, WARN_DEG, find_tdc, pumping_ratio
from frictionwatch.service.output_files import atomic_path, check_output_path

PRESSURE_CHANNELS = 1  # a DAQ table holds time, wheel and one pressure column (drivers/daq/raw.py)
MAX_FOUND_SIGMA_DEG = 1.0  # a TDC found from the pressure less certain than this is not used without --tdc-deg
# exhaust / intake mid-stroke pressure from which --self-calibrate warns (THROTTLED_RATIO: refuses); the TU/e
# motored coast-downs read 1.10-1.16 (ENGINEOFF2 at 2600 rpm 1.57), its fired files 2.3-3.4
SELF_CALIBRATE_WARN_RATIO = 1.25
NOT_A_DAQ_TABLE = {".csv": "a crank-angle pressure table", ".xlsx": "a spreadsheet", ".mf4": "an MDF4 bus log"}


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import-daq", help="convert a raw DAQ table (crank-wheel and pressure volts) to a replay log")
    p.add_argument("file", type=Path, help="whitespace-separated table: time [s], wheel [V], pressure [V]; optionally .gz")
    p.add_argument("--engine", required=True, help="engine preset or TOML file stored in the log (TU/e: tue-4gb10)")
    p.add_argument("--wheel", default=None,
                   help="crank wheel as TEETH-MISSING, e.g. 60-2; default: read from the file (and printed)")
    p.add_argument("--tdc-deg", type=float, default=None,
                   help="crank angle of cylinder-1 firing TDC after the first tooth past the gap [deg] (TU/e group14: "
                        "244.5); default: found from the file's pressure and printed with its 1 sigma")
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
    if args.tdc_deg is not None and not 0.0 <= args.tdc_deg < 720.0:
        raise ValueError(f"--tdc-deg {args.tdc_deg:g} must be in [0, 720) deg after the first tooth past the gap")
    if not args.peg_bar > 0 or not 1.0 < args.n_poly < 1.7:
        raise ValueError(f"--peg-bar {args.peg_bar:g} must be > 0 and --n-poly {args.n_poly:g} in (1, 1.7)")
    check_output_path(args.output)  # before reading and converting the table, not after
    trace = read_daq_table(args.file)
    for note in trace.notes:
        print(f"{args.file.name}: {note}")
    wheel, seen = trace_wheel(trace, args.wheel)
    if args.wheel is None:
        print(f"wheel {wheel}, read from the file: {seen}")
    engine_wheel = f"{spec.sensors.wheel_teeth}-{spec.sensors.wheel_missing}"
    if wheel != engine_wheel:  # the monitor fits the teeth of the engine's wheel to the log's edges
        raise ValueError(f"--engine {args.engine} has a {engine_wheel} wheel but the file's is {wheel}")
    options: dict = {"peg": args.peg, "peg_pa": args.peg_bar * 1e5, "n_poly": args.n_poly,
                     "gain_pa_per_v": None if args.self_calibrate else args.gain_bar_per_v * 1e5}
    tdc_deg = choose_tdc(trace, spec, wheel, args.tdc_deg, options)
    res = process_daq(trace, spec, wheel=wheel, tdc_deg=tdc_deg, **options)
    if not res.calibrations:
        raise ValueError(f"{args.file.name}: every cycle was refused at TDC {tdc_deg:g} deg ({dict(res.damage)}); "
                         "nothing written")
    if args.self_calibrate:
        check_self_calibration(res, args.peg_bar)
    info, records = result_to_records(res, wheel)
    try:
        with atomic_path(args.output) as tmp, LogWriter(tmp, spec.source_text, info) as writer:
            for record in records:
                writer.write(record)
    except OSError as exc:  # a full disk, a vanished folder: the temporary is gone, the target untouched
        raise OSError(f"could not write {args.output}, nothing was written: {exc.strerror or exc}") from exc
    print(f"wrote {args.output}: {len(records)} records")
    return 0


def choose_tdc(trace, spec, wheel: str, stated: float | None, options: dict) -> float:
    """The TDC to import at: the stated one, checked against the pressure's (warned or refused), or the pressure's."""
    try:
        found, why = find_tdc(trace, spec, wheel, stated, **options)
    except ValueError as exc:  # the pressure does not allow the fit (too few cycles, no combustion window ...)
        found, why = None, str(exc)
    if stated is None:
        if found is None:
            raise ValueError(f"{trace.name}: TDC could not be found from the pressure ({why}); state it with --tdc-deg")
        if found.sigma_deg > MAX_FOUND_SIGMA_DEG:
            raise ValueError(f"{trace.name}: {found.describe()}: more uncertain than {MAX_FOUND_SIGMA_DEG:g} deg, "
                             "state it with --tdc-deg")
        print(found.describe())
        return round(found.tdc_deg, 3)
    if found is None:
        print(f"TDC {stated:g} deg as stated; not checked against the pressure: {why}")
        return stated
    diff = (stated - found.tdc_deg + 180.0) % 360.0 - 180.0
    both = (f"--tdc-deg {stated:g} against {found.tdc_deg:.2f} +- {found.sigma_deg:.2f} deg (1 sigma, "
            f"{found.method}, {found.estimate.n_cycles} cycles) from the pressure: {diff:+.2f} deg")
    if abs(diff) > max(REFUSE_DEG, REFUSE_SIGMAS * found.sigma_deg):
        raise ValueError(f"{trace.name}: {both}, which the pressure contradicts; nothing written")
    if abs(diff) > WARN_DEG:
        print(f"warning: {both}")
    else:
        print(f"{both}: agrees")
    return stated


def check_self_calibration(res, peg_bar: float) -> None:
    """Print the gain --self-calibrate chose; refuse it on a throttled file, warn where the pumping loop says the
    intake pressure was below the exhaust's (service.daq_tdc.pumping_ratio)."""
    gain_bar = res.calibrations[0].gain_pa_per_v / 1e5
    ratio = pumping_ratio(res)
    print(f"--self-calibrate: gain {gain_bar:.2f} bar/V from p(intake BDC) = {peg_bar:g} bar (median of "
          f"{len(res.calibrations)} cycles); exhaust / intake stroke pressure {ratio:.2f}")
    if ratio > THROTTLED_RATIO:
        raise ValueError(f"--self-calibrate assumes p(intake BDC) = {peg_bar:g} bar, but the exhaust stroke reads "
                         f"{ratio:.2f}x the intake stroke: the engine was throttled and the gain {gain_bar:.2f} bar/V "
                         "is too high by about that factor; state --gain-bar-per-v; nothing written")
    if ratio > SELF_CALIBRATE_WARN_RATIO:
        print(f"warning: --self-calibrate: the exhaust stroke reads {ratio:.2f}x the intake stroke; p(intake BDC) "
              f"may be below {peg_bar:g} bar and the gain {gain_bar:.2f} bar/V too high")
