"""The change detector's innovation floor (core.monitor.checks.change.ChangeSettings.rel_floor; design note 69's
follow-up): record a healthy run's per-cylinder innovations with the floor off, then replay the detector's reference
on them for a list of floors and take the smallest that raises no alarm.

    python -m bench.calibrate_change_floor record genset-v20 1500 1.0 3 --cycles 1000 --out inn_s3.json
    python -m bench.calibrate_change_floor replay inn_s3.json [--floors 0 0.01 0.02 0.03 0.04] [--write]

``record`` runs the one pipeline (service.pipeline.run) on a simulated healthy log with the detector unable to
alarm and keeps, each cycle, the innovation (the cycle's per-cylinder friction less the smoothed one), the smoothed
figures and the smoothed estimate's motion at the cycle's rows. ``replay`` steps ``cusum_step_reference`` over them,
its mean following the motion as the monitor's does (``--no-follow``: the detector before design note 151); no
alarm in the run means no feedback to miss, and the floor is then checked by running the validating cases,
tests/core/test_monitor_accuracy.py and tests/core/test_condition.py. ``--write`` stores the
smallest floor with no alarm in core/monitor/tuned.json as CHANGE_INNOVATION_REL_FLOOR, with this run as its
provenance. The floor is tuned on a seed no test runs (3) and validated on the tests' seeds.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from datetime import date

import numpy as np
from frictionwatch.core.monitor.checks import condition
from frictionwatch.core.monitor.checks.change import ChangeDetector, cusum_step_reference, follow_smoothed
from frictionwatch.core.tuned import MONITOR_RECORD, Tuned, round_up, write_tuned

NAME = "CHANGE_INNOVATION_REL_FLOOR"
# the floor written is the smallest without an alarm times this, rounded up: one seed, and a replay without the
# feedback an alarm has in a run (the discount moves the later innovations)
MARGIN = 1.25


def record(engine: str, rpm: float, load: float, seed: int, cycles: int) -> dict:
    """The healthy run's innovations (cycles, z), smoothed figures (cycles, z), and each cycle's smoothed friction
    parameters (cycles, p_f) and cylinder rows (cycles, z, p_f) (what ``follow_smoothed`` reads), with the detector
    unable to alarm (h infinite): no alarm discounts the accumulator, so the replay sees the run it replays."""
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.plant.simulate import simulate
    from frictionwatch.service.pipeline import run

    inner, innov, smooth, params, rows_seen = condition.condition_kernel, [], [], [], []

    def spy(levels, stats, estimate, fit, ring, limits, *rest):
        cycle_params, smoothed_params, rows = fit[0], fit[1], fit[2]
        pf = rows.shape[1]
        s = rows @ smoothed_params[:pf]
        innov.append((rows @ cycle_params[:pf] - s).tolist())
        smooth.append(s.tolist())
        params.append(smoothed_params[:pf].tolist())
        rows_seen.append(rows.tolist())
        cusum = limits[2].copy()
        cusum[1] = np.inf  # h: never an alarm
        return inner(levels, stats, estimate, fit, ring, (limits[0], limits[1], cusum), *rest)

    condition.condition_kernel = spy  # a bench's probe: the module's name is what assess_condition calls
    try:
        spec = load_engine(engine)
        sim = simulate(spec, rpm, load, cycles, seed=seed)
        for _ in run(spec, sim.info, sim.records):
            pass
    finally:
        condition.condition_kernel = inner
    return {"case": f"{engine} {rpm:g} rpm {load:g} seed {seed}", "cycles": cycles,
            "command": f"record {engine} {rpm:g} {load:g} {seed} --cycles {cycles}", "innovation": innov,
            "smoothed": smooth, "params": params, "rows": rows_seen}


def replay(doc: dict, floor: float, follow: bool = True) -> list[tuple[int, int]]:
    """(cycle, cylinder) of every alarm the detector's reference raises on the recorded innovations at ``floor``;
    ``follow``: its mean following the recorded smoothed parameters (``follow_smoothed``, as in the monitor)."""
    settings = replace(condition.ConditionSettings().change, rel_floor=floor)
    det: ChangeDetector | None = None
    out = []
    for i, (u, s, p, rows) in enumerate(zip(doc["innovation"], doc["smoothed"], doc["params"], doc["rows"])):
        if follow:
            det = follow_smoothed(det, np.asarray(p), np.asarray(rows))
        det, alarm = cusum_step_reference(det, np.asarray(u), np.asarray(s), settings)
        out += [(i, int(k)) for k in np.flatnonzero(alarm)]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("engine")
    r.add_argument("rpm", type=float)
    r.add_argument("load", type=float)
    r.add_argument("seed", type=int)
    r.add_argument("--cycles", type=int, default=1000)
    r.add_argument("--out", required=True)
    p = sub.add_parser("replay")
    p.add_argument("path")
    p.add_argument("--floors", type=float, nargs="+", default=[0.0, 0.01, 0.02, 0.025, 0.03, 0.035, 0.04, 0.05])
    p.add_argument("--write", action="store_true")
    p.add_argument("--no-follow", action="store_true", help="the detector before design note 151 (its mean not moved "
                   "by the smoothed estimate's motion)")
    args = ap.parse_args()
    if args.cmd == "record":
        doc = record(args.engine, args.rpm, args.load, args.seed, args.cycles)
        with open(args.out, "w") as fh:
            json.dump(doc, fh)
        print(f"{doc['case']}: {len(doc['innovation'])} cycles recorded -> {args.out}")
        return
    with open(args.path) as fh:
        doc = json.load(fh)
    counts = {f: len(replay(doc, f, not args.no_follow)) for f in sorted(args.floors)}
    for f, n in counts.items():
        print(f"rel_floor {f:.3f}: {n} alarms in {len(doc['innovation'])} healthy cycles")
    quiet = [f for f, n in counts.items() if n == 0]
    if not quiet:
        raise SystemExit("no floor of the list leaves the run without an alarm")
    best = round_up(quiet[0] * MARGIN)
    print(f"smallest floor without an alarm: {quiet[0]:g}; with the margin {MARGIN:g}: {best:g}")
    if args.write:
        figure = "; ".join(f"{f:g}: {n}" for f, n in counts.items())
        write_tuned({NAME: Tuned(
            best, f"python -m bench.calibrate_change_floor {doc['command']} --out F; ... replay F --write",
            (doc["case"],), f"alarms per floor on {len(doc['innovation'])} healthy cycles (no feedback): {figure}; "
                            f"smallest without one {quiet[0]:g} x {MARGIN:g}",
            date.today().isoformat(), "tuned")}, MONITOR_RECORD)


if __name__ == "__main__":
    main()
