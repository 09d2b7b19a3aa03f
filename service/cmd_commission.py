"""`frictionwatch commission LOG.mcap... [--engine E] -o MODEL.toml`: measure what the monitor otherwise takes on
trust (issue 25 item 1) and write it into the engine model.

Each log runs through the product's pipeline (service.pipeline.analyze_records: assembler, model view, monitor),
which hands every assembled cycle to the commissioning as the monitor gets it. From the fired cycles (and motored
ones where a log has them): every cylinder's TDC and pegging from its pressure (core.monitor.calibration.tdc), each
channel's gain against its siblings (core.monitor.calibration.pressure_gain); the results become the model's sensor
effects and its calibration section (core.monitor.calibration.commission), which analyze, serve, reanalyze and
discrepancy read. The model is written whole or not at all; the report (table or --json) says every figure, its
1-sigma and where it came from.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.monitor.calibration.commission import (
    Commissioning,
    InertiaFinding,
    commissioned_drive_train,
    commissioned_model,
    tdc_used,
    without_sensor_effects,
)
from frictionwatch.core.monitor.calibration.drive_train import DriveTrainFit, identify_iteratively
from frictionwatch.core.monitor.calibration.inertia import coastdown_record, commission_inertia
from frictionwatch.core.monitor.calibration.pressure_gain import sibling_gains
from frictionwatch.core.monitor.calibration.tdc import tdc_of_cycles
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.types import Cycle
from frictionwatch.service.alert_baseline import Baseline
from frictionwatch.service.alerts import AlertEngine
from frictionwatch.service.output_files import atomic_path, check_output_path
from frictionwatch.service.pipeline import analyze_records, resolve_model

MIN_FIRED = 20  # cycle pairs the TDC fit needs for its block scatter (core.monitor.calibration.tdc.BLOCKS)
MIN_MOTORED = 10
LOG_INDEX_STRIDE = 10**9  # cycles of different logs are never consecutive (the TDC fit joins index, index + 1)
MOTORED_IMEP_PA = 0.5e5  # a cycle is motored when no cylinder's IMEP reaches this (pumping work is negative)
FIRED_FRACTION = 0.5  # ... and fired when every cylinder's IMEP is at least this fraction of the cycle's median


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("commission", help="measure TDC, pressure gains and pegging from commissioning logs and write "
                                          "them into the engine model (its calibration section)")
    p.add_argument("logs", type=Path, nargs="+", help="LOG.mcap: fired running at one or more loads; motored or "
                                                      "coast-down stretches where there are some")
    p.add_argument("--engine", help="engine preset, engine TOML or model TOML (its sensor corrections are measured "
                                    "anew); default: the spec stored in the first log")
    p.add_argument("-o", "--output", type=Path, required=True, help="MODEL.toml to write")
    p.add_argument("--gain-sigma", type=float, default=None,
                   help="relative 1-sigma of the pressure gain common to every channel, from a reference the data "
                        "cannot give (the sensors' calibration certificates); default: as uncalibrated, "
                        "what the channels' own 3 %% leaves in their mean and a shared 1 %%")
    p.add_argument("--max-cycles", type=int, default=600, help="cycles used from each log (default 600)")
    p.add_argument("--json", action="store_true", help="print the report as one JSON document")
    p.set_defaults(func=run)


class _Collector:
    """Every assembled cycle the monitor accepted, per log, re-indexed so that two logs never join."""

    def __init__(self, max_cycles: int):
        self.max_cycles = max_cycles
        self.cycles: dict[int, Cycle] = {}
        self.imep: dict[int, np.ndarray] = {}
        self.twist: dict[int, np.ndarray] = {}  # each analysed cycle's static twist of the throws [rad]
        self.offset = 0
        self.taken = 0

    def next_log(self, number: int) -> None:
        self.offset, self.taken = number * LOG_INDEX_STRIDE, 0

    def on_cycle(self, cycle: Cycle) -> None:
        if self.taken < self.max_cycles:
            self.cycles[self.offset + cycle.index] = dataclasses.replace(cycle, index=self.offset + cycle.index)
            self.taken += 1

    def on_result(self, result: CycleResult) -> None:
        self.imep[self.offset + result.index] = np.asarray(result.imep, dtype=np.float64)

    def on_twist(self, result: CycleResult, twist: np.ndarray) -> None:
        self.twist[self.offset + result.index] = np.asarray(twist, dtype=np.float64)

    def mean_twist(self, cycles: list[Cycle], n_cyl: int) -> np.ndarray:
        """(z,) [rad] the throws' mean static twist over ``cycles`` (zeros without any): a loaded throw runs ahead
        of the flywheel by it, a motored one hardly (genset-v20 at 0.75 load +0.02..+0.16 deg, coasting -0.002..
        -0.012), so the fired and the motored TDCs each take their own cycles' twist."""
        found = [self.twist[c.index] for c in cycles if c.index in self.twist]
        return np.mean(found, axis=0) if found else np.zeros(n_cyl)

    def split(self) -> tuple[list[Cycle], list[Cycle]]:
        """(fired, motored) cycles the monitor analysed, in order; misfiring and partly fired cycles in neither."""
        fired, motored = [], []
        for i in sorted(self.cycles):
            imep = self.imep.get(i)
            if imep is None:
                continue  # the monitor refused it: its reason is in the pipeline's skipped counts
            if np.all(imep < MOTORED_IMEP_PA):
                motored.append(self.cycles[i])
            elif np.all(imep >= FIRED_FRACTION * np.median(imep)) and np.median(imep) >= MOTORED_IMEP_PA:
                fired.append(self.cycles[i])
        return fired, motored


