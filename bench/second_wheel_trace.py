"""Why a genset-v20 cylinder measured at N cycles is not at more (issue 29): each cylinder traced through what
decides "measured" (core.monitor.identify.estimate: the posterior's sigma against ``resolve_rel``, the data gain
against ``min_data_gain``, then the model-error floor's excess over the mean balance), one wheel and the joint fit.

    nice .venv/bin/python -m bench.second_wheel_trace simulate --cycles 3000 --seed 29 --out /tmp/fw-trace
    nice .venv/bin/python -m bench.second_wheel_trace trace /tmp/fw-trace/seed29.mcap [--every 100] [--variants ...]

``simulate`` writes the plant of bench.accuracy_v20_wheels (genset-v20 with its free-end wheel, the +-20 % load
profile compressed to 30 s dwells) to a replay log and the per-cycle truth beside it, so the monitor's variants can be
re-run on the same records without the simulator (~15x its cost). ``trace`` replays the log through the one pipeline
per variant and, every ``--every`` cycles, records for the smoothed estimate: each cylinder's friction, its sigma
before the floor (statistical and whole), its data gain, the floor's relative part sqrt(rel2) and what makes it (the
fit's total, the running mean balance, their sigmas, the misfit term), the accumulated weight, the scales; the
status (measured or not) and the error against the truth (mean of the last 200 cycles). The smoothed call of
``reported_estimate`` is wrapped here (bench only) to read its inputs; nothing in the monitor changes.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.identify import identification, step
from frictionwatch.core.monitor.identify.estimate import cylinder_kernel
from frictionwatch.core.monitor.identify.pull_check import PullCheck, data_only_pull
from frictionwatch.core.monitor.report.figure_status import friction_status
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.plant.simulate import start_simulation
from frictionwatch.drivers.logs.mcap_log import LogReader, LogWriter
from frictionwatch.service.pipeline import EnginePipeline

from bench.accuracy_v20_long import BASE_LOAD, RPM, TRUTH_WINDOW, load_profile, write_json
from bench.accuracy_v20_wheels import TWO_WHEELS

VARIANTS = {"one_wheel": MonitorConfig(), "joint": MonitorConfig(second_wheel=True),
            # every half order of the free end (0.5-11.5), not the hand-set 4.5: what its orders above would add
            # with a perfect free-end wheel (``simulate --tooth-errors flywheel``; design note 38)
            "joint_all_orders": MonitorConfig(second_wheel=True, second_wheel_max_order=12.0)}
DEFAULT_VARIANTS = ["one_wheel", "joint"]


def plant_engine(grid_scale: float = 1.0):
    """genset-v20 with its free-end wheel; its grid coupling (K_e, D_e) x ``grid_scale`` (a diagnostic plant, told
    to the monitor too: note 42)."""
    spec = load_engine(TWO_WHEELS)
    if grid_scale != 1.0:
        ld = spec.load
        spec = replace(spec, load=replace(ld, grid_stiffness_nm_per_rad=ld.grid_stiffness_nm_per_rad * grid_scale,
                                          grid_damping_nms_per_rad=ld.grid_damping_nms_per_rad * grid_scale))
    return spec


def cmd_simulate(args) -> None:
    spec = plant_engine(args.grid_scale)
    hours = args.cycles / (RPM / 120.0) / 3600.0
    steps = load_profile(hours, dwell_s=args.dwell_s, ramp_pct_per_min=args.ramp, repeat=args.repeat_profile)
    from bench.drive_train_model_error import tooth_errors_on  # (it imports bench.accuracy_v20_wheels)
    with tooth_errors_on(args.tooth_errors):  # drawn when the run is set up
        sim = start_simulation(spec, RPM, BASE_LOAD, args.cycles, args.seed, load_steps=steps, second_wheel=True,
                               without=set(w for w in args.without.split(",") if w), cov_imep=args.cov_imep)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    truth = np.full((args.cycles, spec.n_cyl), np.nan)
    load = np.full(args.cycles, np.nan)
    with LogWriter(out / f"seed{args.seed}.mcap", spec.source_text, sim.info) as writer:
        for chunk in sim.chunks():
            for e in chunk.cycles:
                truth[e["index"]] = [c["friction_torque_mean_nm"] for c in e["cylinders"]]
                load[e["index"]] = e["load_torque_nm"]
            for record in chunk.records:
                writer.write(record)
    np.savez(out / f"seed{args.seed}.truth.npz", friction=truth, load=load)
    print(f"wrote {out}/seed{args.seed}.mcap")


class Tap:
    """Wraps the identification step's reported_estimate (core.monitor.identify.step's reference): keeps the inputs and the pre-floor numbers of the first call of each
    identify_cycle (the smoothed estimate)."""

    def __init__(self):
        self.inner = step.reported_estimate
        self.inner_post = step.posterior_from_normal
        self.calls = 0
        self.post_calls = 0
        self.last: dict | None = None
        self.normal = None  # the smoothed posterior's accumulated equations, prior and budget
        self.m = 0  # harmonics of the flywheel's rows (set by the caller)

    def posterior(self, acc, n_pr, r_pr, sys_var, lower):
        self.post_calls += 1
        if self.post_calls % 2 == 1:  # the smoothed posterior first, then the cycle's
            self.normal = (acc, n_pr, np.asarray(sys_var))
        return self.inner_post(acc, n_pr, r_pr, sys_var, lower)

    def sys_parts(self, rows: np.ndarray) -> dict:
        """Each cylinder's systematic variance split by raw-row group: the flywheel's speed rows, the free end's
        and the mean balance [(N m)^2], with the rows' own budget (rms of sqrt(sys_var) per group)."""
        acc, n_pr, sys_var = self.normal
        g = np.linalg.solve(acc.info + n_pr, acc.sys_map)[:rows.shape[1]]  # (p_f, R)
        h = rows @ g  # (z, R): each cylinder's friction per unit raw error of each row
        r = sys_var.shape[0]
        groups = {"flywheel": slice(0, 2 * self.m), "free_end": slice(2 * self.m, r - 1), "balance": slice(r - 1, r)}
        out = {}
        for name, sl in groups.items():
            out[f"sys_{name}"] = (h[:, sl] ** 2 * sys_var[sl][None, :]).sum(axis=1)
        return out

    def __call__(self, spec, layout, post, basis_mean, prior_mean, limits, cyl_rows, floor, check, cal, sens):
        est = self.inner(spec, layout, post, basis_mean, prior_mean, limits, cyl_rows, floor, check, cal, sens)
        self.calls += 1
        if self.calls % 2 == 1:  # identify_cycle: the smoothed estimate first, then the cycle's
            p = layout.n_params
            rows = np.asarray(cyl_rows, dtype=np.float64)
            t_cyl, t_sig, t_tot, s_tot, gain = cylinder_kernel(post.params[:p], post.covariance, post.cov_statistical,
                                                               post.cov_reference, rows)
            _, t_sig_stat, _, s_tot_stat, _ = cylinder_kernel(post.params[:p], post.cov_statistical,
                                                              post.cov_statistical, post.cov_reference, rows)
            excess2 = 0.0
            if math.isfinite(check.balance) and t_tot > 0:
                excess2 = max(0.0, (t_tot - check.balance) ** 2 - s_tot ** 2 - check.balance_sigma ** 2)
            mis = (floor.coupling_per_misfit * max(0.0, check.misfit - floor.misfit_free) * check.coupling_loss) ** 2
            acc = self.normal[0]
            pull = data_only_pull(acc, post, rows, prior_mean)  # the pull check's inputs (note 42), recomputed here
            nan_z = np.full(rows.shape[0], np.nan)
            self.last = dict(pull_d=pull.d if pull else nan_z, pull_v=pull.v if pull else nan_z,
                             pull_cov=pull.cov if pull else np.full((rows.shape[0],) * 2, np.nan),
                             pull_shift=pull.shift if pull else nan_z, t_cyl=t_cyl, t_sig=t_sig, t_sig_stat=t_sig_stat, gain=gain, t_tot=t_tot, s_tot=s_tot,
                             s_tot_stat=s_tot_stat, balance=check.balance, balance_sigma=check.balance_sigma,
                             misfit=check.misfit, coupling=check.coupling_loss, excess_rel=math.sqrt(
                                 excess2) / t_tot if t_tot > 0 else float("nan"),
                             misfit_rel=math.sqrt(mis) / t_tot if t_tot > 0 else float("nan"),
                             weight=float(post.weight), chi2=float(post.chi2_reduced), **self.sys_parts(rows))
        return est


