"""Where the harmonic balance's time goes, per engine: in the pipeline, alone, and split into its kernels.

    python -m bench.bench_balance [--cycles 120] [--engines k9k-4cyl ...]

On bench.bench_monitor's points (deutz-1cyl 3000 rpm, k9k-4cyl 4000 rpm, genset-v20 1500 rpm, full load, seed 1),
the one pipeline (core.monitor.pipeline.CyclePipeline over service.pipeline.assembled_cycles) runs the stream twice
with core.monitor.monitor's ``harmonic_balance`` wrapped: the first pass loads the kernels and keeps each call's
arguments, the second times each call on the thread's CPU clock (``in pipeline``: what a cycle pays, with the
caches as the other stages leave them). Then the kept calls (the first cycle's, two passes without a warm start,
left out) are replayed back to back (``alone``: warm caches), and on the middle call its three steps are timed
each on its own, best of 5: ``pass_samples`` and ``pass_rows`` (core.monitor.balance.harmonic_balance_kernels,
harmonic_balance: each call's dispatch, its records' unboxing and the boxing of the arrays it returns included)
and the term library's kernels (``TermLibrary.evaluate_into``, one call per term from Python); ``rest`` is the
Python of harmonic_balance itself (alone minus the three). Every figure is us per call (one call a cycle once
warm). Quote ``uptime`` beside them: on a shared 2-core box compare ratios between engines, not absolute times.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # one core, also when run directly (before numpy loads BLAS)

import argparse  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402

import frictionwatch.core.monitor.monitor as monitor_module  # noqa: E402
import numpy as np  # noqa: E402
from frictionwatch.core.model.engine import load_engine  # noqa: E402
from frictionwatch.core.monitor.balance.harmonic_balance import pass_rows  # noqa: E402
from frictionwatch.core.monitor.balance.harmonic_balance_kernels import CycleMotion, pass_samples  # noqa: E402
from frictionwatch.core.monitor.pipeline import CyclePipeline  # noqa: E402
from frictionwatch.core.plant.simulate import simulate  # noqa: E402
from frictionwatch.service.pipeline import assembled_cycles  # noqa: E402

from bench.bench_monitor import POINTS, SEED  # noqa: E402


def _best_us(fn, calls: int = 2000, repeats: int = 5) -> float:
    """Best of ``repeats`` means over ``calls`` calls, us, thread CPU clock."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.thread_time()
        for _ in range(calls):
            fn()
        best = min(best, (time.thread_time() - t0) / calls)
    return 1e6 * best


def _steps(args: tuple) -> dict[str, float]:
    """The middle call's three steps, each timed on its own (the inputs harmonic_balance gives them)."""
    op, theta, n_nuis, rel, static, grid, pressure, fly, theta_start, _, n_time = args[:11]
    cyl, m = op.cylinders, fly.harmonics.shape[0]
    twist = cyl.n_nodes > 1
    rel_in = rel if twist else np.zeros((0, m), np.complex128)
    static_in = static if twist else np.zeros(0)
    cyc = CycleMotion(fly.harmonics, float(fly.omega_mean), float(fly.offset), float(fly.drift), float(fly.period),
                      float(theta_start), int(n_time))
    grid_out = pass_samples(cyc, cyl, rel_in, static_in, grid, pressure)
    basis = np.empty((op.layout.n_terms, cyl.node.shape[0], int(n_time)))
    library = op.layout.library
    pattern = fly.pattern_harmonics if n_nuis else np.zeros((m, 0), np.complex128)
    params = theta[:op.layout.n_params]
    return {
        "pass_samples": _best_us(lambda: pass_samples(cyc, cyl, rel_in, static_in, grid, pressure)),
        "terms": _best_us(lambda: library.evaluate_into(grid_out.samples, cyl.friction, basis)),
        "pass_rows": _best_us(lambda: pass_rows(fly.harmonics, cyc.omega_mean, grid_out.known, grid_out.motion,
                                                grid_out.gas, basis, op.mix, op.chain, params, pattern, int(n_nuis))),
    }


def engine_balance(name: str, rpm: float, load: float, cycles: int) -> dict:
    spec = load_engine(name)
    sim = simulate(spec, rpm, load, cycles, seed=SEED)
    stream, _ = assembled_cycles(spec, sim.info, sim.records)
    balance = monitor_module.harmonic_balance
    kept: list[tuple] = []
    spent: list[float] = []

    def keep(*args):
        kept.append(args)
        return balance(*args)

    def timed(*args):
        t0 = time.thread_time()
        out = balance(*args)
        spent.append(time.thread_time() - t0)
        return out

    try:
        for wrapper in (keep, timed):
            monitor_module.harmonic_balance = wrapper
            pipe = CyclePipeline(spec)
            for c in stream:
                pipe.process(c)
    finally:
        monitor_module.harmonic_balance = balance
    calls = kept[1:]
    alone = []
    for _ in range(5):
        t0 = time.thread_time()
        for args in calls:
            balance(*args)
        alone.append((time.thread_time() - t0) / len(calls))
    steps = _steps(calls[len(calls) // 2])
    op, fly = calls[0][0], calls[0][7]
    out = {"nodes": op.cylinders.n_nodes, "cylinders": int(op.cylinders.node.shape[0]),
           "harmonics": int(fly.harmonics.shape[0]), "samples": int(calls[0][10]), "calls": len(spent),
           "in_pipeline_us": 1e6 * statistics.median(spent[1:]), "alone_us": 1e6 * min(alone), **steps}
    out["rest"] = out["alone_us"] - sum(steps.values())
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=120)
    ap.add_argument("--engines", nargs="*", default=[p[0] for p in POINTS])
    args = ap.parse_args()
    print(subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    print(f"{'engine':11s} {'N':>3s} {'z':>3s} {'M':>3s} {'n':>4s} | {'in pipeline':>11s} {'alone':>7s} | "
          f"{'pass_samples':>12s} {'terms':>6s} {'pass_rows':>9s} {'rest':>6s}   (us a call, median / best)")
    for name, rpm, load in POINTS:
        if name not in args.engines:
            continue
        r = engine_balance(name, rpm, load, args.cycles)
        print(f"{name:11s} {r['nodes']:3d} {r['cylinders']:3d} {r['harmonics']:3d} {r['samples']:4d} | "
              f"{r['in_pipeline_us']:11.1f} {r['alone_us']:7.1f} | {r['pass_samples']:12.1f} {r['terms']:6.1f} "
              f"{r['pass_rows']:9.1f} {r['rest']:6.1f}")
    print(subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())


if __name__ == "__main__":
    main()