def commission(logs: list[Path], engine: str | None, gain_sigma: float | None, max_cycles: int = 600,
               progress: Callable[[str], None] | None = None) -> tuple[Commissioning, dict]:
    """The commissioned model and the report (JSON-able) from ``logs`` (module doc)."""
    from frictionwatch.drivers.logs.mcap_log import LogReader

    model: EngineModel | None = None
    for path in logs:  # one engine, its model without sensor corrections (they are measured anew)
        with LogReader(path) as reader:
            if reader.info is None:
                raise ValueError(f"{path.name} has no acquisition metadata; is it a frictionwatch log?")
            found = resolve_model(reader.engine_toml, engine, path.name, reader.info)
        if model is None:
            model = without_sensor_effects(found)
        elif found.spec.name != model.spec.name:
            raise ValueError(f"{path.name} is engine {found.spec.name!r}, the first log {model.spec.name!r}: "
                             "one engine per commissioning")
    assert model is not None  # argparse: at least one log
    # the drive train first (a second wheel): the throws' static twist, which the TDCs below are corrected by,
    # is the chain's (a 15 % softer shaft line read as a -0.29 deg TDC of one genset-v20 cylinder otherwise)
    drive, drive_note = _drive_train(model, logs, max_cycles)
    if drive is not None:
        own = dataclasses.replace(model, effects=tuple(e for e in model.effects if e.name != "chain_mismatch"))
        drive_found = commissioned_drive_train(own, drive)
        if not drive.poor:
            model = drive_found.model
    collector = _Collector(max_cycles)
    skipped: dict[str, dict] = {}
    for n, path in enumerate(logs):
        with LogReader(path) as reader:
            collector.next_log(n)
            analysis = analyze_records(model, reader.info, reader.records(), collector.on_result,
                                       on_cycle=collector.on_cycle, on_twist=collector.on_twist)
            skipped[path.name] = dict(sorted(analysis.skipped.items()))
        if progress:
            progress(f"{path.name}: {analysis.cycles_ok} cycles analysed")
    fired, motored = collector.split()
    if len(fired) < MIN_FIRED and len(motored) < MIN_MOTORED:
        raise ValueError(f"commissioning needs >= {MIN_FIRED} fired or >= {MIN_MOTORED} motored cycles; the logs gave "
                         f"{len(fired)} fired and {len(motored)} motored (skipped: {skipped})")
    spec = model.spec
    # a loaded throw runs ahead of the flywheel by the static twist the monitor models; its thermodynamic TDC reads
    # early by that much, which is not a sensor error (core.monitor.calibration.tdc_watch says the same)
    twist_fired = collector.mean_twist(fired, spec.n_cyl)
    tdc_fired = _twist_added(tdc_of_cycles(fired, spec), twist_fired) if len(fired) >= MIN_FIRED else None
    tdc_motored = (_twist_added(tdc_of_cycles(motored, spec, motored=True), collector.mean_twist(motored, spec.n_cyl))
                   if len(motored) >= MIN_MOTORED else None)
    used = tdc_used(tdc_fired, tdc_motored)
    correction = np.array([t.offset_rad if t is not None else np.nan for t in used])
    correction = np.where(np.isfinite(correction), correction, np.nanmedian(correction))
    # the channels compared at the same piston position: the throw is ahead of the flywheel by its twist (the
    # running gain watch, core.monitor.calibration.gain_watch, compares them so; a healthy genset-v20 read a
    # front-to-rear trend of 0.4 % in gain without it)
    gains = sibling_gains(spec, fired, correction - twist_fired) if fired else None
    inertia, inertia_note = _inertia(model, logs, motored)
    stated = gain_sigma is not None
    if gain_sigma is None:
        # compared with their siblings, the channels' own errors are measured, but their mean is as unknown as
        # before: 3 % over sqrt(z), and the shared 1 %; without a comparison (under three cylinders) each channel
        # keeps its own 3 % (core.monitor.calibration.commission) and the shared 1 % stays
        base = Calibration()
        gain_sigma = (math.hypot(base.gain_sigma / math.sqrt(spec.n_cyl), base.gain_common_sigma) if gains is not None
                      else base.gain_common_sigma)
    today = datetime.date.today().isoformat()
    source = (f"frictionwatch commission {today}: {len(logs)} log(s), {len(fired)} fired and {len(motored)} motored "
              f"cycles; TDC from the pressure ({'fired' if used is tdc_fired else 'motored'}), gains against the "
              f"siblings, common gain {'stated' if stated else 'unreferenced'}")
    if drive is not None and not drive.poor:
        source += f"; drive train from the second wheel (chi2 {drive.chi2:.1f} on {drive.dof} dof)"
    result = commissioned_model(model, tdc_fired, tdc_motored, gains, gain_sigma, inertia, source)
    if drive is not None:
        result = dataclasses.replace(result, report={**result.report, **drive_found.report})
    # the alert baseline as learnt over these logs (the recording is the engine's healthy state: commissioning
    # assumes it), carried in the calibration section; a serving engine compares with it from its first cycle
    baseline = _alert_baseline(result.model, logs)
    if baseline is not None:
        cal = dataclasses.replace(result.model.calibration, baseline=json.dumps(baseline.to_dict()))
        result = dataclasses.replace(result, model=dataclasses.replace(result.model, calibration=cal))
    report = {"engine": spec.name, "logs": [str(p) for p in logs], "cycles_fired": len(fired),
              "cycles_motored": len(motored), "cycles_skipped": skipped, **result.report,
              "inertia_note": inertia_note, "drive_train_note": drive_note,
              "alert_baseline_bands": [] if baseline is None else [
                  {"imep_bar": b.imep_pa / 1e5, "cycles": b.cycles} for b in baseline.bands]}
    return result, report


