"""What draws a genset-v20 cylinder's smoothed estimate away from its truth (issue 29, design note 41): one wheel,
every ``--every`` cycles, from the accumulated equations the monitor itself keeps.

    nice .venv/bin/python -m bench.second_wheel_pull LOG [--every 500] [--start-cycle 0] [--cylinder 13] [--json J]

LOG is a replay log of ``bench.second_wheel_trace simulate`` (its truth beside it). Per checkpoint, for the cylinder:
the posterior's error against the truth (mean of the last 200 cycles); the data-only fixed point N^-1 r of the
accumulated normal equations (no prior, no bound) and its statistical sigma sqrt(c N^-1 c^T): where more cycles of
the same equations lead the estimate; the sandwich's flywheel systematic sigma with the stated per-row budget C
(independent rows: sqrt(sum h^2 C)) and the same C taken coherent over the rows (sum |h| sqrt(C): one physical error
common to every harmonic); how many of the flywheel's harmonics have a budget above the 0.3 %-of-the-harmonic floor
(the identification step's ``accumulate_cycle`` budget: the persistent residual at the estimate seen), and the five raw
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
from frictionwatch.core.monitor.identify import identification, step
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
        self.inner_step = step.accumulate_cycle
        self.budget_seen: dict = {}
        self.within = WithinMap()

    def budget(self, acc, white, forgetting, fold, params, model_rel_error, harmonics):
        """Wraps the step's accumulate_cycle (the budget is its third output)."""
        terms, acc, out = self.inner_step(acc, white, forgetting, fold, params, model_rel_error, harmonics)
        m = white.freq.shape[0]
        e = model_rel_error * white.freq * np.abs(harmonics)
        self.budget_seen = {"floor": e * e / 2.0, "budget": out[:m].copy()}
        if fold:
            self.within.add(white.a[:2 * m], white.inv_sigma[:2 * m], 1j * white.freq * harmonics, float(forgetting))
        return terms, acc, out

    def __call__(self, spec, layout, post, basis_mean, prior_mean, limits, cyl_rows, *rest):
        est = super().__call__(spec, layout, post, basis_mean, prior_mean, limits, cyl_rows, *rest)
        if self.calls % 2 == 1:
            self.rows, self.post, self.p = np.asarray(cyl_rows, dtype=np.float64), post, layout.n_params
        return est


