"""Functions of another checkout swapped into this process, the monitor timed pass by pass with either: what a
shared box can resolve of a cut of a few per cent (design note 37).

    python -m bench.bench_swap_against --base ../base \\
        --swap frictionwatch.core.monitor.checks.ring_pressure:moved_kernel \\
        --swap frictionwatch.core.monitor.calibration.tdc_watch:TraceCut.fits [--pairs 40] [--cycles 120]

Two checkouts' end-to-end runs are separate processes (bench_monitor_against): on this 2-core box shared with other
jobs their ratio moves by +-10-30 % from run to run, more than a cut of a few per cent. Here one process holds both
versions of the named functions: each ``--swap module:attr[.attr]`` is loaded from the base checkout's source of that
module (imported under another name, numba kernels compiled from it) and set in place of this checkout's; the
monitor alone (``bench_monitor._monitor_pass``: CyclePipeline over the assembled cycles of bench_monitor's points)
runs pass by pass, base and this alternated (A B, B A, ...), timed by the thread's CPU time. Reported per engine:
each side's median ms per cycle and the median (min-max) of base / this over the pairs, with ``uptime``.

A swapped function must be one the other code looks up where it is set (a module global read at call time, a class
attribute); a name imported by value elsewhere (``from m import f``) keeps this checkout's there: swap it where it is
read with ``--swap reader_module:f=defining_module`` (the reader's global ``f`` set to the base's ``f`` of the
defining module's file; e.g. ``--swap frictionwatch.core.monitor.monitor:transient_balance=
frictionwatch.core.monitor.identify.identification``). The figures are
only a comparison if the outcomes are equal: run ``bench_monitor_against --check-only`` first.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # one core, as bench_monitor (before numpy loads BLAS: else a threaded BLAS on a
    # shared box made the same passes 5-10x slower by CPU clock)

import argparse  # noqa: E402
import gc  # noqa: E402
import importlib  # noqa: E402
import importlib.util  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from frictionwatch.core.model.engine import load_engine  # noqa: E402
from frictionwatch.core.plant.simulate import simulate  # noqa: E402
from frictionwatch.service.pipeline import assembled_cycles  # noqa: E402

from bench.bench_monitor import CYCLES, POINTS, SEED, _monitor_pass  # noqa: E402


def _owner_and_name(root: object, dotted: str) -> tuple[object, str]:
    parts = dotted.split(".")
    for p in parts[:-1]:
        root = getattr(root, p)
    return root, parts[-1]


def swaps(base: Path, specs: list[str]) -> list[tuple[object, str, object, object]]:
    """(owner, attribute, base's value, this checkout's value) of each ``module:attr[.attr][=source_module]``: the
    base's file of the source module (default: that module; the same path under ``base`` as under this checkout)
    executed as a module of its own, its ``attr`` set in the module's."""
    root = Path(__file__).resolve().parents[1]
    out = []
    for k, spec in enumerate(specs):
        mod_name, _, dotted = spec.partition(":")
        dotted, _, source = dotted.partition("=")
        if not dotted:
            raise SystemExit(f"--swap {spec!r}: expected module:attribute[=source_module]")
        mod = importlib.import_module(mod_name)
        rel = Path(importlib.import_module(source or mod_name).__file__).resolve().relative_to(root)
        path = base / rel
        if not path.is_file():
            raise SystemExit(f"--swap {spec!r}: no {rel} under {base}")
        name = f"_base_swap_{k}"
        spec_ = importlib.util.spec_from_file_location(name, path)
        other = importlib.util.module_from_spec(spec_)
        sys.modules[name] = other  # (dataclasses look their module up while the class is made)
        spec_.loader.exec_module(other)
        owner, attr = _owner_and_name(mod, dotted)
        base_value = getattr(*_owner_and_name(other, dotted))
        out.append((owner, attr, base_value, vars(owner)[attr] if isinstance(owner, type) else getattr(owner, attr)))
    return out


def _use(table, base: bool) -> None:
    for owner, attr, base_value, this_value in table:
        setattr(owner, attr, base_value if base else this_value)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True, help="the other checkout")
    ap.add_argument("--swap", action="append", required=True, help="module:attr[.attr] to take from the base")
    ap.add_argument("--pairs", type=int, default=40)
    ap.add_argument("--cycles", type=int, default=CYCLES)
    ap.add_argument("--engines", default=",".join(n for n, _, _ in POINTS))
    args = ap.parse_args()
    table = swaps(args.base.resolve(), args.swap)
    print("uptime:", open("/proc/loadavg").read().split()[:3], flush=True)
    for name, rpm, load in POINTS:
        if name not in args.engines.split(","):
            continue
        spec = load_engine(name)
        sim = simulate(spec, rpm, load, args.cycles, seed=SEED)
        cycles, _ = assembled_cycles(spec, sim.info, sim.records)
        del sim
        gc.collect()  # (the simulator's records no longer held: not what the passes traverse)
        for side in (True, False):  # first calls and kernel loads of both versions
            _use(table, side)
            _monitor_pass(spec, cycles)
        ms = {True: [], False: []}
        ratios = []
        for p in range(args.pairs):
            for side in ((True, False) if p % 2 == 0 else (False, True)):
                _use(table, side)
                t = time.thread_time()
                n = max(len(_monitor_pass(spec, cycles)), 1)
                ms[side].append(1e3 * (time.thread_time() - t) / n)
            ratios.append(ms[True][-1] / ms[False][-1])
        _use(table, False)
        print(f"  {name:12s} base {statistics.median(ms[True]):.4f} | this {statistics.median(ms[False]):.4f} ms a "
              f"cycle, base/this {statistics.median(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f}) over "
              f"{args.pairs} pairs", flush=True)
    print("uptime:", open("/proc/loadavg").read().split()[:3])


if __name__ == "__main__":
    main()
