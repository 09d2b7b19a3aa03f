"""`frictionwatch analyze LOG.mcap`: per-cylinder friction from a replay log (table, JSON, CSV, plots).

The JSON document is described key by key in docs/results.md and by the JSON Schema
service/schema/analyze-result.schema.json (``SCHEMA_VERSION``); the CSV and the table show the same figures.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np
from frictionwatch.core.monitor.balance.mean_balance import LOAD_STEP_FRACTION
from frictionwatch.core.monitor.calibration.tdc_watch import TdcWatchState
from frictionwatch.core.monitor.checks.sensor_health import SensorHealthConfig
from frictionwatch.core.monitor.report.run_summary import end_of_run_status, flag_summary, mean_and_sem
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.service import coastdown_report
from frictionwatch.service.analyze_output import print_table, write_csv
from frictionwatch.service.output_files import check_output_path
from frictionwatch.service.pipeline import LogAnalysis, analyze_log
from frictionwatch.service.progress import log_extent, progress_bar

SCHEMA_VERSION = "2.2"  # major: a key renamed, removed or its meaning changed; minor: keys added
SCHEMA_FILE = Path(__file__).with_name("schema") / "analyze-result.schema.json"
LAST_CYCLE_KEYS = ("cycle", "t_start_s", "rpm", "load_torque_nm", "load_power_kw", "friction_balance_nm",
                   "coupling_loss_nm", "residual_rms_rad_s", "r_squared", "chi2_reduced", "flags")


SENSOR_HEALTH_HELP = (
    "switch on the speed-based sensor-health stage: each cylinder's TDC, pressure gain and pegging estimated from the "
    "flywheel speed and the compression stroke, flagged and corrected. Off by default because where the engine model "
    "is not the engine its TDC is not reliable (on the simulator a 1 deg wheel offset read 0.05 deg and a healthy "
    "engine's FMEP moved 7.8 %%: docs/design-notes.md item 13). The TDC found from each cylinder's pressure every 100 "
    "cycles (the TDC watch) is on with or without it")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("analyze", help="analyse a replay log: per-cylinder losses")
    p.add_argument("log", type=Path, help="LOG.mcap")
    p.add_argument("--engine", help="engine preset, engine TOML, or model TOML (EngineModel.to_toml: its loss terms and "
                   "coefficients are what the monitor identifies); default: the spec stored in the log")
    p.add_argument("--json", action="store_true", help="print one JSON document (docs/results.md) instead of the table")
    p.add_argument("--csv", type=Path, metavar="OUT", help="write per-cycle, per-cylinder rows to OUT")
    p.add_argument("--plot", type=Path, metavar="DIR", help="write PNG plots to DIR")
    p.add_argument("--sensor-health", action="store_true", help=SENSOR_HEALTH_HELP)
    p.set_defaults(func=run)


def monitor_config(sensor_health: bool) -> MonitorConfig:
    """The monitor's settings for ``--sensor-health`` (analyze, serve): the defaults, with the speed-based
    sensor-health stage (core.monitor.checks.sensor_health) on when asked for."""
    return MonitorConfig(sensor_health=SensorHealthConfig()) if sensor_health else MonitorConfig()


def document(analysis: LogAnalysis) -> dict:
    """What `analyze --json` prints (also what `reanalyze` writes per log): the summary with the coast-down block."""
    doc = summary(analysis)
    coastdown_report.add_to(doc, analysis)
    if analysis.results:
        doc["implausible"] = implausible(doc, analysis)
    return doc


def implausible(doc: dict, analysis: LogAnalysis) -> list[dict]:
    """Every physically impossible or unsupported result of the run, one line each (docs/results.md): cycles whose
    speed fit explains almost none of the speed ripple (flag ``speed_fit_poor``) and the transient block's checks."""
    out = []
    poor = [r.r_squared for r in analysis.results if "speed_fit_poor" in r.flags]
    if poor:
        n = len(analysis.results)
        out.append({"check": "speed_fit", "cycles": len(poor), "reason": (
            f"the speed model explains {100 * min(poor):.0f}-{100 * max(poor):.0f} % of the measured speed ripple in "
            f"{len(poor)} of {n} cycles (R² below {MonitorConfig().r_squared_floor:g}): what is read from the speed "
            "signal (the per-cylinder split, the ripple's harmonics) is not supported by it")})
    transient = doc.get("transient") or {}
    out += transient.get("checks", [])
    return out