class WithinMap:
    """A relative error of the modelled cycle-to-cycle response (bench sketch, note 105): per harmonic i a complex
    relative error rho_i (two real numbers, each of variance 1 here) of each cycle's speed harmonic H_c,i about the
    accumulated mean; the rhs moves by X[:, (i, a|b)] rho = sum_c lambda^age a_c^T D_c (dH_c) per unit rho, dH_c the
    cycle's harmonic minus the accumulated mean: X_a = sum (a_re w Re H + a_im w Im H), X_b = sum (-a_re w Im H +
    a_im w Re H), less the accumulated sys_map times the mean harmonic."""

    def __init__(self):
        self.xa = self.xb = None
        self.h = None
        self.w = 0.0
        self.sa = self.sb = None

    def add(self, a, inv_sigma, h, lam):
        m = h.shape[0]
        ar, ai = a[:m] * inv_sigma[:m, None], a[m:] * inv_sigma[m:, None]  # (m, P)
        xa = ar * h.real[:, None] + ai * h.imag[:, None]
        xb = -ar * h.imag[:, None] + ai * h.real[:, None]
        if self.xa is None or self.xa.shape != xa.shape:
            self.xa, self.xb, self.h, self.w = np.zeros_like(xa), np.zeros_like(xb), np.zeros(m, complex), 0.0
            self.ar, self.ai = np.zeros_like(ar), np.zeros_like(ai)
        self.xa, self.xb = lam * self.xa + xa, lam * self.xb + xb
        self.ar, self.ai = lam * self.ar + ar, lam * self.ai + ai
        self.h, self.w = lam * self.h + h, lam * self.w + 1.0

    def columns(self) -> np.ndarray:
        """(P, 2M) the rhs per unit relative error, the mean harmonic's part removed."""
        hb = self.h / self.w
        ma = self.ar * hb.real[:, None] + self.ai * hb.imag[:, None]
        mb = -self.ar * hb.imag[:, None] + self.ai * hb.real[:, None]
        return np.concatenate([self.xa - ma, self.xb - mb]).T


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
    within = {}
    if tap.within.xa is not None:
        g = rows @ np.linalg.solve(acc.info + n_pr, tap.within.columns())[:p]  # (z, 2M) per unit rho
        gd = rows @ np.linalg.solve(acc.info, tap.within.columns())[:p]
        sw = np.sqrt((g ** 2).sum(axis=1)) / truth * 100.0
        low = np.r_[0:7, m:m + 7]  # orders 0.5-3.5 (a and b of each)
        sl = np.sqrt((g[:, low] ** 2).sum(axis=1)) / truth * 100.0
        within = {"within_sigma_unit_pct": float(sw[k]), "within_sigma_unit_all_pct": [round(float(v), 1) for v in sw],
                  "within_data_only_unit_pct": float(pct * np.sqrt((gd[k] ** 2).sum())),
                  "within_low_unit_all_pct": [round(float(v), 1) for v in sl],
                  "within_data_only_low_unit_pct": float(pct * np.sqrt((gd[k, low] ** 2).sum())),
                  "err_all_pct": [round(float(v), 1) for v in 100 * (t_post / truth - 1)]}
    split = {}
    if sums is not None and sums.aa is not None:
        share, mismatch = sums.split(acc, star, rows[k])
        share = pct * share
        per_order = share[:m] + share[m:2 * m]  # real + imaginary part of each half order (j + 1) / 2
        split = {"split_sum_pct": float(share.sum()), "split_n_mismatch": mismatch,
                 "split_by_order_pct": {f"{(j + 1) / 2:.1f}": round(float(per_order[j]), 1) for j in range(m)},
                 "split_balance_row_pct": float(share[-1]), "split_other_rows_pct": float(share[2 * m:-1].sum())}
    return {**split, **within, "err_pct": float(pct * (t_post[k] - truth[k])), "data_only_err_pct": float(pct * (t_data[k] - truth[k])),
            "data_only_sigma_pct": pct * sd,
            "rms_err_pct": float(100 * np.sqrt(np.mean((t_post / truth - 1) ** 2))),
            "data_only_rms_err_pct": float(100 * np.sqrt(np.mean((t_data / truth - 1) ** 2))),
            "sys_flywheel_pct": float(pct * np.sqrt((h[k, fly] ** 2 * c).sum())),
            "sys_flywheel_coherent_pct": float(pct * (np.abs(h[k, fly]) * np.sqrt(c)).sum()),
            "harmonics_above_floor": int((b > 1.0001 * f).sum()), "harmonics": int(m),
            "top_rows": [int(i) for i in np.argsort(-np.abs(h[k, fly]) * np.sqrt(c))[:5]],
            "unit_scales_err_pct": float(pct * (rows[k] @ star[:p] - truth[k])),
            "data_only_from_unit_pct": float(pct * (t_data[k] - rows[k] @ star[:p]))}


