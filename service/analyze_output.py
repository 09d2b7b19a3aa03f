"""What `frictionwatch analyze` prints and writes besides the JSON document: the table (from the document, so both
say the same) and the per-cycle CSV (docs/results.md describes both)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from frictionwatch.core.monitor.report.figure_status import split_flag
from frictionwatch.core.monitor.report.run_summary import estimate_window, flag_kinds, smoothed_mean_and_sigma
from frictionwatch.service.output_files import atomic_output
from frictionwatch.service.pipeline import LogAnalysis

STATUS_WORDS = {
    "measured": "measured",
    "share": "share, not measured",
    "prior": "prior, not measured",
    "unresolved": "not known from the data",
    "withheld": "withheld (sensor fault)",
}
FIGURE_KEYS = ("friction_torque_mean_nm", "friction_torque_sigma_nm", "fmep_bar", "fmep_sigma_bar")


# ---- the table ---------------------------------------------------------------------------------------------------

def print_table(doc: dict) -> None:
    """The document (cmd_analyze.summary) as a table for a person: every figure with its 1-sigma and what it is."""
    skipped = doc["cycles_skipped"]
    print(f"{doc['engine']}: {doc['cycles_ok']} cycles analysed (cycles {doc.get('first_cycle')}-"
          f"{doc.get('last_cycle')}), skipped {sum(skipped.values())}"
          + (f" ({', '.join(f'{k} {v}' for k, v in skipped.items())})" if skipped else ""))
    if doc["log_damage"]:
        print("log damage: " + ", ".join(f"{k} {v}" for k, v in doc["log_damage"].items()))
    for c in doc.get("implausible") or []:
        print(f"NOT PHYSICAL / NOT SUPPORTED ({c['check']}): {c['reason']}")
    holes = doc.get("dropped_while_behind") or []
    if holes:  # a live session's recording: what it dropped while behind, as its stop line said it
        print(f"dropped while the live analysis was behind (as recorded): {len(holes)} hole"
              f"{'s' if len(holes) > 1 else ''}, ~{sum(h['dropped_cycles'] for h in holes):.0f} cycles, "
              f"{sum(h['dropped_s'] or 0.0 for h in holes):.1f} s of acquisition "
              f"({sum(h['dropped_records'] for h in holes)} records)")
    if doc["data_gaps"]:
        print("not analysed: " + ", ".join(f"{g['from_s']:.3f}-{g['to_s']:.3f} s (~{g['cycles']:g} cycles"
                                           + (f", {g['cause'].replace('_', ' ')}" if g.get("cause") else "") + ")"
                                           for g in doc["data_gaps"]))
    seams = (doc.get("restarts") or {}).get("loop_restart", 0)
    if seams:
        print(f"{seams} loop seam{'s' if seams > 1 else ''} of a replay (restarts, nothing lost)")
    load = ("load not measured" if doc.get("load_torque_mean_nm") is None else
            f"load {doc['load_torque_mean_nm']:.1f} N·m = {_fmt(doc.get('load_power_mean_kw'), '.2f')} kW")
    print(f"run means (measured): speed {_fmt(doc.get('rpm_mean'), '.1f')} rpm, {load}, "
          f"IMEP {_fmt(doc.get('imep_bar'), '.3f')} bar")
    regimes = doc.get("regimes") or []
    if len(regimes) > 1 or any(g["regime"] == "motored" for g in regimes):
        for g in regimes:
            f = g["friction"]
            cov = "" if g["imep_cov"] is None else f", COV {100 * g['imep_cov']:.1f} %"
            print(f"  {g['regime']}: {g['cycles']} cycles ({g['first_cycle']}-{g['last_cycle']}), IMEP "
                  f"{_pm(g['imep_bar'], g['imep_sigma_bar'], '.3f')} bar{cov}, misfire in {g['misfire_cycles']}; "
                  f"friction " + (f"{_pm(f['friction_torque_mean_nm'], f['friction_torque_sigma_nm'], '.2f')} N·m, "
                                  f"FMEP {_pm(f['fmep_bar'], f['fmep_sigma_bar'], '.3f')} bar (mean torque balance)"
                                  if f["status"] == "measured" else f"{f['status']} ({f['reason']})"))
    fr = doc["friction"]
    w = fr["window"]
    print(f"engine friction, {_window_words(w)}:")
    print(f"  FMEP {_pm(fr['fmep_bar'], fr['fmep_sigma_bar'], '.3f')} bar, friction torque "
          f"{_pm(fr['friction_torque_mean_nm'], fr['friction_torque_sigma_nm'], '.2f')} N·m: "
          f"{STATUS_WORDS[fr['status']]}" + (f" ({fr['reason']})" if fr["reason"] else
                                             " (mean torque balance against the measured load)"))
    if fr.get("calibration_sigma_nm") is not None:
        print(f"  of that 1σ, {fr['calibration_sigma_nm']:.2f} N·m is the calibration's: "
              + ("uncalibrated, a typical installation's TDC ±0.5° (±0.2° per cylinder), pressure gain ±3 % per "
                 "channel and ±1 % common, J ±5 %, the load ±0.5 % (±3 % read as electrical power) assumed; "
                 "`frictionwatch commission` measures TDC, gain and J"
                 if fr["calibration"] == "uncalibrated" else "as commissioned (with the load's σ as the model states)"))
    tdc = doc.get("tdc_from_pressure")
    if tdc and tdc["wheel_offset_deg"] is not None:
        print(f"  TDC from the pressure (newest window): the wheel {tdc['wheel_offset_deg']:+.2f} ± "
              f"{tdc['wheel_sigma_deg']:.2f}° from the model's (+ = the true TDC later)"
              + (f"; flagged: {', '.join(tdc['flags'])} (`frictionwatch commission` measures TDC)" if tdc["flags"]
                 else ""))
    rb = doc["friction_run_mean_balance"]
    if rb["status"] == "measured":
        print(f"  mean over the whole run of each cycle's torque balance: FMEP "
              f"{_pm(rb['fmep_bar'], rb['fmep_sigma_bar'], '.3f')} bar ({rb['window']['effective_cycles']:.0f} "
              "cycles, measured" + (f"; {rb['reason']}" if rb["reason"] else "") + ")")
    print(f"{'cyl':>4} {'IMEP bar':>9} {'± 1σ':>6} {'Pmax bar':>9} {'at °CA':>7} {'friction N·m':>13} {'± 1σ':>6} "
          f"{'FMEP bar':>9} {'share N·m':>10} {'data wt':>8}  what it is")
    notes = {}
    for c in doc["cylinders"]:
        f = c["friction"]
        # only a measurement goes in the friction columns: a share beside measured values would read as a
        # per-cylinder ranking (a worn cylinder with less indicated work gets a smaller share)
        fric, sig, fmep = (_fmt(c[k], spec, "-") for k, spec in (("friction_torque_mean_nm", ".2f"),
                                                                  ("friction_torque_sigma_nm", ".2f"),
                                                                  ("fmep_bar", ".3f")))
        print(f"{c['cylinder']:>4} {_fmt(c['imep_bar'], '.3f'):>9} {_fmt(c.get('imep_sigma_bar'), '.3f', ''):>6} "
              f"{_fmt(c.get('pmax_bar_mean'), '.1f'):>9} {_fmt(c.get('pmax_angle_deg_mean'), '.1f'):>7} "
              f"{fric:>13} {sig:>6} {fmep:>9} "
              f"{_fmt(c.get('share_friction_torque_mean_nm'), '.2f', '-'):>10} {_fmt(f['data_weight'], '.2f', '-'):>8}"
              f"  {STATUS_WORDS[f['status']]}")
        if f["status"] != "measured" and f["reason"]:
            notes.setdefault((f["status"], f["reason"].split(" (data weight")[0]), []).append(c["cylinder"])
    print("± is 1σ, the standard uncertainty: of the friction estimate (statistical, modelled systematic and "
          "calibration parts); "
          "of the run mean for IMEP (from the cycle-to-cycle scatter).")
    print("friction and FMEP columns: measurements only. share: the cylinder's part of the engine's measured friction "
          "in proportion to its indicated work, what a cylinder like its siblings would carry, not a measurement of "
          "the cylinder (never a ranking); data wt: the part of what is known about the cylinder's friction that came "
          "from the speed signal (0..1).")
    for (status, reason), cyls in notes.items():
        print(f"cylinders {', '.join(map(str, cyls))} {STATUS_WORDS[status]}: {reason}")
    _print_flags(doc)


def _print_flags(doc: dict) -> None:
    flags = doc["flags"]
    active = set(doc.get("active_flags", ()))
    if not flags["run"]:
        print("flags: none")
        return
    print(f"flags ({doc['cycles_ok']} cycles; * = applies to the figures above):")
    for flag, n in flags["run"].items():
        cycles = flags["cycles"][flag]
        print(f"  {'*' if flag in active else ' '} {flag}: {n} cycles (first {cycles[0]}, last {cycles[-1]})")


def _window_words(w: dict) -> str:
    if w.get("first_cycle") is None:
        return f"at cycle {w['last_cycle']}, nothing accumulated from the data yet"
    forget = w.get("forgetting")
    how = "all weighted equally" if forget is None or forget >= 1.0 else \
        f"older cycles weighted down by {forget:.4f} per cycle"
    return (f"end-of-run estimate over cycles {w['first_cycle']}-{w['last_cycle']} ({how}: "
            f"{w['effective_cycles']:.0f} effective cycles centred on cycle {w['centre_cycle']:.0f})")


def _pm(x: float | None, s: float | None, spec: str) -> str:
    return "n/a" if x is None else format(x, spec) + ("" if s is None else f" ± {format(s, spec)}")


def _fmt(x: float | None, spec: str, missing: str = "n/a") -> str:
    return missing if x is None else format(x, spec)


# ---- the CSV -----------------------------------------------------------------------------------------------------

def csv_columns(kinds: list[str]) -> list[str]:
    return (["cycle", "t_start_s", "rpm", "load_torque_nm", "load_power_kw", "cylinder",
             "imep_bar", "imep_smoothed_bar", "imep_smoothed_sigma_bar",
             "pmax_bar", "pmax_smoothed_bar", "pmax_smoothed_sigma_bar", "pmax_angle_deg",
             "cycle_friction_torque_nm", "cycle_friction_sigma_nm", "cycle_fmep_bar", "cycle_fmep_sigma_bar",
             "cycle_friction_status",
             "friction_torque_mean_nm", "friction_torque_sigma_nm", "fmep_bar", "fmep_sigma_bar", "friction_status",
             "friction_data_weight", "share_friction_torque_mean_nm", "effective_cycles",
             "engine_friction_torque_nm", "engine_friction_sigma_nm", "engine_fmep_bar", "engine_fmep_sigma_bar",
             "engine_friction_status", "engine_friction_balance_nm"]
            + [f"flag_{k}" for k in kinds])


def write_csv(analysis: LogAnalysis, path: Path) -> None:
    """One row per cycle and cylinder (docs/results.md): this cycle's values and estimate, the smoothed ones, with
    1-sigma, status and one 0/1 column per flag kind raised in the run; written whole or not at all."""
    results = analysis.results
    flags = [r.flags for r in results]
    kinds = flag_kinds(flags)
    lam = estimate_window([r.index for r in results], [r.smoothed.weight for r in results]).forgetting
    imep_s, imep_sig = smoothed_mean_and_sigma(np.array([r.imep for r in results]) / 1e5, lam)
    pmax_s, pmax_sig = smoothed_mean_and_sigma(np.array([r.pmax for r in results]) / 1e5, lam)
    with atomic_output(path) as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(csv_columns(kinds))
        for i, r in enumerate(results):
            smooth = r.to_json()  # status from this cycle's flags
            own = r.to_json(smoothed=False)
            raised = [split_flag(f) for f in r.flags]
            eng = smooth["friction"]
            for k, (c, oc) in enumerate(zip(smooth["cylinders"], own["cylinders"])):
                f, of = c["friction"], oc["friction"]
                mine = {kind for kind, cyl in raised if cyl is None or cyl == k + 1}
                w.writerow([r.index, _c(r.t_start), _c(r.rpm_mean), _c(r.load_torque), _c(r.load_power / 1e3), k + 1,
                            _c(c["imep_bar"]), _c(imep_s[i, k]), _c(imep_sig[i, k]),
                            _c(c["pmax_bar"]), _c(pmax_s[i, k]), _c(pmax_sig[i, k]), _c(c["pmax_angle_deg"]),
                            *(_c(of[key]) for key in FIGURE_KEYS), of["status"],
                            *(_c(f[key]) for key in FIGURE_KEYS), f["status"], _c(f["data_weight"]),
                            _c(c["share_friction_torque_mean_nm"]), _c(f["window"]["effective_cycles"]),
                            *(_c(eng[key]) for key in FIGURE_KEYS), eng["status"], _c(r.friction_balance),
                            *(int(kind in mine) for kind in kinds)])


def _c(x: float | None) -> str:
    """A CSV cell: repr-exact float, empty for None / NaN."""
    if x is None:
        return ""
    v = float(x)
    return repr(v) if np.isfinite(v) else ""