def _r(a, n=4):
    return [round(float(v), n) for v in np.atleast_1d(a)]


def cmd_trace(args) -> None:
    log_path = Path(args.log)
    truth = np.load(log_path.with_name(log_path.name.removesuffix(".mcap") + ".truth.npz"))["friction"]
    log = LogReader(log_path)
    spec = load_engine(TWO_WHEELS)
    tap = Tap()
    # the step by its reference, whose wrapper calls the tap sees (the kernel makes the same numbers without them)
    identification.identify_step = step.identify_step_reference
    step.reported_estimate = tap
    step.posterior_from_normal = tap.posterior
    names = args.variants
    # the pull check at another kappa (inf: off), bench only
    pull = {} if args.pull_kappa is None else {"pull_check": PullCheck(kappa=args.pull_kappa)}
    # the accumulated equations' window in cycles (bench only; default the product's, forgetting_factor)
    window = {} if not args.forgetting_cycles else {"forgetting": 1.0 - 1.0 / args.forgetting_cycles}
    # the carried modes' free response (None: the product's, off; 0.1: projected out; design note 105)
    response = {} if args.free_response_carry is None else {"free_response_carry": args.free_response_carry}
    pipes = {n: EnginePipeline(spec, log.info if n != "one_wheel" else replace(log.info, second_wheel=None),
                               replace(VARIANTS[n], **pull, **window, **response)) for n in names}
    taps = {n: None for n in names}
    last = {n: None for n in names}
    counts = {n: 0 for n in names}
    resets = {n: 0 for n in names}  # change alarms: each discounts the accumulated equations (checks.condition)
    doc = {"log": str(log_path), "every": args.every, "variants": names, "trace": {n: [] for n in names}}
    records = log.records()
    offset = 0  # cycles of the log before the monitor's first (``--start-cycle``): the truth's index is the log's
    if args.start_cycle:
        records, offset = records_from_cycle(records, args.start_cycle, log.info)
    for record in itertools.chain(records, [None]):
        for n in names:
            state = pipes[n].state
            tap.m = state.n_harmonics if state is not None else 0
            for o in pipes[n].outcomes(record):
                if not o.ok:
                    continue
                counts[n] += 1
                last[n] = o
                resets[n] += "estimate_reset" in o.result.flags
                taps[n] = tap.last
                if counts[n] % args.every == 0 or record is None:
                    doc["trace"][n].append({**row(n, o, taps[n], truth, pipes[n], offset), "resets": resets[n]})
        if args.cycles and min(counts.values()) >= args.cycles:
            break
    for n in names:
        print(n, [(r["cycles"], r["measured"], r["passing"]) for r in doc["trace"][n]])
    write_json(Path(args.json), doc)
    print(f"wrote {args.json}")