class DriftSeen:
    """Each cycle's drift coefficient as the data see it (the GLS fit of the drift column to the residual at the
    previous estimate, whitened by the statistics' variance) against the random effect's stated prior variance
    s^2 = drift_var (T/2)^2: var_data = mean(f^2) - mean(1/n_d) over the cycles (bench only; note 105)."""

    def __init__(self, scale: float = 1.0):
        self.scale, self.f, self.f2, self.noise, self.stated, self.n = scale, 0.0, 0.0, 0.0, 0.0, 0

    def install(self) -> None:
        from frictionwatch.core.monitor import monitor
        inner, seen = monitor.identify_cycle, self

        def wrapped(cfg, spec, state, fly, rows, exc, pmax, mean, drift_var, free_rows=None, modes=None):
            seen.observe(state, fly, rows, drift_var)
            return inner(cfg, spec, state, fly, rows, exc, pmax, mean, drift_var * seen.scale, free_rows, modes)

        monitor.identify_cycle = wrapped

    def observe(self, state, fly, rows, drift_var: float) -> None:
        m = rows.design.shape[0]
        if state.stats.count < 3 or state.stats.var.shape[0] != m:
            return
        freq = 0.5 * fly.omega_mean * np.arange(1, m + 1)
        col = 1j * freq * fly.pattern_harmonics[:, -1]
        resid = rows.target - rows.design @ state.params
        w = 1.0 / np.maximum(state.stats.var, 1e-30)
        nd = float((np.abs(col) ** 2 * w).sum())
        f = float(((col.real * resid.real + col.imag * resid.imag) * w).sum()) / nd
        self.n += 1
        self.f += f
        self.f2 += f * f
        self.noise += 1.0 / nd
        self.stated += drift_var * (0.5 * fly.period) ** 2

    def summary(self) -> dict:
        if self.n < 2:
            return {}
        mean = self.f / self.n
        return {"drift_var_data": self.f2 / self.n - mean * mean - self.noise / self.n,
                "drift_var_stated": self.stated / self.n, "drift_fit_noise": self.noise / self.n,
                "drift_mean": mean}


def drive_train_modes(spec, hz: list[float]) -> np.ndarray:
    """The chain's eigenvalues lambda [1/s] (upper half plane) nearest each frequency of ``hz`` [Hz] (its
    free-vibration modes with their damping, core.model.dynamics.shaft_model)."""
    from frictionwatch.core.model.dynamics import shaft_model
    sh = shaft_model(spec, 0.0, 157.0)
    n = sh.mass.shape[0]
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-sh.stiffness / sh.mass[:, None], -sh.damping / sh.mass[:, None]]])
    lam = np.linalg.eigvals(a)
    lam = lam[lam.imag > 0]
    return np.array([lam[np.argmin(np.abs(np.abs(lam) / (2 * np.pi) - f))] for f in hz])


def project_free_response(lams: np.ndarray) -> None:
    """Each cycle's flywheel rows with the free response of the modes ``lams`` over the window projected out
    (their amplitude at the window's start a free unknown of the cycle: what a late cylinder's deviation in the
    cycle before leaves ringing; bench only, note 105). Speed harmonic k of Re(c e^(lambda t)), t in [0, T):
    c I_k(lambda) + conj(c) I_k(conj(lambda)), I_k(l) = (e^(l T) - 1) / (T (l - i k 2 pi / T)) (the monitor's
    harmonics: angle Re(h e^(+i k w_c t)), speed i k w_c h)."""
    inner = identification.whitened_rows

    def projected(settings, stats, fly, rows, params, balance, t_i, drift_var):
        white = inner(settings, stats, fly, rows, params, balance, t_i, drift_var)
        m, period = white.freq.shape[0], float(fly.period)
        k = np.arange(1, m + 1)
        cols = []
        for lam in lams:
            i1 = (np.exp(lam * period) - 1.0) / (period * (lam - 2j * np.pi * k / period))
            i2 = (np.exp(np.conj(lam) * period) - 1.0) / (period * (np.conj(lam) - 2j * np.pi * k / period))
            cols += [i1 + i2, 1j * (i1 - i2)]
        f = np.array(cols).T  # (m, 2q) complex
        fw = np.concatenate([f.real, f.imag]) * white.inv_sigma[:2 * m, None]
        q, _ = np.linalg.qr(fw)
        a, y = white.a.copy(), white.y.copy()
        a[:2 * m] -= q @ (q.T @ a[:2 * m])
        y[:2 * m] -= q @ (q.T @ y[:2 * m])
        return replace(white, a=a, y=y)

    identification.whitened_rows = projected


