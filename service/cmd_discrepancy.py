"""`frictionwatch discrepancy LOG.mcap`: where the model and the log disagree, which effect is missing, the model with
it added (core.discrepancy does the numerics; this module reads, assembles, prints and writes).

    frictionwatch discrepancy LOG.mcap [--model FILE | --engine NAME] [--baseline default|rigid|without:NAME,...]
                              [--report DIR] [--json] [-o MODEL_OUT.toml]

``run_discrepancy(source, model, options)`` is the same for the service: records (with their AcquisitionInfo) or a
log path in, the JSON report out.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from frictionwatch.core.discrepancy import Discovery, Options, discover
from frictionwatch.core.model.engine_model import EngineModel, load_model
from frictionwatch.core.types import AcquisitionInfo, Cycle, StreamRecord
from frictionwatch.service.output_files import atomic_paths, check_output_path
from frictionwatch.service.pipeline import assembled_cycles, resolve_model

BASELINES = "default | rigid | without:NAME[,NAME...]"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("discrepancy", help="find the effect the model is missing, add it, show the gap shrink")
    p.add_argument("log", type=Path, help="LOG.mcap")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--model", help="model TOML (EngineModel.to_toml) to start from")
    src.add_argument("--engine", help="engine preset or TOML (its default model); default: the spec in the log")
    p.add_argument("--baseline", default="default", help=f"default effects of the starting model: {BASELINES}")
    p.add_argument("--report", type=Path, metavar="DIR", help="write DIR/discrepancy.html (offline, plots inline)")
    p.add_argument("--json", action="store_true", help="print the JSON report instead of the summary")
    p.add_argument("-o", "--output", type=Path, metavar="MODEL_OUT.toml", help="write the augmented model")
    p.add_argument("--max-steps", type=int, default=Options.max_steps, help="effects to add at most")
    p.set_defaults(func=run)


def with_baseline(model: EngineModel, baseline: str) -> EngineModel:
    """``model`` with default effects left out: 'default' keeps them, 'rigid' drops the flexible shaft line and
    J(theta) (a rigid crank of constant inertia), 'without:a,b' drops the named ones."""
    text = baseline.strip()
    if text == "default":
        return model
    if text == "rigid":
        drop = {"torsional_flexibility", "variable_inertia"}
    elif text.startswith("without:"):
        drop = {n.strip() for n in text.removeprefix("without:").split(",") if n.strip()}
        have = {e.name for e in model.effects}
        unknown = sorted(drop - have)
        if not drop or unknown:
            raise ValueError(f"--baseline {baseline}: the model has no effect {', '.join(unknown) or '(none named)'}; "
                             f"it has {', '.join(sorted(have)) or 'none'}")
    else:
        raise ValueError(f"--baseline {baseline!r}: expected {BASELINES}")
    return EngineModel(model.spec, model.terms, model.coefficients, tuple(e for e in model.effects if e.name not in drop))


@dataclass
class Assembled:
    cycles: list[Cycle]
    skipped: Counter


def assemble(model: EngineModel, info: AcquisitionInfo, records: Iterable[StreamRecord]) -> Assembled:
    """The log's cycles as the pipeline's assembler makes them (service.pipeline.assembled_cycles)."""
    return Assembled(*assembled_cycles(model, info, records))


def run_discrepancy(source: Path | tuple[AcquisitionInfo, Iterable[StreamRecord]], model: EngineModel | str | None = None,
                    options: Options | None = None, baseline: str = "default") -> dict:
    """The service's call: the JSON report of the workflow on a log path or on (info, records) of a recorded
    window (``discrepancy_of``)."""
    return discrepancy_of(source, model, options, baseline)[0]


def discrepancy_of(source: Path | tuple[AcquisitionInfo, Iterable[StreamRecord]], model: EngineModel | str | None = None,
                   options: Options | None = None, baseline: str = "default") -> tuple[dict, Discovery]:
    """The workflow on a log path or on (info, records) of a recorded window. ``model``: an EngineModel, a preset
    or TOML name, or None (the spec the log stores; records need a model). Returns (JSON report, Discovery)."""
    if isinstance(source, (str, Path)):
        from frictionwatch.drivers.logs.mcap_log import LogReader

        path = Path(source)
        with LogReader(path) as reader:
            if reader.info is None:
                raise ValueError(f"{path.name} has no acquisition metadata; is it a frictionwatch log?")
            base = model if isinstance(model, EngineModel) else resolve_model(reader.engine_toml, model, path.name,
                                                                               reader.info)
            base = with_baseline(base, baseline)
            got = assemble(base, reader.info, reader.records())
    else:
        info, records = source
        if not isinstance(model, EngineModel):
            model = load_model(model) if model else None
        if model is None:
            raise ValueError("records need a model (an EngineModel or a preset name)")
        base = with_baseline(model, baseline)
        got = assemble(base, info, records)
    found = discover(base, got.cycles, options)
    doc = found.to_json()
    doc.update({"engine": base.spec.name, "baseline": baseline, "cycles": len(got.cycles),
                "cycles_skipped": dict(sorted(got.skipped.items()))})
    return doc, found


def run(args: argparse.Namespace) -> int:
    if args.max_steps < 0:
        raise ValueError(f"--max-steps {args.max_steps}: expected 0 or more")
    if args.output is not None:
        check_output_path(args.output)
    model = args.model or args.engine  # a name: resolve_model checks it against the engine the log recorded
    doc, found = discrepancy_of(args.log, model, Options(max_steps=args.max_steps), args.baseline)
    if args.output is not None:
        with atomic_paths(args.output) as (tmp,):
            tmp.write_text(found.model.to_toml(), encoding="utf-8")
        doc["model_written"] = str(args.output)
    if args.report is not None:
        from frictionwatch.service.discrepancy_report import write_report

        doc["report_written"] = str(write_report(args.report, doc, found))
    if args.json:
        print(json.dumps(doc, indent=1, default=_plain))
    else:
        print_summary(doc)
    return 0


def print_summary(doc: dict) -> None:
    print(f"{doc['engine']}: {doc['cycles']} cycles, baseline {doc['baseline']}; {doc['verdict']}")
    for f in doc["found"]:
        cyl = f" cylinder {f['cylinder']}" if f["cylinder"] is not None else ""
        params = ", ".join(f"{k}={v:.4g}" + (f" ± {f['sigma'][k]:.2g}" if k in f["sigma"] else "")
                           for k, v in f["parameters"].items() if k in f["sigma"] or not f["sigma"])
        ev = f["evidence"]
        how = (f"named from the pressure: {ev['pressure_reading']}" if ev.get("channel") == "pressure" else
               f"gap {ev['gap_before']:.3g} -> {ev['gap_after']:.3g}, held-out delta chi2 {ev['delta_chi2_heldout']:.1f}")
        print(f"  + {f['effect']}{cyl}: {params}  ({how})")
    print(f"gap (held-out) {doc['gap_before']:.3g} -> {doc['gap_after']:.3g}")
    loc = doc.get("localisation") or {}
    points = (loc.get("balance") or {}).get("points")
    if points:  # several operating points: each judged on its own (core.discrepancy.features)
        print(f"the held-out cycles ran at {len(points)} operating points, each judged against its own noise "
              f"({loc.get('cycles_between_points', 0)} cycles of the log's load steps left out): "
              + "; ".join(f"{p['rpm']:.0f} rpm {p['load_nm']:.4g} N m" for p in points))
    for key in ("model_written", "report_written"):
        if key in doc:
            print(f"wrote {doc[key]}")


def _plain(v: object) -> object:
    return v.item() if hasattr(v, "item") else str(v)


__all__ = ["add_parser", "assemble", "discrepancy_of", "run", "run_discrepancy", "with_baseline"]