def no_cycle_reason(analysis: LogAnalysis, name: str) -> str:
    """One line for a log with no analysed cycle: the skip reasons and the log damage."""
    reasons = ", ".join(f"{k}: {v}" for k, v in analysis.skipped.most_common()) or "no complete cycle in the log"
    damage = ", ".join(f"{k}: {v}" for k, v in analysis.damage.most_common())
    return f"no good cycle in {name} ({reasons}" + (f"; log damage {damage}" if damage else "") + ")"


def summary(analysis: LogAnalysis) -> dict:
    """The analysis as one JSON-able document (docs/results.md): run means of the measured quantities, the
    end-of-run friction estimate with the status, data weight and window of every figure, the mean balance over
    the run, the last cycle's values, and the flags per window."""
    doc: dict = {
        "schema_version": SCHEMA_VERSION,
        "engine": analysis.spec.name,
        "cycles_ok": analysis.cycles_ok,
        "cycles_skipped": dict(sorted(analysis.skipped.items())),
        "log_damage": dict(sorted(analysis.damage.items())),
        "data_gaps": data_gaps(analysis),
        "restarts": dict(sorted(analysis.restarts.items())),
        "dropped_while_behind": analysis.holes,
    }
    results = analysis.results
    if not results:
        return doc
    last = results[-1]
    flags = [r.flags for r in results]
    window, active, status = end_of_run_status(results)
    cyc = last.to_json(status=status, window=asdict(window))
    load = mean_and_sem([r.load_torque for r in results])
    power = mean_and_sem([r.load_power for r in results])
    doc.update({
        "first_cycle": int(results[0].index),
        "last_cycle": int(last.index),
        "rpm_mean": float(np.mean([r.rpm_mean for r in results])),
        "imep_bar": float(np.mean([r.imep.mean() for r in results])) / 1e5,
        "load_torque_mean_nm": _num(load[0]),
        "load_power_mean_kw": _num(power[0] / 1e3),
        "load_measured_cycles": load[2],
        "estimate": "smoothed",
        **{k: cyc[k] for k in ("friction_torque_mean_nm", "friction_torque_sigma_nm", "fmep_bar", "fmep_sigma_bar")},
        "friction": cyc["friction"],
        "friction_run_mean_balance": run_mean_balance(analysis, cyc["friction"]["status"]),
        "regimes": regimes(analysis, cyc["friction"]["status"]),
        "active_flags": sorted(active),
        "sensor_health": cyc["sensor_health"],
        "tdc_from_pressure": tdc_from_pressure(analysis),
        "last": {k: cyc[k] for k in LAST_CYCLE_KEYS},
        "flags": flag_summary([r.index for r in results], flags),
        "cylinders": _cylinders_run(cyc["cylinders"], analysis),
    })
    return doc


def tdc_from_pressure(analysis: LogAnalysis) -> dict | None:
    """The newest window of the TDC watch (core.monitor.calibration.tdc_watch): each cylinder's TDC found from its
    pressure against the one the model states (after its corrections) [deg], the wheel's (their median), and the
    flags it raised; None before a whole window (100 cycles)."""
    return None if analysis.tdc_watch is None else tdc_watch_document(analysis.tdc_watch)


def tdc_watch_document(watch: TdcWatchState) -> dict | None:
    """``tdc_from_pressure``'s block from the watch's state (the API's sensor-health shows the same); None before
    the watch's first whole window."""
    if watch.last is None:
        return None
    found = [e for e in watch.last if e is not None]
    cyl = [None if e is None else {"offset_deg": e.offset_deg, "sigma_deg": e.sigma_deg, "method": e.method}
           for e in watch.last]
    return {"wheel_offset_deg": float(np.median([e.offset_deg for e in found])) if found else None,
            "wheel_sigma_deg": float(np.median([e.sigma_deg for e in found])) if found else None,
            "flags": list(watch.flags), "cylinders": cyl}