def _record_tick(record) -> int:
    for name in ("t0_ticks", "ticks"):
        v = getattr(record, name, None)
        if v is not None:
            return int(np.atleast_1d(v)[0]) if np.size(v) else -1
    return -1


def records_from_cycle(records, start_cycle: int, info):
    """The log's records from (about) its ``start_cycle``-th cycle on, at the nominal speed (a governed genset: within
    a cycle or two over thousands), and that cycle count, so the monitor starts there as on a fresh start."""
    records = iter(records)
    first = None
    for record in records:
        tick = _record_tick(record)
        if tick < 0:
            continue
        first = tick if first is None else first
        if tick - first >= start_cycle * 120.0 / RPM * info.tick_hz:
            return itertools.chain([record], records), start_cycle
    return iter(()), start_cycle


def row(name, outcome, t, truth_all, pipe, offset: int = 0) -> dict:
    res, idx = outcome.result, outcome.index + offset
    lo = max(0, idx + 1 - TRUTH_WINDOW)
    truth = truth_all[lo:idx + 1].mean(axis=0)
    est = res.smoothed
    status = friction_status(est, ())
    measured = np.array([s.status == "measured" for s in status.cylinders])
    err = t["t_cyl"] / truth - 1.0
    sig_pre = t["t_sig"] / np.abs(t["t_cyl"])
    floor_sig = np.sqrt(t["t_sig"] ** 2 + (t["excess_rel"] ** 2 + t["misfit_rel"] ** 2) * t["t_cyl"] ** 2)
    passing = measured & (np.abs(err) <= 0.05) & (np.abs(err) <= 2.0 * est.friction_torque_mean_sigma / truth)
    state = pipe.state if hasattr(pipe, "state") else None
    return {"cycles": idx + 1, "measured": int(measured.sum()), "passing": int(passing.sum()),
            "measured_mask": [int(m) for m in measured], "err_pct": _r(100 * err, 2),
            "sigma_pre_pct": _r(100 * sig_pre, 2), "sigma_stat_pct": _r(100 * t["t_sig_stat"] / np.abs(t["t_cyl"]), 2),
            "sigma_floor_pct": _r(100 * floor_sig / np.abs(t["t_cyl"]), 2),
            "sigma_reported_pct": _r(100 * est.friction_torque_mean_sigma / truth, 2),
            "cal_sigma_pct": _r(100 * est.calibration_sigma / truth, 2) if est.calibration_sigma is not None else [],
            "pull_d_pct": _r(100 * t["pull_d"] / truth, 2), "pull_v_pct2": _r(1e4 * t["pull_v"] / truth ** 2, 3),
            "pull_shift_pct": _r(100 * t["pull_shift"] / truth, 2),
            # in N m (the check's directions are those of its covariance in N m^2): d, shift, cov and the truth
            "pull_nm": {"d": _r(t["pull_d"], 6), "shift": _r(t["pull_shift"], 6), "truth": _r(truth, 6),
                        "cov": [_r(c, 8) for c in t["pull_cov"]]},
            "gain": _r(t["gain"], 3), "t_tot": round(float(t["t_tot"]), 3), "s_tot": round(float(t["s_tot"]), 3),
            "s_tot_stat": round(float(t["s_tot_stat"]), 3), "truth_tot": round(float(truth.sum()), 3),
            "balance": round(float(t["balance"]), 3), "balance_sigma": round(float(t["balance_sigma"]), 3),
            "excess_rel_pct": round(100 * t["excess_rel"], 3), "misfit": round(float(t["misfit"]), 3),
            "misfit_rel_pct": round(100 * t["misfit_rel"], 3), "coupling": round(float(t["coupling"]), 3),
            "weight": round(t["weight"], 1), "chi2": round(t["chi2"], 3),
            **{f"{k}_pct": _r(100 * np.sqrt(t[k]) / np.abs(t["t_cyl"]), 2) for k in ("sys_flywheel", "sys_free_end",
                                                                                     "sys_balance")},
            "scales": _r(state.params[:state.layout.n_params] if state is not None else [], 4)}


