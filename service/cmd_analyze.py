"""`frictionwatch analyze LOG.mcap`: per-cylinder friction from a replay log (table, JSON, CSV, plots)."""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np
from frictionwatch.service import coastdown_report
from frictionwatch.service.pipeline import LogAnalysis, analyze_log
from frictionwatch.service.progress import progress_bar


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("analyze", help="analyse a replay log: per-cylinder losses")
    p.add_argument("log", type=Path, help="LOG.mcap")
    p.add_argument("--engine", help="engine preset, engine TOML, or model TOML (EngineModel.to_toml: its loss terms and "
                   "coefficients are what the monitor identifies); default: the spec stored in the log")
    p.add_argument("--json", action="store_true", help="print one JSON document instead of the table")
    p.add_argument("--csv", type=Path, metavar="OUT", help="write per-cycle, per-cylinder rows to OUT")
    p.add_argument("--plot", type=Path, metavar="DIR", help="write PNG plots to DIR")
    p.set_defaults(func=run)


def summary(analysis: LogAnalysis) -> dict:
    """The analysis as one JSON-able document; the keys match the simulator's truth file."""
    last = analysis.last
    doc: dict = {
        "engine": analysis.spec.name,
        "cycles_ok": analysis.cycles_ok,
        "cycles_skipped": dict(sorted(analysis.skipped.items())),
        "log_damage": dict(sorted(analysis.damage.items())),
        "data_gaps": data_gaps(analysis),
    }
    if last is not None:
        doc.update(last.to_json())
        # indicated quantities as means over the analysed cycles (the friction estimate is already accumulated)
        for k, cyl in enumerate(doc["cylinders"]):
            for key, values in (("imep_bar", [r.imep[k] for r in analysis.results]),
                                ("pmax_bar", [r.pmax[k] for r in analysis.results])):
                cyl[key] = float(np.mean(values)) / 1e5
        doc["imep_bar"] = float(np.mean([r.imep.mean() for r in analysis.results])) / 1e5
        doc["rpm"] = float(np.mean([r.rpm_mean for r in analysis.results]))
    return doc


def data_gaps(analysis: LogAnalysis) -> list[dict]:
    """Spans between consecutive analysed cycles longer than 1.5 cycles at the speed before them: cycles skipped,
    lost with a damaged part of the log (a cycle inside a lost chunk is not 'skipped', it never arrived), or an engine
    at rest. ``cycles``: how many cycle lengths fit in the span."""
    gaps = []
    for a, b in zip(analysis.results, analysis.results[1:]):
        cycle_s = 120.0 / a.rpm_mean
        if b.t_start - a.t_start > 1.5 * cycle_s:
            gaps.append({"after_cycle": a.index, "from_s": a.t_start + cycle_s, "to_s": b.t_start,
                         "cycles": round((b.t_start - a.t_start) / cycle_s - 1.0, 1)})
    return gaps


def run(args: argparse.Namespace) -> int:
    if not args.log.exists():
        raise FileNotFoundError(f"no such log: {args.log}")
    with progress_bar(total=0, desc=f"analyze {args.log.name}") as bar:
        analysis = analyze_log(args.log, args.engine, on_result=lambda r: bar.update(1))
    if not analysis.results:
        reasons = ", ".join(f"{k}: {v}" for k, v in analysis.skipped.most_common()) or "no complete cycle in the log"
        damage = ", ".join(f"{k}: {v}" for k, v in analysis.damage.most_common())
        print(f"frictionwatch analyze: error: no good cycle in {args.log.name} ({reasons}"
              + (f"; log damage {damage}" if damage else "") + ")", file=sys.stderr)
        return 2
    doc = summary(analysis)
    coastdown_report.add_to(doc, analysis)
    if args.csv:
        write_csv(analysis, args.csv)
    if args.plot:
        from frictionwatch.service.plots import write_plots

        write_plots(analysis, args.plot)
    if args.json:
        print(json.dumps(doc, indent=1))
    else:
        print_table(doc)
        coastdown_report.print_lines(doc)
    return 0


def print_table(doc: dict) -> None:
    print(f"{doc['engine']}: {doc['cycles_ok']} cycles analysed, skipped {sum(doc['cycles_skipped'].values())}"
          + (f" ({', '.join(f'{k} {v}' for k, v in doc['cycles_skipped'].items())})" if doc["cycles_skipped"] else ""))
    if doc["log_damage"]:
        print("log damage: " + ", ".join(f"{k} {v}" for k, v in doc["log_damage"].items()))
    if doc["data_gaps"]:
        print("not analysed: " + ", ".join(f"{g['from_s']:.3f}-{g['to_s']:.3f} s (~{g['cycles']:g} cycles)"
                                           for g in doc["data_gaps"]))
    print(f"speed {doc.get('rpm') or float('nan'):.1f} rpm, load {doc.get('load_torque_nm') or float('nan'):.1f} N m, "
          f"engine FMEP {_fmt(doc['fmep_bar'], '.3f')} ± {_fmt(doc.get('fmep_sigma_bar'), '.3f')} bar")
    print(f"{'cyl':>4} {'IMEP bar':>9} {'Pmax bar':>9} {'@ degCA':>8} {'friction N m':>13} {'± 1σ':>7} {'FMEP bar':>9}")
    shared = False
    for c in doc["cylinders"]:
        fric, sigma, fmep = c["friction_torque_mean_nm"], c.get("friction_torque_sigma_nm"), c["fmep_bar"]
        if fric is None:  # not resolved by the data: show the Eq. 6 share, marked, never as a measurement
            prior = c.get("prior_friction_torque_mean_nm")
            fric_txt, sigma_txt, fmep_txt = ("n/a" if prior is None else f"{prior:.2f}*"), "", ""
            shared = True
        else:
            fric_txt, sigma_txt = f"{fric:.2f}", ("" if sigma is None else f"{sigma:.2f}")
            fmep_txt = "" if fmep is None else f"{fmep:.3f}"
        print(f"{c['cylinder']:>4} {_fmt(c['imep_bar'], '.3f'):>9} {c.get('pmax_bar') or float('nan'):>9.1f} "
              f"{c.get('pmax_angle_deg') or float('nan'):>8.1f} {fric_txt:>13} {sigma_txt:>7} {fmep_txt:>9}")
    if shared:
        print("* not resolved from the speed data yet: the cylinder's share of the engine's friction in proportion to"
              " its indicated work (paper 000 Eq. 6), not a per-cylinder measurement")


def write_csv(analysis: LogAnalysis, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["cycle", "t_start_s", "rpm", "cylinder", "imep_bar", "pmax_bar", "friction_torque_mean_nm",
                    "fmep_bar"])
        for r in analysis.results:
            d = r.to_json(smoothed=False)
            for c in d["cylinders"]:
                w.writerow([d["cycle"], d["t_start_s"], d["rpm"], c["cylinder"], c["imep_bar"], c.get("pmax_bar"),
                            c["friction_torque_mean_nm"], c["fmep_bar"]])


def _fmt(x: float | None, spec: str) -> str:
    return "n/a" if x is None else format(x, spec)
