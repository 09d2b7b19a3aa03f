"""The pull check's cost per call (core.monitor.identify.pull_check, design note 42, issue 26 item 7).

    python -m bench.bench_pull_check capture OUT.pkl [--cycles 60]   (inputs of every call over a monitor run)
    python -m bench.bench_pull_check time IN.pkl [--repeat 200]       (the check alone, per call, on those inputs)
    python -m bench.bench_pull_check monitor [--cycles 120] [--repeat 6]   (the monitor per cycle, either path)

``capture``: genset-v20 (1500 rpm) and k9k-4cyl (4000 rpm) at full load, seed 1 (bench.bench_monitor's points),
simulated here and run through the one pipeline (CyclePipeline) with ``PullCheck.sigma`` wrapped to keep a copy of
every call's inputs (accumulator, smoothed posterior, cylinder rows, shares) and its output. ``time``: per engine,
the numpy reference (``pull_sigma_reference``: one LAPACK inverse, the products, eigh) split into its parts, and
``PullCheck.sigma`` (the kernel), alternated call by call over the captured inputs, ``repeat`` rounds; the median
over rounds of the mean per call [us], and the ratio reference / kernel per round (its median, min-max). ``monitor``: the same points' cycles through
CyclePipeline.process, the check by the kernel or by the reference (``PullCheck.sigma`` swapped), alternated pass by
pass (A B B A ...), timed by the thread's CPU time; the median of the passes' mean ms per cycle per path and the
median (min-max) of reference/kernel over pass pairs; before timing, every cycle's smoothed and cycle estimates of
the two paths are compared (rtol 1e-10). One core
(BLAS/numba threads pinned to 1); quote ``uptime`` beside any absolute figure (docs: quiet-bench.md)."""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import copy  # noqa: E402
import pickle  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from frictionwatch.core.model.engine import load_engine  # noqa: E402
from frictionwatch.core.monitor.identify import identification, step  # noqa: E402
from frictionwatch.core.monitor.identify import pull_check as pc  # noqa: E402
from frictionwatch.core.monitor.identify.spd import spd_inverse  # noqa: E402
from frictionwatch.core.monitor.pipeline import CyclePipeline  # noqa: E402
from frictionwatch.core.plant.simulate import simulate  # noqa: E402

from bench.bench_monitor import SEED, monitored_cycles  # noqa: E402
from bench.bench_monitor_against import differences, plain  # noqa: E402

POINTS = (("genset-v20", 1500.0, 1.0), ("k9k-4cyl", 4000.0, 1.0))


def capture(cycles: int) -> dict:
    """{engine: [(acc, post, rows, share, kappa, sigma), ...]} of every PullCheck.sigma call of a monitor run."""
    out: dict = {}
    original = pc.PullCheck.sigma
    for name, rpm, load in POINTS:
        calls: list = []

        def recorded(self, acc, post, rows, share, _calls=calls):
            sig = original(self, acc, post, rows, share)
            _calls.append(copy.deepcopy((acc, post, np.asarray(rows), np.asarray(share), self.kappa, sig)))
            return sig

        pc.PullCheck.sigma = recorded
        # the step by its reference, which calls PullCheck.sigma (its kernel makes the same sigmas without it)
        fused, identification.identify_step = identification.identify_step, step.identify_step_reference
        try:
            spec = load_engine(name)
            monitored_cycles(spec, simulate(spec, rpm, load, cycles, seed=SEED))
        finally:
            pc.PullCheck.sigma = original
            identification.identify_step = fused
        out[name] = calls
    return out


def _parts(acc, post, rows, share, kappa) -> dict:
    """Seconds of each part of the reference on one input (one call each: the split, not the total)."""
    t = [time.perf_counter()]
    p = rows.shape[1]
    inv = spd_inverse(acc.info)
    t.append(time.perf_counter())
    theta_d = inv @ acc.rhs
    d = rows @ (theta_d[:p] - post.params[:p])
    gap = max(1.0, float(post.chi2_reduced)) * inv[:p, :p] - post.cov_statistical[:p, :p]
    cov = rows @ gap @ rows.T
    cov = 0.5 * (cov + cov.T)
    shift = rows @ post.params[:p] - share
    t.append(time.perf_counter())
    lam, u = np.linalg.eigh(cov)
    t.append(time.perf_counter())
    pc.pull_sigma(pc.DataPull(d, np.maximum(np.diag(cov), 0.0), shift, cov), kappa)
    t.append(time.perf_counter())
    return {"spd_inverse": t[1] - t[0], "products": t[2] - t[1], "eigh": t[3] - t[2], "pull_sigma (eigh incl.)":
            t[4] - t[3]}


