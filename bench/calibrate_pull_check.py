"""The pull check's kappa (core.monitor.identify.pull_check, design note 42): tuned on some traces, counted on others.

    nice .venv/bin/python -m bench.second_wheel_trace trace LOG --variants one_wheel --pull-kappa inf --json J
    nice .venv/bin/python -m bench.calibrate_pull_check count J [J ...] [--kappa 2]
    nice .venv/bin/python -m bench.calibrate_pull_check tune J [J ...] --on "genset-v20 1500 rpm 0.75 seed 43"
        [--write]

The traces are made with the check off (``--pull-kappa inf``): they hold, every checkpoint and cylinder, the figure's
error against the truth, its whole sigma before the calibration's (the floor's included, ``sigma_floor_pct``), the
monitor's "measured" mask and the check's inputs (d, v, shift in % of the truth). The check at any kappa is then
applied here exactly as ``pull_check.pull_sigma`` and ``with_pull`` do (sigma added in quadrature, a figure whose
sigma exceeds ``resolve_rel`` of it is a share): ``count`` prints, per trace, measured (within 5 % and 2 sigma) every
1,000 cycles and, from 1,000 cycles on, the measured figures outside 2 sigma and the posterior's figures outside it
whatever their status; ``tune`` takes the largest kappa of ``KAPPAS`` (the least cost) with neither on the given
traces (the rule fixed before any trace was looked at), and with ``--write``
records it in core/monitor/tuned.json (PULL_CHECK_KAPPA) with those traces' cases and figure.
"""

from __future__ import annotations

import argparse
import datetime
import json
from pathlib import Path

import numpy as np
from frictionwatch.core.monitor.identify.pull_check import DataPull, pull_sigma
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.tuned import MONITOR_RECORD, Tuned, write_tuned

KAPPAS = (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 6.0, np.inf)
FROM_CYCLE = 1000  # checkpoints counted from here (the first 1,000 cycles: few cylinders measured at all)


def applied(r: dict, kappa: float, resolve_rel: float) -> dict:
    """One checkpoint's cylinders with the check at ``kappa``: err, sigma (% of the truth), measured (z,)."""
    err = np.array(r["err_pct"])
    scale = np.abs(1.0 + err / 100.0)  # a sigma in % of the figure -> in % of the truth
    sig0 = np.array(r["sigma_floor_pct"]) * scale
    meas0 = np.array(r["measured_mask"]).astype(bool)
    d = np.array(r["pull_d_pct"], dtype=float)
    pull = np.zeros_like(err)
    if np.all(np.isfinite(d)) and np.isfinite(kappa):
        if "pull_nm" in r:  # the check as the code takes it, in N m (its directions: its covariance's in N m^2)
            q = r["pull_nm"]
            cov = np.array(q["cov"])
            pull = 100.0 * pull_sigma(DataPull(np.array(q["d"]), np.diag(cov), np.array(q["shift"]), cov),
                                      kappa) / np.array(q["truth"])
        else:  # a trace before the directions were recorded: per cylinder
            pull = pull_sigma(DataPull(d, np.array(r["pull_v_pct2"]), np.array(r["pull_shift_pct"])), kappa)
    sig = np.sqrt(sig0 ** 2 + pull ** 2)
    meas = meas0 & (sig <= 100.0 * resolve_rel * scale)
    return {"err": err, "sigma": sig, "measured": meas, "pull": pull}


def counts(doc: dict, kappa: float, resolve_rel: float, variant: str = "one_wheel") -> dict:
    """Measured (within 5 % and 2 sigma) every 1k; from FROM_CYCLE on the measured figures outside 2 sigma and the
    posterior's figures outside 2 sigma whatever their status (``all_outside``: a share is reported as the share,
    but the figure's sigma is the check's statement about the posterior all the same)."""
    every_k, outside, n_meas, worst, all_out, n_all = {}, 0, 0, (0.0, None), 0, 0
    for r in doc["trace"][variant]:
        a = applied(r, kappa, resolve_rel)
        m = a["measured"]
        good = int((m & (np.abs(a["err"]) <= 5.0) & (np.abs(a["err"]) <= 2.0 * a["sigma"])).sum())
        if r["cycles"] % 1000 == 0:
            every_k[r["cycles"]] = f"{int(m.sum())} ({good})"
        if r["cycles"] >= FROM_CYCLE:
            out = m & (np.abs(a["err"]) > 2.0 * a["sigma"])
            outside += int(out.sum())
            n_meas += int(m.sum())
            all_out += int((np.abs(a["err"]) > 2.0 * a["sigma"]).sum())
            n_all += int(m.size)
            z = np.where(m, np.abs(a["err"]) / a["sigma"], 0.0)
            if z.max() > worst[0]:
                k = int(z.argmax())
                worst = (float(z.max()), f"cyl {k + 1} at {r['cycles']}: {a['err'][k]:+.1f} % on sigma "
                                         f"{a['sigma'][k]:.1f} % (pull {a['pull'][k]:.1f} %)")
    return {"every_1k": every_k, "outside": outside, "measured": n_meas, "worst": worst, "all_outside": all_out,
            "all": n_all}


def line(path: str, kappa: float, c: dict) -> str:
    ks = " | ".join(c["every_1k"][k] for k in sorted(c["every_1k"]))
    return (f"{Path(path).name} kappa {kappa:g}: every 1k {ks}; from {FROM_CYCLE} outside 2 sigma {c['outside']} of "
            f"{c['measured']} measured, every figure {c['all_outside']} of {c['all']}; largest |error|/sigma measured {c['worst'][0]:.2f} ({c['worst'][1]})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("count")
    c.add_argument("json", nargs="+")
    c.add_argument("--kappa", type=float, nargs="+", default=list(KAPPAS))
    t = sub.add_parser("tune")
    t.add_argument("json", nargs="+")
    t.add_argument("--on", nargs="+", required=True, help="the traces' cases, as core/tuned.py writes them")
    t.add_argument("--write", action="store_true")
    args = ap.parse_args()
    resolve_rel = MonitorConfig().resolve_rel
    docs = {p: json.loads(Path(p).read_text()) for p in args.json}
    kappas = args.kappa if args.cmd == "count" else KAPPAS
    table = {k: {p: counts(d, k, resolve_rel) for p, d in docs.items()} for k in kappas}
    for k in kappas:
        for p in docs:
            print(line(p, k, table[k][p]))
    if args.cmd != "tune":
        return
    ok = [k for k in KAPPAS if all(table[k][p]["outside"] == 0 and table[k][p]["all_outside"] == 0 for p in docs)]
    if not ok:
        raise SystemExit("no kappa of KAPPAS leaves every figure within 2 sigma on these traces")
    kappa = max(ok)
    figure = "; ".join(line(p, kappa, table[kappa][p]) for p in docs)
    nxt = [k for k in KAPPAS if k > kappa]
    if nxt:
        figure += "; next kappa " + "; ".join(line(p, nxt[0], table[nxt[0]][p]) for p in docs)
    print(f"kappa = {kappa:g}")
    if args.write:
        cmd = ("python -m bench.calibrate_pull_check tune " + " ".join(Path(p).name for p in docs) + " --on "
               + " ".join(repr(c) for c in args.on) + " --write")
        write_tuned({"PULL_CHECK_KAPPA": Tuned(float(kappa), cmd, tuple(args.on), figure,
                                               datetime.date.today().isoformat())}, MONITOR_RECORD)
        print(f"wrote PULL_CHECK_KAPPA = {kappa:g} to {MONITOR_RECORD}")


if __name__ == "__main__":
    main()