def _alert_baseline(model: EngineModel, logs: list[Path]) -> Baseline | None:
    """The alerts' healthy state per load band over ``logs``, learnt as a serving engine learns it, with the
    commissioned ``model``: its TDC, gain and pegging corrections applied, as a serving engine with that model will
    apply them. (Learnt on the uncorrected pressure, a corrected channel read as a change from commissioning by its
    correction: a healthy genset-v20 whose cylinder 5 was corrected by +2.1 % raised "compression pressure 1.021x
    its commissioning value" 14 cycles into a session; bench/ring_after_commission.py.)"""
    from frictionwatch.drivers.logs.mcap_log import LogReader

    alerts = AlertEngine(model.spec)
    for n, path in enumerate(logs):
        def learn(result: CycleResult, offset: int = n * LOG_INDEX_STRIDE) -> None:
            alerts.update(dataclasses.replace(result, index=offset + result.index))

        with LogReader(path) as reader:
            analyze_records(model, reader.info, reader.records(), learn)
    return alerts.baseline


def _drive_train(model: EngineModel, logs: list[Path], max_cycles: int) -> tuple[DriveTrainFit | None, str]:
    """The shaft line's stiffness and damping scales from the logs that carry the second wheel
    (core.monitor.calibration.drive_train), relative to the engine file's chain: each round runs those logs'
    first ``max_cycles`` cycles through the monitor with the chain the round before identified. None and why not
    when no log has a second wheel or the cycles do not allow it."""
    from frictionwatch.drivers.logs.mcap_log import LogReader

    if model.spec.sensors.second_wheel is None:
        return None, "the engine file states no second wheel: the drive train is the engine file's"
    with_wheel = []
    for path in logs:
        with LogReader(path) as reader:
            if reader.info is not None and reader.info.second_wheel is not None:
                with_wheel.append(path)
    if not with_wheel:
        return None, "no log carries the second wheel: the drive train is the engine file's"
    base = dataclasses.replace(model, effects=tuple(e for e in model.effects if e.name != "chain_mismatch"))
    cfg = MonitorConfig(drive_train_inputs=True)

    def results_for(chain) -> list[CycleResult]:
        out: list[CycleResult] = []
        for path in with_wheel:
            taken: list[CycleResult] = []
            with LogReader(path) as reader:
                analyze_records(dataclasses.replace(base, spec=chain), reader.info, reader.records(), taken.append,
                                cfg)
            out.extend(taken[:max_cycles])
        return out

    try:
        fit = identify_iteratively(base.spec, results_for, cfg.tooth_error_deg, cfg.model_rel_error)
    except ValueError as exc:
        return None, f"the drive train was not identified: {exc}"
    return fit, fit.words