def _cylinders_run(cylinders: list[dict], analysis: LogAnalysis) -> list[dict]:
    """The last cycle's cylinder documents with their indicated quantities as run means (the truth file's imep_bar
    and pmax_bar_mean), their 1-sigma (of the mean, from the cycle-to-cycle scatter) and scatter, over the cycles
    where the cylinder's own pressure was analysed (``pressure_cycles``): a flagged channel's stand-in (its
    siblings' mean, core.monitor.checks.pressure_trace) is NaN in ``pressure_figures`` and left out."""
    own = np.array([r.pressure_figures() for r in analysis.results])  # (cycles, 3, z)
    out = []
    for k, c in enumerate(cylinders):
        imep = mean_and_sem(own[:, 0, k] / 1e5)
        pmax = mean_and_sem(own[:, 1, k] / 1e5)
        doc = {key: v for key, v in c.items() if key not in ("imep_bar", "pmax_bar", "pmax_angle_deg")}
        doc.update({
            "imep_bar": _num(imep[0]), "imep_sigma_bar": _num(imep[1]),
            "imep_std_bar": _num(imep[1] * np.sqrt(imep[2])),
            "pmax_bar_mean": _num(pmax[0]), "pmax_sigma_bar": _num(pmax[1]),
            "pmax_std_bar": _num(pmax[1] * np.sqrt(pmax[2])),
            "pmax_angle_deg_mean": _num(np.degrees(mean_and_sem(own[:, 2, k])[0])),
            "pressure_cycles": imep[2],
        })
        out.append(doc)
    return out


def run_mean_balance(analysis: LogAnalysis, engine_status: str) -> dict:
    """The engine's friction as the mean over every analysed cycle of its mean torque balance (indicated - load -
    modelled coupling loss): the run's mean, where the smoothed estimate is the end of a forgetting window."""
    return balance_figure(analysis.results, engine_status)


def regimes(analysis: LogAnalysis, engine_status: str) -> list[dict]:
    """The run split by regime, each that occurs once: ``fired`` (some cylinder burned) and ``motored`` (no cylinder
    burned: the cycle's ``motored`` flag, core.monitor.checks.condition), each with its cycles, IMEP (mean over the
    cylinders, per cycle; run mean, its 1-sigma and the cycle-to-cycle scatter; COV for the fired regime), the
    cycles with a misfire flag and the friction as the mean of its cycles' torque balances (``balance_figure``)."""
    groups: dict[str, list] = {"fired": [], "motored": []}
    for r in analysis.results:
        groups["motored" if "motored" in r.flags else "fired"].append(r)
    out = []
    for name, rs in groups.items():
        if not rs:
            continue
        mean, sem, n = mean_and_sem([float(np.mean(r.imep)) / 1e5 for r in rs])
        std = sem * np.sqrt(n)
        out.append({
            "regime": name, "cycles": len(rs), "first_cycle": int(rs[0].index), "last_cycle": int(rs[-1].index),
            "imep_bar": _num(mean), "imep_sigma_bar": _num(sem), "imep_std_bar": _num(std),
            "imep_cov": _num(std / mean) if name == "fired" and mean > 0 else None,
            "misfire_cycles": sum(any(f.startswith("misfire_cyl") for f in r.flags) for r in rs),
            "friction": balance_figure(rs, engine_status),
        })
    return out