def cmd_summary(args) -> None:
    """Per trace file and variant: measured (within 5 % and 2 sigma) every 1,000 cycles; from 2k on min/median/max measured, the
    most within 5 % and 2 sigma, how often the measured count fell between checkpoints, measured figures outside
    2 sigma, |error| / sigma (median, 99th percentile), rms error over the 20 cylinders at the last checkpoint. The
    sigma is the whole one *without* the calibration's (``sigma_pre_pct``; uncalibrated the calibration adds ~48 %,
    so every figure would be within 2 sigma of the reported one, design note 35)."""
    for path in args.json:
        d = json.loads(Path(path).read_text())
        for v in d["variants"]:
            pts, counts, ratios, prev, falls, out, n_meas = {}, [], [], None, 0, 0, 0
            for r in d["trace"][v]:
                e, s = np.array(r["err_pct"]), np.array(r["sigma_pre_pct"])
                m = np.array(r["measured_mask"]).astype(bool)
                good = int(((np.abs(e) <= 5.0) & (np.abs(e) <= 2.0 * s) & m).sum())
                if r["cycles"] % 1000 == 0:
                    pts[r["cycles"]] = f"{int(m.sum())} ({good})"
                if r["cycles"] >= 2000:
                    counts.append((int(m.sum()), good))
                    falls += prev is not None and m.sum() < prev
                    prev = m.sum()
                    out += int(((np.abs(e) > 2.0 * s) & m).sum())
                    n_meas += int(m.sum())
                    ratios += list(np.abs(e[m]) / s[m])
            meas = np.array([c[0] for c in counts] or [0])
            q = np.percentile(ratios, [50, 99]) if ratios else [float("nan")] * 2
            rms = float(np.sqrt(np.mean(np.square(d["trace"][v][-1]["err_pct"]))))
            print(f"{Path(path).name} {v}: every 1k {' | '.join(pts[k] for k in sorted(pts))}; from 2k measured "
                  f"{meas.min()}/{int(np.median(meas))}/{meas.max()}, within 5 % and 2 sigma at most "
                  f"{max([c[1] for c in counts] or [0])}, falls {falls}, outside 2 sigma {out} of {n_meas}, "
                  f"|error|/sigma {q[0]:.2f} / {q[1]:.2f}, rms error at {d['trace'][v][-1]['cycles']} {rms:.1f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(required=True)
    s = sub.add_parser("simulate")
    s.add_argument("--cycles", type=int, default=3000)
    s.add_argument("--seed", type=int, default=29)
    s.add_argument("--dwell-s", type=float, default=30.0)
    s.add_argument("--ramp", type=float, default=60.0)
    s.add_argument("--out", default="/tmp/fw-trace")
    s.add_argument("--tooth-errors", choices=("both", "flywheel", "free_end"), default="both",
                   help="which wheels have tooth-spacing errors (flywheel: the free-end wheel perfect, what its "
                        "in-band nuisances would remove at most; design note 38)")
    s.add_argument("--without", default="", help="default-on plant effects off, comma list (variable_inertia: "
                   "also tell the monitor, ``second_wheel_pull --without``; note 42)")
    s.add_argument("--repeat-profile", action="store_true",
                   help="the profile's set-points to the end (bench.accuracy_v20_wheels --repeat-profile's plant)")
    s.add_argument("--cov-imep", type=float, default=0.02, help="cycle-to-cycle COV of IMEP (0: every cycle alike)")
    s.add_argument("--grid-scale", type=float, default=1.0, help="the generator's grid stiffness and damping x this "
                   "(plant; ``second_wheel_pull --grid-scale`` tells the monitor)")
    s.set_defaults(func=cmd_simulate)
    t = sub.add_parser("trace")
    t.add_argument("log")
    t.add_argument("--every", type=int, default=100)
    t.add_argument("--cycles", type=int, default=0)
    t.add_argument("--variants", nargs="+", default=DEFAULT_VARIANTS, choices=list(VARIANTS))
    t.add_argument("--pull-kappa", type=float, default=None,
                   help="the pull check's kappa (inf: off; default the tuned one, core/monitor/tuned.json)")
    t.add_argument("--forgetting-cycles", type=float, default=0.0,
                   help="the accumulated equations' window N (forgetting 1 - 1/N; 0: the product's)")
    t.add_argument("--free-response-carry", type=float, default=None,
                   help="MonitorConfig free_response_carry (default the product's: 0.1, the chain's slow modes' free "
                   "response a random effect of the data's variance; 0: left in the rows; notes 105, 108)")
    t.add_argument("--start-cycle", type=int, default=0,
                   help="start the monitor fresh at about this cycle of the log (a steady stretch alone; note 41)")
    u = sub.add_parser("summary")
    u.add_argument("json", nargs="+")
    u.set_defaults(func=cmd_summary)
    t.add_argument("--json", default="/tmp/fw-trace/trace.json")
    t.set_defaults(func=cmd_trace)
    args = ap.parse_args()
    args.func(args)


if __name__ == "__main__":
    main()