def _inertia(model: EngineModel, logs: list[Path], motored: list[Cycle]) -> tuple[InertiaFinding | None, str]:
    """J from the motored (coast-down) cycles, one record per log (core.monitor.calibration.inertia), or None and
    why not."""
    by_log: dict[int, list[Cycle]] = {}
    for c in motored:
        by_log.setdefault(c.index // LOG_INDEX_STRIDE, []).append(c)
    try:
        records = [r for n, cycles in sorted(by_log.items())
                   if (r := coastdown_record(logs[n].name, cycles, model)) is not None]
        if not records:
            return None, "no coast-down (motored) cycles: J stays the engine file's, its sigma as uncalibrated"
        found = commission_inertia(records)
    except ValueError as exc:
        return None, f"J not measured: {exc}"
    return (InertiaFinding(found.inertia, found.inertia_std, float(model.spec.total_inertia), len(records)),
            f"J from the speed ripple of {len(records)} coast-down record(s)")


def _twist_added(estimates: list, twist: np.ndarray) -> list:
    return [None if e is None else dataclasses.replace(e, offset_rad=e.offset_rad + float(twist[k]))
            for k, e in enumerate(estimates)]


def run(args: argparse.Namespace) -> int:
    if args.max_cycles < MIN_FIRED:
        raise ValueError(f"--max-cycles {args.max_cycles}: expected at least {MIN_FIRED}")
    if args.gain_sigma is not None and not 0.0 <= args.gain_sigma < 0.5:
        raise ValueError(f"--gain-sigma {args.gain_sigma}: expected a relative 1-sigma in [0, 0.5)")
    check_output_path(args.output)
    result, report = commission(list(args.logs), args.engine, args.gain_sigma, args.max_cycles)
    with atomic_path(args.output) as tmp:
        tmp.write_text(result.model.to_toml(), encoding="utf-8")
    report["model_written"] = str(args.output)
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        print_report(report)
    return 0


def print_report(doc: dict) -> None:
    """The report for a person: the wheel, each cylinder, and what the calibration section now says."""
    print(f"{doc['engine']}: commissioned from {len(doc['logs'])} log(s), {doc['cycles_fired']} fired and "
          f"{doc['cycles_motored']} motored cycles")
    print(f"wheel TDC: {doc['wheel_tdc_offset_deg']:+.3f} ± {doc['wheel_tdc_sigma_deg']:.3f}° "
          "(+ = the true TDC lies later than the wheel says)")
    print(f"{'cyl':>4} {'TDC fired °':>14} {'TDC motored °':>14} {'own °':>15} {'pegging bar':>12} "
          f"{'gain vs siblings':>17}")
    for c in doc["cylinders"]:
        f, m = c["tdc_fired"], c["tdc_motored"]
        fs = f"{f['offset_deg']:+.3f}±{f['sigma_deg']:.3f}" if f else "—"
        ms = f"{m['offset_deg']:+.3f}±{m['sigma_deg']:.3f}" if m else "—"
        gs = (f"{c['gain_vs_siblings']:.4f}±{c['gain_sigma']:.4f}" + (" *" if c["gain_corrected"] else "")
              if "gain_vs_siblings" in c else "—")
        agree = "" if c.get("methods_agree", True) else "  fired and motored disagree"
        # the own offset applied, or the reading left (the TDC watch compares the cylinder with it while running)
        own = f"{c['own_tdc_offset_deg']:+.3f} applied" if c["own_tdc_offset_deg"] != 0.0 \
            else f"{c.get('own_tdc_reading_deg', 0.0):+.3f} kept"
        print(f"{c['cylinder']:>4} {fs:>14} {ms:>14} {own:>15} {c['pegging_bar']:+12.3f} "
              f"{gs:>17}{agree}")
    cal = doc["calibration"]
    print(f"calibration written: TDC ±{cal['tdc_wheel_sigma_deg']:.3f}° (wheel), ±{cal['tdc_cylinder_sigma_deg']:.3f}° "
          f"(each cylinder), gain ±{100 * cal['gain_sigma']:.2f} % per channel and ±{100 * cal['gain_common_sigma']:.2f} "
          f"% common ({doc['gain_reference']}), J ±{100 * cal['inertia_sigma']:.1f} %")
    inertia = doc.get("inertia")
    if inertia:
        print(f"J: {inertia['measured_kgm2']:.5f} ± {inertia['sigma_kgm2']:.5f} kg·m² measured, the engine file's "
              f"{inertia['engine_file_kgm2']:.5f} (the monitor runs with the file's; the difference is in J's sigma)")
    else:
        print(doc["inertia_note"])
    drive = doc.get("drive_train")
    print(doc["drive_train_note"] + ("" if drive is None else " (written as the model's chain_mismatch effect)"
                                     if drive["applied"] else " (nothing written)"))
    bands = doc["alert_baseline_bands"]
    print("alert baseline (the healthy state the alerts compare with): " + (
        ", ".join(f"IMEP {b['imep_bar']:.2f} bar ({b['cycles']} cycles)" for b in bands) if bands else
        "none learnt: it needs 200 healthy cycles at one load (service/alerts.py AlertConfig.baseline_cycles)"))
    print("* gain corrected (beyond the siblings' spread); an own TDC beyond twice its sigma is applied as a model effect, "
          "one within it is kept as read (what the TDC watch expects of that cylinder while running)")
    print(f"model written to {doc['model_written']}")