def balance_figure(results: list, engine_status: str) -> dict:
    """The mean of the cycles' torque balances over ``results`` as a figure (status, reason, window, torque and
    FMEP with the 1-sigma of the mean from their scatter)."""
    used = [r for r in results if np.isfinite(r.friction_balance)]
    mean, sem, n = mean_and_sem([r.friction_balance for r in used])
    mep = results[-1].mep_per_nm(engine=True) / 1e5  # bar per N m of the engine: 4 pi / V_d of all cylinders
    if engine_status == "withheld":
        status, reason = "withheld", "a sensor fault is flagged (see friction.reason)"
    elif n == 0 and not any(np.isfinite(r.load_torque) or np.isfinite(r.load_power) for r in results):
        status, reason = "unresolved", "no load measurement in any cycle: nothing balances the indicated work"
    elif n == 0:  # the load is measured, but no two consecutive cycles have it steady enough for their window
        status, reason = "unresolved", (
            f"the load changed by more than {LOAD_STEP_FRACTION:.0%} of the rated torque between every two "
            "consecutive cycles (or the cycle before was missing): no window's load is known, nothing balances")
    else:
        status = "measured"
        reason = None if n == len(results) else f"the load was measured in {n} of {len(results)} cycles"
    has = status == "measured"
    # the scatter's sem is all the cycles know of themselves; the calibration's error is the same in every cycle
    # and does not average down (the last estimate's calibration part: the same sensitivities)
    est = results[-1].smoothed
    cal = est.total_calibration_sigma
    sem = math.hypot(sem, cal) if math.isfinite(sem) else sem
    return {
        "calibration": est.calibration, "calibration_sigma_nm": _num(cal) if has else None,
        "status": status, "reason": reason, "data_weight": None,
        "window": {"first_cycle": int(used[0].index) if used else None, "last_cycle": int(results[-1].index),
                   "effective_cycles": float(n), "centre_cycle": _num(np.mean([r.index for r in used])) if used else
                   None, "forgetting": 1.0},
        "friction_torque_mean_nm": _num(mean) if has else None,
        "friction_torque_sigma_nm": _num(sem) if has else None,
        "fmep_bar": _num(mean * mep) if has else None,
        "fmep_sigma_bar": _num(sem * mep) if has else None,
    }


def data_gaps(analysis: LogAnalysis) -> list[dict]:
    """Spans between consecutive analysed cycles longer than 1.5 cycles at the speed before them: cycles skipped,
    lost with a damaged part of the log (a cycle inside a lost chunk is not 'skipped', it never arrived), or an engine
    at rest. ``cycles``: how many cycle lengths fit in the span. ``cause``: the restart reason of a hole the log
    records inside it (a live session's recording: ``dropped_while_behind``, the data dropped while its analysis was
    behind, not a gap in the engine's data), else None."""
    gaps = []
    holes = [(h["first_cycle"], h["reason"]) for h in analysis.holes if h["first_cycle"] is not None]
    for a, b in zip(analysis.results, analysis.results[1:]):
        cycle_s = 120.0 / a.rpm_mean
        if b.t_start - a.t_start > 1.5 * cycle_s:
            cause = next((why for first, why in holes if a.index < first <= b.index), None)
            gaps.append({"after_cycle": a.index, "from_s": a.t_start + cycle_s, "to_s": b.t_start,
                         "cycles": round((b.t_start - a.t_start) / cycle_s - 1.0, 1), "cause": cause})
    return gaps


def run(args: argparse.Namespace) -> int:
    if not args.log.exists():
        raise FileNotFoundError(f"no such log: {args.log}")
    if args.log.is_dir():  # `reanalyze` takes a folder of logs; analyze one log
        raise IsADirectoryError(f"{args.log} is a folder, not a log (`frictionwatch reanalyze` takes a folder)")
    if args.csv:
        check_output_path(args.csv)  # an unwritable output is found before the run, not after it
    if args.plot:
        if args.plot.exists() and not args.plot.is_dir():
            raise NotADirectoryError(f"--plot {args.plot} is a file, expected a folder")
        check_output_path(args.plot / "friction_torque_vs_angle.png")
    extent = log_extent(args.log)
    with progress_bar(total=1 if extent.known else 0, desc=f"analyze {args.log.name}",
                      estimated_total=extent.known) as bar:
        analysis = analyze_log(args.log, args.engine, on_result=lambda r: bar.advance(extent.fraction(r.t_start)),
                               config=monitor_config(args.sensor_health))
    if not analysis.results:
        print(f"frictionwatch analyze: error: {no_cycle_reason(analysis, args.log.name)}", file=sys.stderr)
        return 2
    doc = document(analysis)
    written: list[Path] = []
    if args.csv:
        write_csv(analysis, args.csv)
        written.append(args.csv)
    if args.plot:
        from frictionwatch.service.plots import write_plots

        written += write_plots(analysis, args.plot)
    if args.json:
        print(json.dumps(doc, indent=1))
    else:
        print_table(doc)
        coastdown_report.print_lines(doc)
    for path in written:  # on stderr with --json: stdout stays one JSON document
        print(f"wrote {path}", file=sys.stderr if args.json else sys.stdout)
    return 0


def _num(x: float) -> float | None:
    v = float(x)
    return v if np.isfinite(v) else None
