"""What draws a genset-v20 cylinder's smoothed estimate away from its truth (issue 29, design note 41): one wheel,
every ``--every`` cycles, from the accumulated equations the monitor itself keeps.

    nice .venv/bin/python -m bench.second_wheel_pull LOG [--every 500] [--start-cycle 0] [--cylinder 13] [--json J]

LOG is a replay log of ``bench.second_wheel_trace simulate`` (its truth beside it). Per checkpoint, for the cylinder:
the posterior's error against the truth (mean of the last 200 cycles); the data-only fixed point N^-1 r of the
accumulated normal equations (no prior, no bound) and its statistical sigma sqrt(c N^-1 c^T): where more cycles of
the same equations lead the estimate; the sandwich's flywheel systematic sigma with the stated per-row budget C
(independent rows: sqrt(sum h^2 C)) and the same C taken coherent over the rows (sum |h| sqrt(C): one physical error
common to every harmonic); how many of the flywheel's harmonics have a budget above the 0.3 %-of-the-harmonic floor
(``identification.accumulate_cycle``'s budget: the persistent residual at the estimate seen), and the five raw
rows that carry most of the cylinder's systematic part (row j < M: the real part of half order (j + 1) / 2,
j >= M: its imaginary); at the preset's coefficients (every friction scale 1, as the plant has them; the nuisances
at their best given those) the cylinder's figure against the truth (a check that the truth is there) and the
data-only point's offset from it; with ``--split`` that offset split exactly by raw row (per half order, the mean
balance's row, the rest). The monitor is wrapped here (bench only); nothing in it changes.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from frictionwatch.core.monitor.identify import identification
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.drivers.logs.mcap_log import LogReader
from frictionwatch.service.pipeline import EnginePipeline

from bench.accuracy_v20_long import TRUTH_WINDOW
from bench.second_wheel_trace import Tap, plant_engine, records_from_cycle


class PullTap(Tap):
    """The trace's tap, also keeping the smoothed estimate's posterior, cylinder rows and the flywheel's budget."""

    def __init__(self):
        super().__init__()
        self.inner_step = identification.accumulate_cycle
        self.budget_seen: dict = {}

    def budget(self, acc, white, forgetting, fold, params, model_rel_error, harmonics):
        """Wraps identification.accumulate_cycle (the budget is its third output)."""
        terms, acc, out = self.inner_step(acc, white, forgetting, fold, params, model_rel_error, harmonics)
        m = white.freq.shape[0]
        e = model_rel_error * white.freq * np.abs(harmonics)
        self.budget_seen = {"floor": e * e / 2.0, "budget": out[:m].copy()}
        return terms, acc, out

    def __call__(self, spec, layout, post, basis_mean, prior_mean, limits, cyl_rows, *rest):
        est = super().__call__(spec, layout, post, basis_mean, prior_mean, limits, cyl_rows, *rest)
        if self.calls % 2 == 1:
            self.rows, self.post, self.p = np.asarray(cyl_rows, dtype=np.float64), post, layout.n_params
        return est


class RowSums:
    """Per raw row r, the smoothed accumulator's whitened sums a_r a_r^T (R, P, P) and a_r y_r (R, P) with its
    forgetting, so that the data-only point's offset from any parameters splits exactly by row: the rows' score
    sum_r (a_r y_r - a_r a_r^T theta) times N^-1 (``Accumulator.cycle_terms`` / ``fold`` wrapped, bench only)."""

    def __init__(self):
        self.aa = self.ay = None
        self.pending: dict = {}
        self.inner_terms, self.inner_fold = Accumulator.cycle_terms, Accumulator.fold

    def install(self) -> None:
        sums = self

        def cycle_terms(acc, a, y, inv_sigma, reference_rows=0):
            terms = sums.inner_terms(acc, a, y, inv_sigma, reference_rows)
            sums.pending[id(terms)] = (np.array(a), np.array(y))
            return terms

        def fold(acc, terms, forgetting, raw=None):
            out = sums.inner_fold(acc, terms, forgetting, raw)
            ay = sums.pending.pop(id(terms), None)
            if ay is not None and raw is not None:  # the smoothed accumulator's fold (it alone keeps raw sums)
                a, y = ay
                if sums.aa is None or sums.aa.shape[:2] != a.shape:
                    sums.aa, sums.ay = np.zeros(a.shape + a.shape[1:]), np.zeros(a.shape)
                lam = float(forgetting)
                sums.aa = lam * sums.aa + a[:, :, None] * a[:, None, :]
                sums.ay = lam * sums.ay + a * y[:, None]
            sums.pending.clear()
            return out

        Accumulator.cycle_terms, Accumulator.fold = cycle_terms, fold

    def split(self, acc: Accumulator, theta: np.ndarray, row: np.ndarray) -> tuple[np.ndarray, float]:
        """(R,) each raw row's share of row @ (N^-1 r - theta)[:p], and how far the sums are from the accumulator's
        N (relative; ~1e-15 when they are the same cycles)."""
        score = self.ay - np.einsum("rij,j->ri", self.aa, theta)
        p = row.shape[0]
        share = score @ np.linalg.solve(acc.info, np.eye(acc.info.shape[0])[:, :p] @ row)
        return share, float(np.abs(self.aa.sum(axis=0) - acc.info).max() / np.abs(acc.info).max())