def timing(calls: list, repeat: int) -> dict:
    check = pc.PullCheck(calls[0][4])
    ref_us, ker_us, ratio = [], [], []
    parts: dict = {}
    for _ in range(repeat):
        t0 = time.perf_counter()
        for acc, post, rows, share, kappa, _ in calls:
            pc.pull_sigma_reference(acc, post, rows, share, kappa)
        t1 = time.perf_counter()
        for acc, post, rows, share, _, _ in calls:
            check.sigma(acc, post, rows, share)
        t2 = time.perf_counter()
        ref_us.append((t1 - t0) / len(calls) * 1e6)
        ker_us.append((t2 - t1) / len(calls) * 1e6)
        ratio.append((t1 - t0) / (t2 - t1))
        for acc, post, rows, share, kappa, _ in calls[::5]:
            for k, v in _parts(acc, post, rows, share, kappa).items():
                parts.setdefault(k, []).append(v * 1e6)
    return {"calls": len(calls), "reference_us": round(statistics.median(ref_us), 1),
            "kernel_us": round(statistics.median(ker_us), 1),
            "reference/kernel": [round(statistics.median(ratio), 2), round(min(ratio), 2), round(max(ratio), 2)],
            "reference parts, median us": {k: round(statistics.median(v), 1) for k, v in parts.items()}}


def _reference_sigma(self, acc, post, rows, share):
    return pc.pull_sigma_reference(acc, post, rows, share, self.kappa)


def _run(spec, cycles, reference: bool) -> tuple[float, list]:
    """CPU seconds of CyclePipeline.process over ``cycles`` and each analysed cycle's two estimates."""
    kernel = pc.PullCheck.sigma
    pc.PullCheck.sigma = _reference_sigma if reference else kernel
    fused, identification.identify_step = identification.identify_step, step.identify_step_reference
    try:
        pipe, out, spent = CyclePipeline(spec), [], 0.0
        for c in cycles:
            t0 = time.thread_time()
            o = pipe.process(c)
            spent += time.thread_time() - t0
            if o.ok:
                out.append(o.result)
    finally:
        pc.PullCheck.sigma = kernel
        identification.identify_step = fused
    return spent, out


def monitor(n_cycles: int, repeat: int) -> dict:
    out = {}
    for name, rpm, load in POINTS:
        spec = load_engine(name)
        cycles = monitored_cycles(spec, simulate(spec, rpm, load, n_cycles, seed=SEED))
        _, ker = _run(spec, cycles, False)
        _, ref = _run(spec, cycles, True)
        diff, compared = differences(plain(ref), plain(ker), name, rtol=1e-10)  # every number of every result
        if diff:
            raise SystemExit(f"kernel and reference differ: {diff[:5]}")
        exact, _ = differences(plain(ref), plain(ker), name, rtol=0.0)
        times = {False: [], True: []}
        ratio = []
        for _ in range(repeat):
            pair = {}
            for ref_first in (False, True):
                for use_ref in ((True, False) if ref_first else (False, True)):
                    pair.setdefault(use_ref, []).append(_run(spec, cycles, use_ref)[0] / len(cycles) * 1e3)
            for k, v in pair.items():
                times[k].extend(v)
            ratio.append(statistics.median(pair[True]) / statistics.median(pair[False]))
        out[name] = {"cycles": len(cycles), "numbers compared (rtol 1e-10)": compared,
                     "fields not bit-identical": exact[:4],
                     "reference ms/cycle": round(statistics.median(times[True]), 4),
                     "kernel ms/cycle": round(statistics.median(times[False]), 4),
                     "reference/kernel": [round(statistics.median(ratio), 4), round(min(ratio), 4),
                                          round(max(ratio), 4)]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("capture")
    c.add_argument("out")
    c.add_argument("--cycles", type=int, default=60)
    t = sub.add_parser("time")
    t.add_argument("inp")
    t.add_argument("--repeat", type=int, default=200)
    m = sub.add_parser("monitor")
    m.add_argument("--cycles", type=int, default=120)
    m.add_argument("--repeat", type=int, default=6)
    a = ap.parse_args()
    if a.cmd == "monitor":
        for name, r in monitor(a.cycles, a.repeat).items():
            print(name, r)
        return
    if a.cmd == "capture":
        data = capture(a.cycles)
        with open(a.out, "wb") as f:
            pickle.dump(data, f)
        print({k: len(v) for k, v in data.items()})
        return
    with open(a.inp, "rb") as f:
        data = pickle.load(f)
    for name, calls in data.items():
        calls = [x for x in calls if x[0].weight > 0.0]  # (warm-up calls return at once on both paths)
        print(name, timing(calls, a.repeat))


if __name__ == "__main__":
    main()