def free_response_seen(stats) -> dict:
    """The carried modes' free-response statistics (note 108): per mode the EWMA coefficient^2, its noise part and
    the prior variance they give (empty when no mode is carried)."""
    if stats.free_coef_sq is None:
        return {}
    return {"free_coef_sq": [float(f"{v:.3g}") for v in stats.free_coef_sq],
            "free_noise": [float(f"{v:.3g}") for v in stats.free_noise],
            "free_var": [float(f"{v:.3g}") for v in np.maximum(stats.free_coef_sq - stats.free_noise, 0.0)]}


def free_response_raw_moment() -> None:
    """Each carried mode's prior variance the EWMA of its coefficient^2 itself, the noise part not subtracted (an
    upper bound: a mean free response counted as variance; bench only, note 108)."""
    from frictionwatch.core.monitor.identify import free_response
    inner = free_response.free_response_variance

    def raw(prev, coef_sq, noise, memory):
        sq, nz, n, _ = inner(prev, coef_sq, noise, memory)
        return sq, nz, n, sq

    free_response.free_response_variance = raw


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
    ap.add_argument("--drift-scale", type=float, default=1.0, help="the drift random effect's prior variance x this "
                    "(bench only: how much of the offset the drift's stated size decides; note 105)")
    ap.add_argument("--free-response-carry", type=float, default=None, help="MonitorConfig free_response_carry (0: "
                    "the chain's free response left in the rows; 0.1, the default: its slow modes a random effect; "
                    "notes 105, 108)")
    ap.add_argument("--free-modes", default="", help="the chain's modes (Hz, comma list: the nearest of its "
                    "eigenvalues) whose free response each cycle's flywheel rows have projected out, beside the "
                    "monitor's own (with --free-response-carry 0: these alone; note 105)")
    ap.add_argument("--free-raw-moment", action="store_true", help="the carried modes' prior variance their "
                    "coefficient's mean square, the noise part not subtracted (note 108)")
    args = ap.parse_args()
    if args.free_raw_moment:
        free_response_raw_moment()
    drift = DriftSeen(args.drift_scale)
    drift.install()
    log_path = Path(args.log)
    truth_all = np.load(log_path.with_name(log_path.name.removesuffix(".mcap") + ".truth.npz"))["friction"]
    tap = PullTap()
    identification.identify_step = step.identify_step_reference  # the step by the wrappers the taps see
    step.reported_estimate, step.posterior_from_normal = tap, tap.posterior
    step.accumulate_cycle = tap.budget
    sums = RowSums() if args.split else None
    if sums is not None:
        sums.install()
    log = LogReader(log_path)
    cfg = MonitorConfig(variable_inertia="variable_inertia" not in args.without.split(","))
    if args.fit_drift:
        cfg = replace(cfg, fit_drift=True, drift_nuisance=False)
    if args.free_response_carry is not None:
        cfg = replace(cfg, free_response_carry=args.free_response_carry)
    if args.free_modes:
        lams = drive_train_modes(plant_engine(args.grid_scale), [float(f) for f in args.free_modes.split(",")])
        print("modes", [(round(abs(x) / (2 * np.pi), 2), round(-x.real / abs(x), 3)) for x in lams])
        project_free_response(lams)
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
                out.append({"cycles": idx + 1, **checkpoint(tap, truth, args.cylinder - 1, sums), **drift.summary(),
                            **free_response_seen(pipe.state.stats)})
                print(json.dumps({k: round(v, 2) if isinstance(v, float) else v for k, v in out[-1].items()}),
                      flush=True)
        if args.cycles and n >= args.cycles:
            break
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps({"log": str(log_path), "cylinder": args.cylinder, "points": out}, indent=1))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