def checkpoint(tap: PullTap, truth: np.ndarray, k: int, sums: RowSums | None = None) -> dict:
    acc, n_pr, sys_var = tap.normal
    rows, p, m = tap.rows, tap.p, tap.m
    t_post = rows @ tap.post.params[:p]
    h = rows @ np.linalg.solve(acc.info + n_pr, acc.sys_map)[:p]  # (z, R) friction per unit raw error of each row
    fly = slice(0, 2 * m)
    c = sys_var[fly]
    th_d = np.linalg.solve(acc.info, acc.rhs)
    t_data = rows @ th_d[:p]
    sd = float(np.sqrt(rows[k] @ np.linalg.inv(acc.info)[:p, :p] @ rows[k]))
    b, f = tap.budget_seen["budget"], tap.budget_seen["floor"]
    pct = 100.0 / truth[k]
    # the plant's coefficients are the preset's (every friction scale 1); the other parameters (nuisances) at their
    # best given those. (Split by row from sys_map times the mean raw residual, the offset did not add up: ~190-3,200
    # times it, the whitening varies between cycles; ``--split`` keeps the per-row whitened sums instead, note 41)
    star = np.ones(acc.info.shape[0])
    if acc.info.shape[0] > p:
        star[p:] = np.linalg.solve(acc.info[p:, p:], acc.rhs[p:] - acc.info[p:, :p] @ star[:p])
    split = {}
    if sums is not None and sums.aa is not None:
        share, mismatch = sums.split(acc, star, rows[k])
        share = pct * share
        per_order = share[:m] + share[m:2 * m]  # real + imaginary part of each half order (j + 1) / 2
        split = {"split_sum_pct": float(share.sum()), "split_n_mismatch": mismatch,
                 "split_by_order_pct": {f"{(j + 1) / 2:.1f}": round(float(per_order[j]), 1) for j in range(m)},
                 "split_balance_row_pct": float(share[-1]), "split_other_rows_pct": float(share[2 * m:-1].sum())}
    return {**split, "err_pct": float(pct * (t_post[k] - truth[k])), "data_only_err_pct": float(pct * (t_data[k] - truth[k])),
            "data_only_sigma_pct": pct * sd,
            "rms_err_pct": float(100 * np.sqrt(np.mean((t_post / truth - 1) ** 2))),
            "data_only_rms_err_pct": float(100 * np.sqrt(np.mean((t_data / truth - 1) ** 2))),
            "sys_flywheel_pct": float(pct * np.sqrt((h[k, fly] ** 2 * c).sum())),
            "sys_flywheel_coherent_pct": float(pct * (np.abs(h[k, fly]) * np.sqrt(c)).sum()),
            "harmonics_above_floor": int((b > 1.0001 * f).sum()), "harmonics": int(m),
            "top_rows": [int(i) for i in np.argsort(-np.abs(h[k, fly]) * np.sqrt(c))[:5]],
            "unit_scales_err_pct": float(pct * (rows[k] @ star[:p] - truth[k])),
            "data_only_from_unit_pct": float(pct * (t_data[k] - rows[k] @ star[:p]))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log")
    ap.add_argument("--every", type=int, default=500)
    ap.add_argument("--start-cycle", type=int, default=0)
    ap.add_argument("--cylinder", type=int, default=13, help="1-based")
    ap.add_argument("--split", action="store_true",
                    help="split the data-only offset from the truth by raw row (per-row sums kept; note 41)")
    ap.add_argument("--json", default="/tmp/fw-trace/pull.json")
    ap.add_argument("--cycles", type=int, default=0, help="stop after this many analysed cycles (0: the whole log)")
    ap.add_argument("--without", default="", help="as the log's ``simulate --without``: variable_inertia off in the "
                    "monitor too")
    ap.add_argument("--grid-scale", type=float, default=1.0, help="as the log's ``simulate --grid-scale``")
    ap.add_argument("--fit-drift", action="store_true", help="the monitor fits each cycle's linear speed drift "
                    "instead of taking it as a random effect (MonitorConfig fit_drift, drift_nuisance off; note 42)")
    args = ap.parse_args()
    log_path = Path(args.log)
    truth_all = np.load(log_path.with_name(log_path.name.removesuffix(".mcap") + ".truth.npz"))["friction"]
    tap = PullTap()
    identification.reported_estimate, identification.posterior_from_normal = tap, tap.posterior
    identification.accumulate_cycle = tap.budget
    sums = RowSums() if args.split else None
    if sums is not None:
        sums.install()
    log = LogReader(log_path)
    cfg = MonitorConfig(variable_inertia="variable_inertia" not in args.without.split(","))
    if args.fit_drift:
        cfg = replace(cfg, fit_drift=True, drift_nuisance=False)
    pipe = EnginePipeline(plant_engine(args.grid_scale), replace(log.info, second_wheel=None), cfg)
    records, offset = log.records(), 0
    if args.start_cycle:
        records, offset = records_from_cycle(records, args.start_cycle, log.info)
    n, out = 0, []
    for record in records:
        tap.m = pipe.state.n_harmonics if pipe.state is not None else 0
        for o in pipe.outcomes(record):
            if not o.ok:
                continue
            n += 1
            if n % args.every == 0:
                idx = o.index + offset
                truth = truth_all[max(0, idx + 1 - TRUTH_WINDOW):idx + 1].mean(axis=0)
                out.append({"cycles": idx + 1, **checkpoint(tap, truth, args.cylinder - 1, sums)})
                print(json.dumps({k: round(v, 2) if isinstance(v, float) else v for k, v in out[-1].items()}),
                      flush=True)
        if args.cycles and n >= args.cycles:
            break
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps({"log": str(log_path), "cylinder": args.cylinder, "points": out}, indent=1))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
